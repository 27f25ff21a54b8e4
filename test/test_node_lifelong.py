"""Lifelong mode of calibrator_node over real DDS, with a cmd_vel motion hint.

A robot-month stop commanded still (Twist zero) is collected; the next stop, during which
the command says drive (the robot is blocked), is found still by the detector but not
collected. ~/calibrate, ~/save and ~/reset keep working; ~/reset archives the lifelong store
and keeps the active calibration, and the next stop goes into the fresh store. Messages are
counted at the node, every wait is on a condition.
"""

import json
import re

from conftest import replay_flow, wait_count, wait_for
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
import numpy as np
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.nodes.calibrator import CalibratorNode
from thermal_imu_calib.sim.robot_month import robot_month

RATE = 2000.0
WAIT = 120.0


def _stops(m, n=2):
    """Return ``n`` consecutive plain stops (no push, not blocked) of 60-200 s."""
    ok = [s for s in m.stops if s.push is None and not s.blocked and 60 < s.t1 - s.t0 < 200]
    return ok[:n]


def test_holds_during_commanded_motion_are_not_collected(ros, tmp_path):
    m = robot_month(2, days=1.0)
    a, b, c, e = (m.segment(s) for s in _stops(m, 4))
    # the lifelong state of an earlier run: an active calibration (the true one)
    (tmp_path / 'life').mkdir()
    m.true_calibration(a.stop.t0).save(str(tmp_path / 'life' / 'active.yaml'))
    active_id = Calibration.load(str(tmp_path / 'life' / 'active.yaml')).id
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {
            'lifelong': True, 'lifelong_dir': str(tmp_path / 'life'),
            'cmd_vel_topic': 'cmd_vel', 'hint_timeout': 600.0, 'frame_id': 'imu_link',
            'calibration_file': str(tmp_path / 'cal.yaml'),
            'collection_file': str(tmp_path / 'collection.jsonl'),
            'progress_period': 0.2, 'report': False}.items()]))
    player = ros.node('player')
    imu_pub = player.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = player.create_publisher(Temperature, '/imu/temperature', 100)
    cmd_pub = player.create_publisher(Twist, 'cmd_vel', 10)
    progress, diags = [], []
    player.create_subscription(String, '/thermal_imu_calibrator/progress',
                               lambda msg: progress.append(json.loads(msg.data)), 10)
    player.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 10)
    logs = []
    player.create_subscription(Log, '/rosout', lambda msg: logs.append(msg.msg), 100)
    for pub in (imu_pub, temp_pub, cmd_pub):
        ros.wait_matched(pub, timeout=WAIT)
    life = node.lifelong
    assert life is not None

    def received():
        return progress[-1]['imu_received'] if progress else 0

    def play(seg, i0=0, i1=None):
        imu = seg.imu.slice(slice(i0, i1))
        tc = seg.temperature
        sel = (tc.stamp_ns >= imu.stamp_ns[0]) & (tc.stamp_ns <= imu.stamp_ns[-1])
        n = replay_flow(imu_pub, imu, [(temp_pub, tc.stamp_ns[sel], tc.temperature[sel])],
                        RATE, received, what='IMU messages at the calibrator')
        last = int(imu.stamp_ns[-1])
        wait_for(lambda: node._newest_ns is not None and node._newest_ns >= last, WAIT,
                 'the calibrator to process what was sent')
        return n

    def command(still):
        before = life.counts['hint_messages']
        msg = Twist()
        if not still:
            msg.linear.x = 0.5
        cmd_pub.publish(msg)
        wait_for(lambda: life.counts['hint_messages'] > before, WAIT, 'the cmd_vel hint')

    sent = play(a, 0, 20)                       # driving up to stop A
    command(still=True)                         # stopped: commanded still
    sent += play(a, 20)
    sent += play(b, 0, 20)                      # driving to stop B
    command(still=False)                        # the command says drive (it keeps coming)
    sent += play(b, 20)                         # ...but the robot is blocked at stop B
    sent += play(c, 0, 30)                      # driving on closes stop B's hold
    base = m.start_ns * 1e-9
    in_b = (base + b.stop.t0 - 1, base + b.stop.t1 + 1)

    def collected_b():
        w = node.windows
        return len(w) and ((w.t0 >= in_b[0]) & (w.t1 <= in_b[1])).any()
    wait_for(collected_b, WAIT, 'the detector to close stop B (the node\'s own collection)')
    wait_for(lambda: life.holds() >= 1, WAIT, 'stop A in the lifelong store')
    wait_count(received, sent, 'IMU messages at the calibrator')
    store = life.life.store.recent
    in_a = (base + a.stop.t0 - 1, base + a.stop.t1 + 1)
    assert ((store.t0 >= in_a[0]) & (store.t1 <= in_a[1])).any(), 'stop A not collected'
    assert not ((store.t0 >= in_b[0]) & (store.t1 <= in_b[1])).any(), \
        'a hold during commanded motion was collected'
    assert life.counts['holds_refused_by_hints'] >= 1
    assert life.gate.counts['windows_refused'] >= 1
    # /diagnostics carries the lifelong status with the hold count
    st = wait_for(lambda: next((s for d in reversed(diags) for s in d.status
                                if s.name.endswith('lifelong calibration')
                                and any(kv.key == 'holds_total' and int(kv.value) >= 1
                                        for kv in s.values)), None), WAIT,
                  'a lifelong diagnostics status with holds')
    values = {kv.key: kv.value for kv in st.values}
    assert int(values['holds_refused_by_hints']) >= 1
    assert np.isfinite(float(values['raw_windows']))
    assert 0.0 <= float(values['temperature_degC']) <= 40.0          # the present reading
    # the services keep working: ~/calibrate on the node's own collection (one pose, two
    # holds: an offset model), ~/save writes it
    resp = ros.call(player, Trigger, '/thermal_imu_calibrator/calibrate', timeout=WAIT)
    assert resp.success and 'offset' in resp.message, resp.message
    assert (tmp_path / 'cal.yaml').exists()
    resp = ros.call(player, Trigger, '/thermal_imu_calibrator/save', timeout=WAIT)
    assert resp.success, resp.message
    # ~/reset clears the node's collection and starts the lifelong one afresh: the store
    # moves to archive/<UTC time>/ as it was, the active calibration stays active
    holds = life.holds()
    stored = (tmp_path / 'life' / 'holds' / 'recent.jsonl').read_bytes()
    assert holds >= 1 and stored and life.life.active.id == active_id
    resp = ros.call(player, Trigger, '/thermal_imu_calibrator/reset', timeout=WAIT)
    assert resp.success and len(node.windows) == 0, resp.message
    archives = list((tmp_path / 'life' / 'archive').iterdir())
    assert len(archives) == 1 and re.fullmatch(r'\d{8}T\d{6}Z', archives[0].name)
    assert (archives[0] / 'holds' / 'recent.jsonl').read_bytes() == stored
    for text in (f'moved the {holds} hold', f'{archives[0]}/ (kept there, not deleted)',
                 f'the active calibration {active_id} stays active'):
        assert text in resp.message, resp.message
    assert life.holds() == 0 and life.life.active.id == active_id
    assert (tmp_path / 'life' / 'active.yaml').exists()
    wait_for(lambda: any(x.startswith('lifelong reset: collection restarted') and
                         str(archives[0]) in x for x in logs), WAIT, 'the reset in the log')
    # the collection goes on into the fresh store: stop C, commanded still
    command(still=True)
    sent += play(c, 30)
    sent += play(e, 0, 30)                      # driving on closes stop C's hold
    wait_for(lambda: life.holds() >= 1, WAIT, 'stop C in the fresh lifelong store')
    in_c = (base + c.stop.t0 - 1, base + c.stop.t1 + 1)
    store = life.life.store.recent
    assert ((store.t0 >= in_c[0]) & (store.t1 <= in_c[1])).all()
    assert (archives[0] / 'holds' / 'recent.jsonl').read_bytes() == stored


def test_lifelong_follows_its_temperature_under_another_name_across_a_restart(ros, tmp_path):
    # lifelong mode with the shipped temperature_topics and a driver publishing its
    # temperature on /imu/temp beside the IMU: the node follows it as the collection for
    # ~/calibrate does (nodes/topic_follower), the lifelong store collects with it and its
    # calibrations name it; a restart follows it again and resumes the node's collection
    from test_node_calibrator import calibrator, Player, recording
    params = {'lifelong': True, 'lifelong_dir': str(tmp_path / 'life'),
              'frame_id': 'imu_link', 'report': False}
    rec = recording(repetitions=1)
    cut = int(np.searchsorted(rec.imu().stamp_ns, (rec.schedule[2].stamp_end_ns
                                                   + rec.schedule[3].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path, **params)
    player = Player(ros, temperature_topic='/imu/temp')     # waits for the match
    assert node.temperature_topics == ['/imu/temp']
    # the state was loaded at start (frame_id given), its inputs named once decided
    wait_for(lambda: node.lifelong.life.topics == ['/imu/temp'], WAIT, 'the decision')
    player.play(rec, 0, cut)
    player.wait_received()
    wait_for(lambda: node.lifelong.holds() >= 2, WAIT, 'holds in the lifelong store')
    held, stored = len(node.windows.hold_ids), node.lifelong.holds()
    ros.remove(node)
    node = calibrator(ros, tmp_path, **params)
    assert node._resume_later                                # resumed once followed again
    player.forget_progress()
    player.sent = [0, 0]
    player.wait_connected()
    assert node.temperature_topics == ['/imu/temp']
    wait_for(lambda: node.resumed_holds == held, WAIT, 'the resume, once decided')
    player.play(rec, cut)
    player.wait_received()
    wait_for(lambda: node.lifelong.holds() > stored, WAIT, 'more holds in the lifelong store')
    assert node.lifelong.life.topics == ['/imu/temp']
    notes = [n for n in node.input_notes() if n.startswith('nothing is published on '
                                                           '/imu/temperature; /imu/temp')]
    assert notes, node.input_notes()


def test_lifelong_follows_a_temperature_its_driver_publishes_late_under_another_name(
        ros, tmp_path, monkeypatch):
    # lifelong mode decided without a reading (nothing published for GRACE_S after the
    # first IMU message): it collects nothing, and keeps looking; when the IMU's driver
    # starts publishing /imu/temp, the input moves there (nodes/absent_inputs.follow_late)
    # and the store collects with it
    from test_node_calibrator import calibrator, imu_player, recording
    from thermal_imu_calib.nodes import absent_inputs
    monkeypatch.setattr(absent_inputs, 'GRACE_S', 1.0)
    rec = recording(repetitions=1)
    imu = rec.imu()
    (_, tc), = rec.temperatures.items()
    cut = int(np.searchsorted(imu.stamp_ns, (rec.schedule[1].stamp_end_ns
                                             + rec.schedule[2].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path, lifelong=True, lifelong_dir=str(tmp_path / 'life'),
                      frame_id='imu_link', report=False)
    drv, imu_pub, progress = imu_player(ros, 'late_imu_driver')
    sent = replay_flow(imu_pub, imu.slice(slice(0, cut)), [], RATE,
                       lambda: progress[-1]['imu_received'], what='the first part')
    wait_for(lambda: progress[-1]['imu_received'] >= sent and node._inputs_decided, WAIT,
             'the decision without a reading')
    assert node.k == 1 and node.temperature_topics == ['imu/temperature']
    assert node.lifelong.holds() == 0
    temp_pub = drv.create_publisher(Temperature, '/imu/temp', 100)
    ros.wait_matched(temp_pub, 1, timeout=WAIT)
    assert node.temperature_topics == ['/imu/temp']
    rest = imu.slice(slice(cut, None))
    late = tc.stamp_ns >= rest.stamp_ns[0]
    sent += replay_flow(imu_pub, rest, [(temp_pub, tc.stamp_ns[late], tc.temperature[late])],
                        RATE, lambda: progress[-1]['imu_received'], what='the rest',
                        readings=lambda: progress[-1]['temperature_readings'])
    wait_for(lambda: node.lifelong.holds() >= 2, WAIT, 'holds in the lifelong store')
    assert node.lifelong.life.topics == ['/imu/temp'] and node._name_follower is None


def test_the_published_calibration_follows_the_newest_holds(ros, tmp_path):
    """``gyro_follow``: the node publishes the active model with the newest holds' gyro miss
    taken off (``gyro_ageing.offset``, format 5) on start, and again after a new hold."""
    from _robot_month import detector_windows
    from thermal_imu_calib.lifelong import follower
    from thermal_imu_calib.lifelong.store import HoldStore, StoreConfig
    from thermal_imu_calib.nodes import common
    m = robot_month(2, days=1.0)
    a, b = (m.segment(s) for s in _stops(m, 40)[-2:])     # the day's last two plain stops
    base = m.start_ns * 1e-9
    # an earlier run's state: the true model active, the holds before stop A stored
    win = detector_windows(m)
    before = win.select(win.t1 < base + a.stop.t0 - 5.0)
    life_dir = tmp_path / 'life'
    life_dir.mkdir()
    HoldStore(str(life_dir / 'holds'), 1, StoreConfig()).add(before)
    truth = m.true_calibration(a.stop.t0)
    truth.save(str(life_dir / 'active.yaml'))
    player = ros.node('player')
    latched = []
    player.create_subscription(String, 'imu/calibration', latched.append,
                               common.CALIBRATION_QOS)
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {
            'lifelong': True, 'lifelong_dir': str(life_dir), 'gyro_follow': True,
            'new_holds': 100000,                # no re-estimate running when the test ends
            'use_latitude': True, 'latitude': 45.0, 'frame_id': 'imu_link',
            'calibration_file': str(tmp_path / 'cal.yaml'),
            'collection_file': str(tmp_path / 'collection.jsonl'),
            'progress_period': 0.2, 'report': False}.items()]))
    life = node.lifelong
    first = Calibration.from_yaml(wait_for(lambda: latched and latched[-1], WAIT,
                                           'the published calibration').data)
    active = Calibration.load(str(life_dir / 'active.yaml'))
    want, rec = follower.follow(active, life.life.store.recent, active.gravity, 45.0,
                                float(before.t1.max()), 0.5, 2.0, 5.0)
    assert want is not None, rec
    np.testing.assert_allclose(first.gyro_ageing['offset'], want, rtol=1e-9)
    assert first.id == life.life.output.id != active.id
    # a new hold moves the offset: published again
    imu_pub = player.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = player.create_publisher(Temperature, '/imu/temperature', 100)
    for pub in (imu_pub, temp_pub):
        ros.wait_matched(pub, timeout=WAIT)
    progress = []
    player.create_subscription(String, '/thermal_imu_calibrator/progress',
                               lambda msg: progress.append(json.loads(msg.data)), 10)

    def received():
        return progress[-1]['imu_received'] if progress else 0
    n0, sent = life.holds(), 0
    for seg in (a, b):                         # stop A, then driving to B closes its hold
        imu = seg.imu
        tc = seg.temperature
        sel = (tc.stamp_ns >= imu.stamp_ns[0]) & (tc.stamp_ns <= imu.stamp_ns[-1])
        sent += replay_flow(imu_pub, imu, [(temp_pub, tc.stamp_ns[sel], tc.temperature[sel])],
                            RATE, received, what='IMU messages at the calibrator')
    wait_count(received, sent, 'IMU messages at the calibrator')
    wait_for(lambda: life.holds() > n0, WAIT, 'stop A in the lifelong store')
    new = wait_for(lambda: next((Calibration.from_yaml(x.data) for x in reversed(latched)
                                 if Calibration.from_yaml(x.data).id != first.id), None),
                   WAIT, 'the calibration published again after the new hold')
    assert new.id == life.life.output.id and new.gyro_ageing['offset'] is not None
    assert not np.allclose(new.gyro_ageing['offset'], first.gyro_ageing['offset'], rtol=0,
                           atol=1e-12)


def test_without_a_latitude_the_follower_publishes_only_when_told(ros, tmp_path):
    """No ``use_latitude``: the node publishes the active model as it is (the follower idle,
    said in the start-up log), or, with ``follow_without_latitude``, the model with the
    stored holds' miss in its own convention (the vertical earth rate left in the miss)."""
    from _robot_month import detector_windows
    from thermal_imu_calib.lifelong import follower
    from thermal_imu_calib.lifelong.store import HoldStore, StoreConfig
    from thermal_imu_calib.nodes import common
    m = robot_month(2, days=1.0)
    win = detector_windows(m)
    truth = m.true_calibration(m.config.days * 86400.0 / 2)
    player = ros.node('player_nl')
    logs = []
    player.create_subscription(Log, '/rosout', logs.append, 100)
    for without in (False, True):
        life_dir = tmp_path / f'life{int(without)}'
        life_dir.mkdir()
        HoldStore(str(life_dir / 'holds'), 1, StoreConfig()).add(win)
        truth.save(str(life_dir / 'active.yaml'))
        latched = []
        player.create_subscription(String, f'/nl{int(without)}/imu/calibration',
                                   latched.append, common.CALIBRATION_QOS)
        node = ros.add(CalibratorNode(
            context=ros.context, namespace=f'nl{int(without)}', parameter_overrides=[
                Parameter(k, value=v) for k, v in {
                    'lifelong': True, 'lifelong_dir': str(life_dir), 'gyro_follow': True,
                    'follow_without_latitude': without, 'new_holds': 100000,
                    'frame_id': 'imu_link', 'calibration_file': str(tmp_path / 'cal.yaml'),
                    'collection_file': str(tmp_path / f'collection{int(without)}.jsonl'),
                    'report': False}.items()]))
        got = Calibration.from_yaml(wait_for(lambda: latched and latched[-1], WAIT,
                                             'the published calibration').data)
        active = Calibration.load(str(life_dir / 'active.yaml'))
        if not without:
            assert got.id == active.id and not got.gyro_ageing
            wait_for(lambda: any('gyro follower idle' in x.msg for x in logs), WAIT,
                     'the start-up log saying the follower is idle')
            continue
        want, rec = follower.follow(active, node.lifelong.life.store.recent, active.gravity,
                                    None, float(win.t1.max()), 0.5, 2.0, 5.0, True)
        assert want is not None, rec
        np.testing.assert_allclose(got.gyro_ageing['offset'], want, rtol=1e-9)
        # the true model keeps the earth rate: its miss holds the vertical 52 urad/s
        assert 3e-5 < np.linalg.norm(want) < 1e-4, want
