"""A temperature first published after the calibrator decided without one (real DDS).

``nodes/late_inputs``: the node, with the shipped ``temperature_topics`` and nothing on them
for ``absent_inputs.GRACE_S`` after the first IMU message, collects without a temperature;
a driver that starts publishing it later is taken at its first reading, as ``calibrate``
takes a log's late temperature (the IMU samples more than ``temperature_timeout`` before
it are not collected). Live against offline on a real recording is
``test_live_offline.py``'s ``late_temperature`` case; here the mechanics: the inputs come
back, the collection made without them is moved aside, the file's note says what
happened, a snapshot taken before the first reading works, and a publisher of another
type is still only named.
"""

from conftest import replay_flow, wait_for
import numpy as np
from sensor_msgs.msg import Temperature
from std_msgs.msg import Float32
from std_srvs.srv import Trigger
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.nodes import absent_inputs
from test_node_calibrator import calibrator, imu_player, RATE, recording, WAIT

#: a shorter wait before deciding without a temperature (the node reads it at each tick)
GRACE_S = 1.0


def test_a_temperature_published_late_is_taken_from_its_first_reading(ros, tmp_path,
                                                                      monkeypatch):
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    rec = recording(repetitions=2)      # the faces of the first round before the readings
    imu = rec.imu()
    (_, tc), = rec.temperatures.items()
    cut = int(np.searchsorted(imu.stamp_ns, (rec.schedule[1].stamp_end_ns
                                             + rec.schedule[2].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path)
    drv, imu_pub, progress = imu_player(ros, 'late_driver')
    sent = replay_flow(imu_pub, imu.slice(slice(0, cut)), [], RATE,
                       lambda: progress[-1]['imu_received'], what='the first part')
    wait_for(lambda: progress[-1]['imu_received'] >= sent and node.k == 0
             and progress[-1]['samples'] > 0, WAIT, 'the decision without a temperature')
    held = len(node.windows.hold_ids)
    assert held >= 1 and node._late_inputs is not None
    # an estimate while the shadow aligner is under the node's (its snapshot copies it):
    # answered (a refusal or not), and nothing raised (the ``ros`` fixture checks)
    assert ros.call(drv, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180).message
    warned = []
    node.get_logger().warning = warned.append
    temp_pub = drv.create_publisher(Temperature, 'imu/temperature', 100)
    ros.wait_matched(temp_pub, 1, timeout=WAIT)
    rest = imu.slice(slice(cut, None))
    late = tc.stamp_ns >= rest.stamp_ns[0]
    sent += replay_flow(imu_pub, rest, [(temp_pub, tc.stamp_ns[late], tc.temperature[late])],
                        RATE, lambda: progress[-1]['imu_received'], what='the second part',
                        readings=lambda: progress[-1]['temperature_readings'])
    wait_for(lambda: progress[-1]['imu_received'] >= sent, WAIT, 'every IMU message')
    assert node.k == 1 and node.temperature_topics == ['imu/temperature']
    said = [w for w in warned if w.startswith('/imu/temperature: the first reading came')]
    assert len(said) == 1 and 'moved to' in said[0], warned
    assert not [w for w in warned if 'it is not used' in w], warned
    aside = [p for p in tmp_path.glob('collection.jsonl.without_temperature-*')
             if p.suffix not in ('.transitions', '.json')]
    assert len(aside) == 1 and aside[0].read_text().count('\n') >= held, aside

    resp = ros.call(drv, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert len(cal.inputs) == 1
    notes = [n for n in cal.notes if n.startswith('input: ')]
    assert [n for n in notes if 'the first reading came' in n], cal.notes
    assert not [n for n in notes if 'no temperature is published' in n], cal.notes
    # nothing collected from before the readings, but what calibrate keeps of a log whose
    # temperature starts there: samples at most temperature_timeout before the first one
    t_first = tc.stamp_ns[late][0] * 1e-9
    assert node.windows.t0.min() >= t_first - node.temperature_timeout
    assert len(node.windows.hold_ids) >= 2


def test_a_late_publisher_of_another_type_is_named_not_taken(ros, tmp_path, monkeypatch,
                                                             request):
    import rclpy
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    rec = recording(repetitions=1)
    imu = rec.imu()
    node = calibrator(ros, tmp_path)
    drv, imu_pub, progress = imu_player(ros, 'late_float_driver')
    sent = replay_flow(imu_pub, imu.slice(slice(0, 3000)), [], RATE,
                       lambda: progress[-1]['imu_received'], what='IMU messages')
    wait_for(lambda: progress[-1]['imu_received'] >= sent and node.k == 0, WAIT,
             'the decision without a temperature')
    warned = []
    node.get_logger().warning = warned.append
    # another participant, as a driver's process is (one participant refuses a second type
    # on a topic it has)
    context = rclpy.Context()
    rclpy.init(context=context)
    request.addfinalizer(context.try_shutdown)
    other = rclpy.create_node('float_driver', context=context)
    request.addfinalizer(other.destroy_node)
    other.create_publisher(Float32, 'imu/temperature', 10)
    wait_for(lambda: warned, WAIT, 'the warning')
    assert warned[0] == ('/imu/temperature is published now, after the node decided to '
                         "collect without a temperature, as another type than the input's; "
                         'it is not used: restart the node to calibrate with it'), warned
    assert node.k == 0


class _ZeroStamps:
    """A publisher whose messages leave with header stamp 0 (published in stamp order)."""

    def __init__(self, pub):
        self.pub = pub

    def publish(self, msg):
        msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0
        self.pub.publish(msg)


def test_a_late_temperature_stamped_0_goes_on_the_imus_clock(ros, tmp_path, monkeypatch):
    # a late driver that leaves its header stamps 0: taken, and its readings put on the
    # IMU's clock as for any input stamped so (io.headerless.StampChoice); the node kept no
    # IMU history meanwhile, so only readings after the next IMU message are placed
    monkeypatch.setattr(absent_inputs, 'GRACE_S', GRACE_S)
    rec = recording(repetitions=2)
    imu = rec.imu()
    (_, tc), = rec.temperatures.items()
    cut = int(np.searchsorted(imu.stamp_ns, (rec.schedule[1].stamp_end_ns
                                             + rec.schedule[2].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path)
    drv, imu_pub, progress = imu_player(ros, 'late_zero_driver')
    sent = replay_flow(imu_pub, imu.slice(slice(0, cut)), [], RATE,
                       lambda: progress[-1]['imu_received'], what='the first part')
    wait_for(lambda: progress[-1]['imu_received'] >= sent and node.k == 0, WAIT,
             'the decision without a temperature')
    temp_pub = drv.create_publisher(Temperature, 'imu/temperature', 100)
    ros.wait_matched(temp_pub, 1, timeout=WAIT)
    rest = imu.slice(slice(cut, None))
    late = tc.stamp_ns >= rest.stamp_ns[0]
    sent += replay_flow(imu_pub, rest, [(_ZeroStamps(temp_pub), tc.stamp_ns[late],
                                         tc.temperature[late])],
                        RATE, lambda: progress[-1]['imu_received'], what='the second part',
                        readings=lambda: progress[-1]['temperature_readings'])
    wait_for(lambda: progress[-1]['imu_received'] >= sent, WAIT, 'every IMU message')
    assert node.k == 1 and node._clocks.bare == [True]
    resp = ros.call(drv, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert resp.success, resp.message
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert len(cal.inputs) == 1 and cal.valid_range is not None
    assert [n for n in cal.notes if 'the first reading came' in n], cal.notes
