"""A temperature first published after the calibrator decided without one (real DDS).

``nodes/late_inputs``: the node, with the shipped ``temperature_topics`` and nothing on them
for ``absent_inputs.GRACE_S`` after the first IMU message, collects without a temperature;
a driver that starts publishing it later is taken at its first reading, as ``calibrate``
takes a log's late temperature (the IMU samples more than ``temperature_timeout`` before
it are not collected). Live against offline on a real recording is
``test_live_offline.py``'s ``late_temperature`` case; here the mechanics: the inputs come
back, the collection made without them is moved aside, the file's note says what
happened, a snapshot taken before the first reading works, a late Float32 driver is
followed and its readings put on the IMU's clock, a late temperature under another name is
followed, and a publisher of a type that is not a thermal one is only named.
"""

from conftest import other_participant, replay_flow, wait_for
import numpy as np
from sensor_msgs.msg import Temperature
from std_msgs.msg import Float32, String
from std_srvs.srv import Trigger
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.nodes import absent_inputs, late_inputs
from test_node_calibrator import calibrator, imu_player, RATE, recording, WAIT

#: a shorter wait before deciding without a temperature (the node reads it at each tick)
GRACE_S = 1.0


class _LateSession:
    """A calibrator, a driver without a temperature, the first part played and decided.

    ``recording(repetitions=2)``: the faces of the first round come before the readings.
    ``play_rest(pub)`` then plays the rest with the readings on ``pub``.
    """

    def __init__(self, ros, tmp_path, name):
        self.ros = ros
        rec = recording(repetitions=2)
        self.imu = rec.imu()
        (_, self.tc), = rec.temperatures.items()
        self.cut = int(np.searchsorted(self.imu.stamp_ns, (rec.schedule[1].stamp_end_ns
                                                           + rec.schedule[2].stamp_start_ns)
                                       // 2))
        self.node = calibrator(ros, tmp_path)
        self.drv, self.imu_pub, self.progress = imu_player(ros, name)
        self.sent = replay_flow(self.imu_pub, self.imu.slice(slice(0, self.cut)), [], RATE,
                                self.received, what='the first part')
        wait_for(lambda: self.received() >= self.sent and self.node.k == 0
                 and self.progress[-1]['samples'] > 0, WAIT,
                 'the decision without a temperature')

    def received(self):
        return self.progress[-1]['imu_received']

    def play_rest(self, temp_pub):
        """Match ``temp_pub``, play the rest with its readings; return their stamps (ns)."""
        self.ros.wait_matched(temp_pub, 1, timeout=WAIT)
        rest = self.imu.slice(slice(self.cut, None))
        late = self.tc.stamp_ns >= rest.stamp_ns[0]
        self.sent += replay_flow(self.imu_pub, rest, [(temp_pub, self.tc.stamp_ns[late],
                                                      self.tc.temperature[late])],
                                 RATE, self.received, what='the second part',
                                 readings=lambda: self.progress[-1]['temperature_readings'])
        wait_for(lambda: self.received() >= self.sent, WAIT, 'every IMU message')
        return self.tc.stamp_ns[late]

    def calibrate(self):
        return self.ros.call(self.drv, Trigger, '/thermal_imu_calibrator/calibrate',
                             timeout=180)


def test_a_temperature_published_late_is_taken_from_its_first_reading(ros, tmp_path,
                                                                      monkeypatch):
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    late = _LateSession(ros, tmp_path, 'late_driver')
    node = late.node
    held = len(node.windows.hold_ids)
    assert held >= 1 and node._late_inputs is not None
    # an estimate while the shadow aligner is under the node's (its snapshot copies it):
    # answered (a refusal or not), and nothing raised (the ``ros`` fixture checks)
    assert late.calibrate().message
    warned = []
    node.get_logger().warning = warned.append
    stamps = late.play_rest(late.drv.create_publisher(Temperature, 'imu/temperature', 100))
    assert node.k == 1 and node.temperature_topics == ['imu/temperature']
    said = [w for w in warned if w.startswith('/imu/temperature: the first reading came')]
    assert len(said) == 1 and 'moved to' in said[0], warned
    assert not [w for w in warned if 'it is not used' in w], warned
    aside = [p for p in tmp_path.glob('collection.jsonl.without_temperature-*')
             if p.suffix not in ('.transitions', '.json')]
    assert len(aside) == 1 and aside[0].read_text().count('\n') >= held, aside

    resp = late.calibrate()
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert len(cal.inputs) == 1
    notes = [n for n in cal.notes if n.startswith('input: ')]
    assert [n for n in notes if 'the first reading came' in n], cal.notes
    assert not [n for n in notes if 'no temperature is published' in n], cal.notes
    # nothing collected from before the readings, but what calibrate keeps of a log whose
    # temperature starts there: samples at most temperature_timeout before the first one
    assert node.windows.t0.min() >= stamps[0] * 1e-9 - node.temperature_timeout
    assert len(node.windows.hold_ids) >= 2


def test_a_reset_while_the_inputs_are_watched_feeds_their_clocks_at_once(ros, tmp_path,
                                                                         monkeypatch):
    # ~/reset gives the node fresh clocks; the watched inputs' clocks, judged afresh too,
    # are put under them in the reset itself, not at the next tick: every IMU message
    # after it reaches them (before 2026-12-03 those of the first tick after it did not).
    # The tick's re-shadowing is switched off here, so only the reset can do it
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    late = _LateSession(ros, tmp_path, 'late_reset_driver')
    watched = late.node._late_inputs
    monkeypatch.setattr(late_inputs, 'watch', lambda node: None)
    before = watched.clocks
    resp = late.ros.call(late.drv, Trigger, '/thermal_imu_calibrator/reset', timeout=60)
    assert resp.success, resp.message
    assert watched.clocks is not before and watched.clocks.span is None
    part = late.imu.slice(slice(late.cut, late.cut + 200))      # one chunk, no back-pressure
    replay_flow(late.imu_pub, part, [], RATE, late.received, what='after the reset')
    want = (int(part.stamp_ns[0]), int(part.stamp_ns[-1]))
    wait_for(lambda: watched.clocks.span == want, WAIT,
             f'the watched clocks to see the messages after the reset ({want})')


class _ZeroStamps:
    """A publisher whose messages leave with header stamp 0 (published in stamp order)."""

    def __init__(self, pub):
        self.pub = pub

    def publish(self, msg):
        msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0
        self.pub.publish(msg)

    def __getattr__(self, name):          # topic_name, get_subscription_count, ...
        return getattr(self.pub, name)


def test_a_late_temperature_stamped_0_goes_on_the_imus_clock(ros, tmp_path, monkeypatch):
    # a late driver that leaves its header stamps 0: taken, and its readings put on the
    # IMU's clock as for any input stamped so (io.headerless.StampChoice); the node kept no
    # IMU history meanwhile, so only readings after the next IMU message are placed
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    late = _LateSession(ros, tmp_path, 'late_zero_driver')
    late.play_rest(_ZeroStamps(late.drv.create_publisher(Temperature, 'imu/temperature', 100)))
    assert late.node.k == 1 and late.node._clocks.bare == [True]
    resp = late.calibrate()
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert len(cal.inputs) == 1 and cal.valid_range is not None
    assert [n for n in cal.notes if 'the first reading came' in n], cal.notes


class _AsFloat32:
    """A publisher of std_msgs/Float32 taking the harness's Temperature messages (um7-like)."""

    def __init__(self, pub):
        self.pub = pub

    def publish(self, msg):
        self.pub.publish(Float32(data=float(msg.temperature)))

    def __getattr__(self, name):          # topic_name, get_subscription_count, ...
        return getattr(self.pub, name)


def test_a_late_float32_driver_is_followed_and_put_on_the_imus_clock(ros, tmp_path,
                                                                     monkeypatch, request):
    # the node subscribes its input as sensor_msgs/Temperature; a driver started late
    # publishes std_msgs/Float32 (no header) on it: the input is re-subscribed as Float32
    # (nodes/thermal_types), taken at its first reading, and each reading takes the stamp of
    # the IMU message published before it (the node kept their publish order meanwhile)
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    late = _LateSession(ros, tmp_path, 'late_float32_driver')
    node = late.node
    warned = []
    node.get_logger().warning = warned.append
    # another participant: DDS refuses a second type on a topic in the node's
    driver = other_participant(request, 'float32_driver')
    stamps = late.play_rest(_AsFloat32(driver.create_publisher(Float32, 'imu/temperature', 100)))
    assert node.k == 1 and node._clocks.bare == [True]
    assert node.type_follower.types == ['std_msgs/msg/Float32']
    assert not [w for w in warned if 'it is not used' in w], warned
    resp = late.calibrate()
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert len(cal.inputs) == 1 and cal.valid_range is not None
    notes = [n for n in cal.notes if n.startswith('input: ')]
    assert [n for n in notes if 'the first reading came' in n], cal.notes
    assert [n for n in notes if n.startswith('input: /imu/temperature is published as '
                                             'std_msgs/msg/Float32 by /float32_driver, '
                                             'not sensor_msgs/msg/Temperature')], cal.notes
    # the readings were placed on the IMU's clock from the first: each chunk's readings go
    # out before its IMU messages (replay_flow), so the first takes the stamp of the last
    # IMU message published before it, the first part's last; nothing collected starts
    # more than temperature_timeout before that, and no reading was left out as published
    # before every IMU message the node kept
    first = late.imu.stamp_ns[late.cut - 1] * 1e-9
    assert first - node.temperature_timeout <= node.windows.t0.min() <= stamps[0] * 1e-9 + 30
    assert len(node.windows.hold_ids) >= 2
    assert node.counts['temperature_before_imu'] == 0


def test_a_late_publisher_of_a_type_not_thermal_is_named_not_taken(ros, tmp_path, monkeypatch,
                                                                   request):
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    rec = recording(repetitions=1)
    imu = rec.imu()
    node = calibrator(ros, tmp_path)
    drv, imu_pub, progress = imu_player(ros, 'late_string_driver')
    sent = replay_flow(imu_pub, imu.slice(slice(0, 3000)), [], RATE,
                       lambda: progress[-1]['imu_received'], what='IMU messages')
    wait_for(lambda: progress[-1]['imu_received'] >= sent and node.k == 0, WAIT,
             'the decision without a temperature')
    warned = []
    node.get_logger().warning = warned.append
    other_participant(request, 'string_driver').create_publisher(String, 'imu/temperature', 10)
    wait_for(lambda: warned, WAIT, 'the warning')
    assert warned[0] == ('/imu/temperature is published now, after the node decided to '
                         'collect without a temperature (as std_msgs/msg/String, not one '
                         'thermal type); it is not used: restart the node to calibrate with '
                         'it'), warned
    assert node.k == 0


def test_a_late_temperature_under_another_name_is_followed_and_taken(ros, tmp_path,
                                                                     monkeypatch):
    # the IMU's driver starts publishing its temperature on /imu/temp after the node (the
    # shipped temperature_topics) decided without one: the watched input moves there by the
    # rule calibrate picks a log's temperature with (nodes/topic_follower), and is taken at
    # its first reading; the collection file names it, so a restart follows it again
    import json
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    late = _LateSession(ros, tmp_path, 'late_renamed_driver')
    node = late.node
    warned = []
    node.get_logger().warning = warned.append
    late.play_rest(late.drv.create_publisher(Temperature, '/imu/temp', 100))
    assert node.k == 1 and node.temperature_topics == ['/imu/temp']
    said = ('nothing is published on /imu/temperature; /imu/temp (sensor_msgs/msg/Temperature), '
            'published with the IMU topic by /late_renamed_driver, is the only '
            'sensor_msgs/Temperature topic it publishes: subscribed to it instead')
    assert len([w for w in warned if w.startswith(said)]) == 1, warned
    assert [w for w in warned if w.startswith('/imu/temp: the first reading came')], warned
    resp = late.calibrate()
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert [i.topic for i in cal.inputs] == ['/imu/temp']
    notes = [n for n in cal.notes if n.startswith('input: ')]
    assert [n for n in notes if n.startswith('input: ' + said)], cal.notes
    assert [n for n in notes if 'the first reading came' in n], cal.notes
    with open(tmp_path / 'collection.jsonl.inputs.json') as f:
        assert json.load(f)['temperature_topics'] == ['/imu/temp']
