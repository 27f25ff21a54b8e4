"""Calibrator node over real DDS: refusal, busy refusal, reset/save, kill -9 and resume.

Also the pose changes between holds (whole_unit gyro scale/misalignment): used by
``~/calibrate``, persisted, resumed after a restart, cleared on ``~/reset``.
"""

import json
import os
import signal
import subprocess
import threading

import _motion_data
from conftest import (DOMAIN_ID, other_participant, replay, replay_flow, venv_exe, wait_count,
                      wait_for)
import numpy as np

from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.collection.motion import load_transitions, save_transitions
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.nodes import common
from thermal_imu_calib.nodes.calibrator import CalibratorNode
from thermal_imu_calib.collection.feed import windows_from_columns


RATE = 2000.0     # IMU messages per second (20x the 100 Hz recordings)
# the bound of a wait on a condition: reached only when something is broken (a busy 2-core
# machine can starve a freshly started node for tens of seconds; the wait ends as soon as
# the condition holds, so a generous bound costs nothing when the path works)
WAIT = 120.0
SHORT = {'hold_s': (14.0, 15.0), 'transition_s': (1.5, 2.0)}


def recording(**overrides):
    """Return a short simulated warm-up (demo device) with the given overrides."""
    return sim.simulate('demo', 5, **{**SHORT, **overrides})


def motion_recording():
    """Return six faces and two corners up, 14-15 s holds, a scaled and misaligned gyro."""
    return _motion_data.recording('demo', 5, **SHORT, repetitions=1,
                                  faces=sim.SIX_FACES + (sim.TILTED,) * 2)


class Player:
    """A driver node publishing a recording and reading the calibrator's progress."""

    def __init__(self, ros, n_subscribers=1, temperature_topic='/imu/temperature', also=()):
        self.ros = ros
        self.node = ros.node('player')
        self.also = [self.node.create_publisher(Temperature, t, 10) for t in also]
        self.imu_pub = self.node.create_publisher(Imu, 'imu/data_raw', 1000)
        self.temp_pub = self.node.create_publisher(Temperature, temperature_topic, 100)
        self.progress = []
        self.sent = [0, 0]
        self._progress_sub = self._subscribe_progress()
        ros.wait_matched(self.imu_pub, n_subscribers, timeout=WAIT)
        ros.wait_matched(self.temp_pub, n_subscribers, timeout=WAIT)
        self.wait_connected()

    def _subscribe_progress(self):
        return self.node.create_subscription(
            String, '/thermal_imu_calibrator/progress',
            lambda m: self.progress.append(json.loads(m.data)), 10)

    def forget_progress(self):
        """Start a new progress list with a new subscription, after the calibrator restarted.

        Clearing the list is not enough: a message of the old calibrator still queued in
        the subscription would be read after it, with the old process's counts (seen once
        under load: a wait saw the count 7526 below where it started).
        """
        with self.ros.paused():             # between two spins of the harness's executor
            self.node.destroy_subscription(self._progress_sub)
            self.progress = []
            self._progress_sub = self._subscribe_progress()

    def wait_connected(self):
        """Wait until the calibrator reports it has matched our publishers (both ways)."""
        self.latest_progress(lambda p: p['imu_publishers'] >= 1
                             and min(p['temperature_publishers']) >= 1,
                             'the calibrator to match the player\'s publishers')

    def play(self, rec, i0=0, i1=None):
        """Publish IMU samples i0..i1 of ``rec`` with the temperatures of that interval."""
        imu = rec.imu()
        i1 = len(imu) if i1 is None else i1
        part = imu.slice(slice(i0, i1))
        (_, tc), = rec.temperatures.items()
        m = (tc.stamp_ns >= part.stamp_ns[0]) & (tc.stamp_ns <= part.stamp_ns[-1])
        n = replay_flow(self.imu_pub, part, [(self.temp_pub, tc.stamp_ns[m],
                                              tc.temperature[m])], RATE,
                        lambda: self.reported('imu_received'), what='the calibrator input')
        self.sent[0] += n
        self.sent[1] += int(m.sum())
        return n

    def prime(self, rec, i, timeout=WAIT):
        """Repeat IMU sample i (and the temperature before it) until the calibrator has one.

        After a restart the publisher may still be matched to the dead reader; data, not
        the match count, shows that the path to the new process works. Returns the count
        the calibrator reports, to be added to what ``play`` publishes afterwards.
        """
        imu = rec.imu().slice(slice(i, i + 1))
        (_, tc), = rec.temperatures.items()
        j = max(int(np.searchsorted(tc.stamp_ns, imu.stamp_ns[0])) - 1, 0)

        def received():
            replay(self.imu_pub, imu, [(self.temp_pub, tc.stamp_ns[j:j + 1],
                                        tc.temperature[j:j + 1])])
            return next((p for p in reversed(self.progress) if p['imu_received'] >= 1
                         and p['temperature_readings'] >= 1), None)

        wait_for(received, timeout, 'a primed sample at the calibrator', poll=0.05)

    def reported(self, key):
        """Return ``key`` of the newest progress message (0 before the first)."""
        return self.progress[-1][key] if self.progress else 0

    def wait_received(self):
        """Wait until the calibrator reports the messages published so far as received.

        Bounded by progress (``wait_count``): under load it waits as long as the count
        moves. Best effort may lose a few; what reached the calibrator is then asserted on.
        """
        imu, temps = self.sent
        wait_count(lambda: self.reported('imu_received'), imu,
                   f'{imu} IMU messages at the calibrator')
        wait_count(lambda: self.reported('temperature_readings'), temps,
                   f'{temps} temperatures at the calibrator')

    def call(self, service, timeout=180):
        """Call a Trigger service of the calibrator."""
        return self.ros.call(self.node, Trigger, f'/thermal_imu_calibrator/{service}',
                             timeout=timeout)

    def latest_progress(self, predicate, what='progress', timeout=None):
        """Wait for a progress message satisfying ``predicate``; return it."""
        def hit():
            return next((p for p in reversed(self.progress) if predicate(p)), None)
        timeout = WAIT if timeout is None else timeout
        return wait_for(hit, timeout, lambda: f'{what}; last: '
                        f'{self.progress[-1] if self.progress else "no progress message"}')


def calibrator(ros, tmp_path, **params):
    """Start an in-process calibrator writing to tmp_path."""
    defaults = {'calibration_file': str(tmp_path / 'calibration.yaml'),
                'collection_file': str(tmp_path / 'collection.jsonl'),
                'progress_period': 0.2}
    overrides = [Parameter(k, value=v) for k, v in {**defaults, **params}.items()]
    return ros.add(CalibratorNode(context=ros.context, parameter_overrides=overrides))


def test_refusal_lists_missing_faces_and_next_pose(ros, tmp_path):
    rec = recording(faces=('+z', '-z', '+z'), repetitions=1)
    calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    prog = player.latest_progress(lambda p: p['segments'] >= 2, what='two closed segments')
    assert not prog['ready'] and prog['next_pose'] in ('+x', '-x', '+y', '-y')
    assert set(prog['missing_faces']) == {'+x', '-x', '+y', '-y'}
    resp = player.call('calibrate')
    assert not resp.success
    assert resp.message.startswith('refused:')
    for face in ('+x', '-x', '+y', '-y'):
        assert face in resp.message, resp.message
    assert not os.path.exists(tmp_path / 'calibration.yaml')


def test_second_calibrate_is_refused_while_data_keeps_flowing(ros, tmp_path):
    rec = recording(repetitions=1)
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    gate, started = threading.Event(), threading.Event()
    real = node._estimate

    def slow_estimate(*args):
        started.set()
        assert gate.wait(30), 'the test never released the estimation'
        return real(*args)

    node._estimate = slow_estimate
    first = {}
    caller = threading.Thread(target=lambda: first.update(r=player.call('calibrate')))
    caller.start()
    try:
        wait_for(started.is_set, WAIT, 'the first estimation to start')
        second = player.call('calibrate')
        assert not second.success and 'already running' in second.message
        # the executor is not blocked: new samples are still taken in during the estimation
        before = node._rate.total
        extra = sim.simulate('demo', 6, **SHORT).imu().slice(slice(0, 400))
        extra.stamp_ns = extra.stamp_ns - extra.stamp_ns[0] + rec.imu().stamp_ns[-1] + 10 ** 9
        replay(player.imu_pub, extra, (), RATE)
        wait_for(lambda: node._rate.total >= before + 400, WAIT, 'samples during estimation')
        assert node.progress()['calibrating']
    finally:
        gate.set()
        caller.join(60)
    assert first['r'].success, first['r'].message
    cal = Calibration.load(tmp_path / 'calibration.yaml')
    assert cal.id in first['r'].message and 'holds' in first['r'].message


def test_calibrate_writes_bak_save_and_reset(ros, tmp_path):
    rec = recording(repetitions=1)
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    latched = []
    player.node.create_subscription(String, 'imu/calibration', latched.append,
                                    common.CALIBRATION_QOS)
    resp = player.call('save')
    assert not resp.success and 'no calibration estimated yet' in resp.message
    (tmp_path / 'calibration.yaml').write_text('previous file\n')
    player.play(rec)
    player.wait_received()
    resp = player.call('calibrate')
    assert resp.success, (resp.message, node.counts)
    assert (tmp_path / 'calibration.yaml.bak').read_text() == 'previous file\n'
    cal = Calibration.load(tmp_path / 'calibration.yaml')
    wait_for(lambda: latched, WAIT, 'the published calibration')
    assert Calibration.from_yaml(latched[-1].data).id == cal.id
    os.unlink(tmp_path / 'calibration.yaml')
    resp = player.call('save')
    assert resp.success and cal.id in resp.message
    assert Calibration.load(tmp_path / 'calibration.yaml').id == cal.id
    lines = (tmp_path / 'collection.jsonl').read_text().splitlines()
    assert len(lines) == len(node.windows) > 0
    resp = player.call('reset')
    assert resp.success and 'cleared' in resp.message
    assert not (tmp_path / 'collection.jsonl').exists()
    assert len(node.windows) == 0
    prog = player.latest_progress(lambda p: p['segments'] == 0 and p['samples'] == 0,
                                  what='progress after reset')
    assert prog['missing_faces'] == ['+x', '-x', '+y', '-y', '+z', '-z']


def _calibrator_process(tmp_path, log):
    exe = venv_exe('calibrator_node')
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    return subprocess.Popen(
        [exe, '--ros-args', '-p', f'calibration_file:={tmp_path / "calibration.yaml"}',
         '-p', f'collection_file:={tmp_path / "collection.jsonl"}',
         '-p', 'progress_period:=0.2'],
        env=env, stdout=log, stderr=subprocess.STDOUT)


def test_kill_9_and_restart_resumes_from_collection_file(ros, tmp_path):
    rec = recording(repetitions=1)
    imu = rec.imu()
    # kill in the pose change after the third hold
    mid = (rec.schedule[2].stamp_end_ns + rec.schedule[3].stamp_start_ns) // 2
    cut = int(np.searchsorted(imu.stamp_ns, mid))
    log = open(tmp_path / 'calibrator.log', 'w')
    proc = _calibrator_process(tmp_path, log)
    try:
        player = Player(ros)
        player.play(rec, 0, cut)
        player.wait_received()
        first = player.latest_progress(lambda p: p['segments'] >= 3,
                                       'three segments before the kill')
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(10) == -signal.SIGKILL
        saved = Windows.from_jsonl((tmp_path / 'collection.jsonl').read_text())
        assert len(saved.hold_ids) == first['segments'] >= 3
        player.forget_progress()
        proc = _calibrator_process(tmp_path, log)
        resumed = player.latest_progress(lambda p: True, 'progress after the restart')
        assert resumed['segments'] == first['segments'] and resumed['samples'] == 0
        assert resumed['faces_covered'] == first['faces_covered']
        player.wait_connected()
        player.prime(rec, cut)
        player.sent = [0, 0]   # the new process counts from zero (primes come on top)
        player.play(rec, cut + 1)
        player.wait_received()
        resp = player.call('calibrate')
        assert resp.success, (resp.message, player.progress[-1])
        assert f'{len(rec.schedule)} holds' in resp.message, resp.message
        total = Windows.from_jsonl((tmp_path / 'collection.jsonl').read_text())
        assert len(np.unique(total.hold)) == len(total.hold_ids) >= len(rec.schedule) - 1
        assert np.all(total.hold[:len(saved)] == saved.hold)
    finally:
        _stop(proc, log)


def _stop(proc, log):
    """Stop a node process we started (SIGINT, then SIGKILL) and close its log."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    log.close()


def _wait_processed(node, stamp_ns):
    """Wait until ``node`` has processed the sample stamped ``stamp_ns`` (and so all before).

    After ``Player.prime`` the received count includes the primes, so it cannot show that
    the last published samples have arrived; the newest processed stamp can.
    """
    wait_for(lambda: node._newest_ns == int(stamp_ns), WAIT,
             lambda: f'sample {stamp_ns} at the calibrator (newest {node._newest_ns})')


def _saved_pose_changes(tmp_path):
    tdir = tmp_path / 'collection.jsonl.transitions'
    return sorted(p.name for p in tdir.iterdir()) if tdir.exists() else []


def test_whole_unit_calibrate_uses_the_pose_changes_and_reset_clears_them(ros, tmp_path):
    rec = motion_recording()
    n = len(rec.schedule) - 1
    calibrator(ros, tmp_path, model='whole_unit', use_latitude=True, latitude=45.0)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    # the last hold is still open: the pose change into it is added by ~/calibrate
    prog = player.latest_progress(lambda p: p['pose_changes'] == n - 1,
                                  f'{n - 1} pose changes')
    assert prog['pose_changes_dropped'] == 0
    assert len(_saved_pose_changes(tmp_path)) == n - 1
    resp = player.call('calibrate')
    assert resp.success, resp.message
    assert f'{n} of {n} pose changes used for gyro scale and misalignment' in resp.message
    cal = Calibration.load(tmp_path / 'calibration.yaml')
    assert cal.gyro.kind == 'whole_unit_gyro'
    assert np.all(cal.gyro.meta()['estimated']['Omega1'])
    d = cal.fit['rotation_direction_error_deg']
    assert d['after_rms'] < d['before_rms']
    resp = player.call('reset')
    assert resp.success and f'{n - 1} pose changes' in resp.message, resp.message
    assert not (tmp_path / 'collection.jsonl.transitions').exists()
    player.latest_progress(lambda p: p['pose_changes'] == 0 and p['segments'] == 0,
                           'no pose changes after the reset')


def test_pose_changes_resume_after_restart_and_restart_with_the_timeline(ros, tmp_path):
    rec = motion_recording()
    imu = rec.imu()
    # stop in the pose change after the fifth hold (its samples are lost with the process)
    mid = (rec.schedule[4].stamp_end_ns + rec.schedule[5].stamp_start_ns) // 2
    cut = int(np.searchsorted(imu.stamp_ns, mid))
    node = calibrator(ros, tmp_path, model='whole_unit')
    player = Player(ros)
    player.play(rec, 0, cut)
    player.wait_received()
    player.latest_progress(lambda p: p['segments'] == 5 and p['pose_changes'] == 4,
                           'five holds and four pose changes before the restart')
    saved = _saved_pose_changes(tmp_path)
    assert saved == [f'{h:06d}-{h + 1:06d}.npz' for h in range(4)]
    # what a kill -9 can leave: a temporary file, a pose change whose hold was not written
    tdir = tmp_path / 'collection.jsonl.transitions'
    (tdir / '.collection-x1').write_bytes(b'partial')
    orphan = load_transitions(str(tdir / saved[-1]))[0]
    orphan.hold_from, orphan.hold_to = 4, 5
    save_transitions(str(tdir / '000004-000005.npz'), [orphan])
    ros.remove(node)
    player.forget_progress()
    node = calibrator(ros, tmp_path, model='whole_unit')
    resumed = player.latest_progress(lambda p: True, 'progress after the restart')
    assert resumed['pose_changes'] == 4 and resumed['segments'] == 5
    assert _saved_pose_changes(tmp_path) == saved
    player.wait_connected()
    player.prime(rec, cut)
    player.sent = [0, 0]
    player.play(rec, cut + 1)
    player.wait_received()
    _wait_processed(node, imu.stamp_ns[-1])
    # the pose change cut by the restart is lost; 5 -> 6 is new, 6 -> 7 waits for hold 7
    player.latest_progress(lambda p: p['pose_changes'] == 5, 'five pose changes')
    # a replay from the start (stamps jump back): hold 7 closes, its pose change is kept,
    # and the replayed holds get new ids, with pose changes between them only
    end = int(np.searchsorted(imu.stamp_ns, (rec.schedule[2].stamp_end_ns
                                             + rec.schedule[3].stamp_start_ns) // 2))
    player.play(rec, 0, end)
    player.wait_received()
    _wait_processed(node, imu.stamp_ns[end - 1])
    player.latest_progress(lambda p: p['pose_changes'] == 8, 'eight pose changes')
    assert node.counts['time_resets'] == 1
    trs = node.transitions
    assert [(t.hold_from, t.hold_to) for t in trs[-3:]] == [(6, 7), (8, 9), (9, 10)]
    assert len(_saved_pose_changes(tmp_path)) == 8
    resp = player.call('calibrate')
    assert resp.success, resp.message
    assert '8 of 8 pose changes used' in resp.message, resp.message
    assert 'stamps jumped back 1 time(s) while collecting (a recording played again, or ' \
        'another?)' in resp.message, resp.message


def test_collection_of_other_thermal_inputs_is_not_resumed(ros, tmp_path):
    # windows collected with the die temperature (degC) must not be mixed with windows whose
    # thermal column is a resonance-frequency proxy (Hz) after a reconfiguration
    rec = recording(repetitions=1)
    win = windows_from_columns(rec.imu_chunks(), rec.temperatures.values())
    assert len(win) > 0
    node = calibrator(ros, tmp_path)
    assert json.loads((tmp_path / 'collection.jsonl.inputs.json').read_text()) == {
        'temperature_topics': ['imu/temperature'], 'temperature_units': ['degC']}
    ros.remove(node)
    (tmp_path / 'collection.jsonl').write_text(win.to_jsonl())
    # same topic count, same unit: resumed
    node = calibrator(ros, tmp_path)
    assert len(node.windows) == len(win)
    ros.remove(node)
    # same topic count, other unit: set aside with the reason, a new collection
    node = calibrator(ros, tmp_path, temperature_units=['Hz'])
    assert len(node.windows) == 0
    aside = [p for p in os.listdir(tmp_path) if p.startswith('collection.jsonl.incompatible-')]
    assert any(p.endswith('.inputs.json') for p in aside)
    assert any(not p.endswith('.inputs.json') and not p.endswith('.transitions') for p in aside)
    assert json.loads((tmp_path / 'collection.jsonl.inputs.json').read_text())[
        'temperature_units'] == ['Hz']
    ros.remove(node)
    # set aside again within the same second: a new name, the first one kept (os.replace
    # overwrote it, and the pose changes' directory failed, before 2026-12-02)
    first = {p: (tmp_path / p).read_bytes() for p in aside if (tmp_path / p).is_file()}
    (tmp_path / 'collection.jsonl').write_text(win.to_jsonl())
    stamp = aside[0].split('incompatible-')[1].split('.')[0]
    for sec in range(int(stamp), int(stamp) + 120):     # every name of the next 2 minutes
        taken = tmp_path / f'collection.jsonl.incompatible-{sec}'
        if not taken.exists():
            taken.write_text('earlier\n')
    node = calibrator(ros, tmp_path)                      # degC again: other inputs
    assert len(node.windows) == 0 and not node._collection_error
    again = [p.name for p in tmp_path.glob('collection.jsonl.incompatible-*-1')]
    assert len(again) == 1, sorted(os.listdir(tmp_path))
    assert (tmp_path / again[0]).read_text() == win.to_jsonl()
    assert all((tmp_path / p).read_bytes() == b for p, b in first.items())
    ros.remove(node)


def test_bringup_process_calibrates_over_dds_and_compensates(ros, tmp_path):
    # the `bringup` console script: both nodes in one process, driven only over DDS
    rec = recording(repetitions=1)
    cal_file = tmp_path / 'calibration.yaml'
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    log = open(tmp_path / 'bringup.log', 'w')
    proc = subprocess.Popen(
        [venv_exe('bringup'), '--ros-args', '-p', f'calibration_file:={cal_file}',
         '-p', f'collection_file:={tmp_path / "collection.jsonl"}',
         '-p', 'progress_period:=0.2'], env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        player = Player(ros, n_subscribers=2)          # the compensator and the calibrator
        out = ros.collect(player.node, Imu, 'imu/data_compensated', 1000)
        player.play(rec)
        player.wait_received()
        resp = player.call('calibrate')
        assert resp.success, (resp.message, (tmp_path / 'bringup.log').read_text()[-2000:])
        cal = Calibration.load(cal_file)
        assert cal.id in resp.message
        # the compensator in the same process applies it: the newest messages come out
        # as the core computes them with that file
        tail = rec.imu().slice(slice(-50, None))
        tail.stamp_ns = tail.stamp_ns + 10 ** 9 * 5
        (_, tc), = rec.temperatures.items()

        def applied():
            out.clear()
            replay(player.imu_pub, tail, [(player.temp_pub, tc.stamp_ns[-1:] + 5 * 10 ** 9,
                                           tc.temperature[-1:])])
            wait_count(lambda: len(out), len(tail), 'compensated messages', settle=1.0,
                       loss=0.1)
            return _applied(out, tail, cal, tc)
        wait_for(applied, WAIT, 'the compensator to apply the new calibration')
    finally:
        _stop(proc, log)


def _applied(out, tail, cal, tc):
    """Return True when the messages in ``out`` are ``cal`` applied to ``tail``."""
    stamps, accel, gyro = common.imu_to_arrays(list(out))
    idx = np.searchsorted(tail.stamp_ns, stamps)
    if len(stamps) == 0 or not np.array_equal(tail.stamp_ns[idx], stamps):
        return False
    ref = cal.apply(tail.accel[idx], tail.gyro[idx],
                    np.full((len(idx), 1), tc.temperature[-1]))
    return (np.allclose(accel, ref.accel, rtol=0, atol=1e-9)
            and np.allclose(gyro, ref.gyro, rtol=0, atol=1e-12))


def _driver(ros, name, temperature_topic):
    """Return (node, IMU publisher, temperature publisher, ~/progress list) of a driver.

    Waits until the calibrator has matched the IMU publisher.
    """
    node = ros.node(name)
    imu_pub = node.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = node.create_publisher(Temperature, temperature_topic, 100)
    progress = []
    node.create_subscription(String, '/thermal_imu_calibrator/progress',
                             lambda m: progress.append(json.loads(m.data)), 10)
    ros.wait_matched(imu_pub, 1, timeout=WAIT)
    wait_for(lambda: progress and progress[-1]['imu_publishers'] >= 1, WAIT,
             'the calibrator to match the IMU publisher')
    return node, imu_pub, temp_pub, progress


def test_a_temperature_on_another_topic_is_named_in_the_refusal(ros, tmp_path, request):
    # a driver publishing its temperature as imu/temp while the shipped config listens on
    # imu/temperature: every IMU sample waits for a temperature and none is collected.
    # The answer said "no stationary segments were found. ... check the IMU topic"
    # A second driver publishes std_msgs/String on imu/temperature itself (another
    # participant, as a driver's process is): DDS never connects it; the answer says so
    # (a thermal type, std_msgs/Float32 say, would be followed: ``thermal_types``).
    from conftest import replay_flow
    rec = recording(repetitions=1, faces=('+z', '-z'))
    calib = calibrator(ros, tmp_path)
    bare = other_participant(request, 'float_driver').create_publisher(
        String, '/imu/temperature', 10)
    # something is published on imu/temperature, so /imu/temp is not followed
    # (nodes/topic_follower): seen before the driver's topics are
    wait_for(lambda: calib.get_publishers_info_by_topic('/imu/temperature'), WAIT,
             'the String publisher on the graph')
    node, imu_pub, temp_pub, progress = _driver(ros, 'driver_with_imu_temp', '/imu/temp')
    imu = rec.imu()
    (_, tc), = rec.temperatures.items()
    sent = replay_flow(imu_pub, imu, [(temp_pub, tc.stamp_ns, tc.temperature)], RATE,
                       lambda: progress[-1]['imu_received'], what='the calibrator input')
    wait_for(lambda: progress[-1]['imu_received'] >= sent
             and progress[-1]['stale_temperature_samples'] > 0, WAIT, 'the IMU messages')
    bare.publish(String(data='30.0'))
    resp = ros.call(node, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert not resp.success
    assert resp.message.startswith('refused: no temperature reading arrived on '
                                   '/imu/temperature (0 publishers)'), resp.message
    assert "thermal-input topics on the graph: /imu/temp (set temperature_topics:='[/imu/temp]')" \
        in resp.message, resp.message
    assert ('/imu/temperature is published as std_msgs/msg/String by /float_driver, not '
            'sensor_msgs/msg/Temperature, so none of it is received: publish '
            'sensor_msgs/msg/Temperature on it' in resp.message), resp.message
    assert "temperature_topics:='[]'" in resp.message
    assert not os.path.exists(tmp_path / 'calibration.yaml')


def test_a_gyro_in_deg_per_s_is_refused_as_calibrate_refuses_it(ros, tmp_path):
    # a driver publishing deg/s: the turns (up to 140 deg/s in this recording) read beyond
    # any gyroscope in rad/s; calibrate's input gate refuses the log naming the unit, and
    # ~/calibrate answers the same (before: holds lost, "faces missing"), until ~/reset
    from conftest import replay_flow
    from thermal_imu_calib.io.gate import GYRO_UNIT_ROWS
    rec = recording(repetitions=1)
    calibrator(ros, tmp_path)
    node, imu_pub, temp_pub, progress = _driver(ros, 'driver_in_deg_per_s', 'imu/temperature')
    ros.wait_matched(temp_pub, 1, timeout=WAIT)
    imu = rec.imu()
    imu = type(imu)(imu.stamp_ns, imu.accel, np.degrees(imu.gyro), imu.frame_id)
    (_, tc), = rec.temperatures.items()
    sent = replay_flow(imu_pub, imu, [(temp_pub, tc.stamp_ns, tc.temperature)], RATE,
                       lambda: progress[-1]['imu_received'], what='the calibrator input')
    wait_for(lambda: progress[-1]['imu_received'] >= sent, WAIT, 'the IMU messages')
    resp = ros.call(node, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert not resp.success
    assert resp.message.startswith('refused: '), resp.message
    assert ('beyond any gyroscope) while the accelerometer was in range: the gyro values look '
            'in deg/s, while sensor_msgs/Imu angular_velocity is in rad/s') in resp.message
    n = int(resp.message.split('refused: ')[1].split(' IMU samples')[0])
    assert n >= GYRO_UNIT_ROWS
    assert not os.path.exists(tmp_path / 'calibration.yaml')
    # ~/reset clears it with the collection: a driver fixed since is judged afresh
    assert ros.call(node, Trigger, '/thermal_imu_calibrator/reset', timeout=60).success
    again = ros.call(node, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert 'deg/s' not in again.message, again.message


def test_an_imu_on_another_topic_is_named_in_the_refusal(ros, tmp_path):
    # the driver publishes imu/data; the calibrator listens on imu/data_raw; a compensator's
    # output (also sensor_msgs/Imu) is not offered
    calibrator(ros, tmp_path, temperature_topics=[''])
    node = ros.node('driver_with_imu_data')
    pub = node.create_publisher(Imu, '/imu/data', 10)
    out = ros.node('thermal_imu_compensator').create_publisher(Imu, '/imu/data_compensated', 10)
    wait_for(lambda: {'/imu/data', '/imu/data_compensated'}
             <= set(dict(node.get_topic_names_and_types())), WAIT, 'both topics on the graph')
    pub.publish(Imu())
    out.publish(Imu())
    resp = ros.call(node, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)
    assert not resp.success
    assert resp.message.startswith(
        'refused: no IMU message arrived on /imu/data_raw (0 publishers); sensor_msgs/Imu '
        'topics on the graph: /imu/data (remap: ros2 launch ... imu_topic:=/imu/data).'), \
        resp.message


def test_use_sim_time_without_a_clock_still_collects(ros, tmp_path):
    # use_sim_time:=true with a bag played without --clock: ROS time stays 0, and the
    # node's processing and progress timers (on ROS time before 2026-11-29) never fired,
    # so nothing was taken in and no progress came. Data are timed by header stamps.
    rec = recording(repetitions=1, faces=('+z', '-z'))
    node = calibrator(ros, tmp_path, use_sim_time=True)
    assert node.get_clock().now().nanoseconds == 0
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    # every message taken in: a progress message may be sent between a batch's arrival and
    # the next processing tick (seen once in a clean clone: 17 of 3079 not yet processed),
    # so the condition is waited for, not asserted on the newest snapshot
    prog = player.latest_progress(lambda p: p['segments'] >= 1 and p['stationary']
                                  and p['samples'] >= p['imu_received'] - 10,
                                  what='a closed hold, one in progress, every message taken in')
    assert prog['imu_received'] >= player.sent[0], prog


def test_a_restart_into_another_session_does_not_merge_the_resumed_holds(ros, tmp_path):
    # the collection resumes after a restart (kill -9 test above). A recording played
    # again after a restart (stamps before the resumed holds), or another one hours or
    # days later, is a new session: the resumed holds are moved aside, not merged
    rec = recording(repetitions=1, faces=('+z', '-z', '+x'))
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    first = player.latest_progress(lambda p: p['segments'] >= 2, 'two holds')['segments']
    ros.remove(node)
    player.forget_progress()
    node = calibrator(ros, tmp_path)
    assert node.resumed_holds == first
    player.wait_connected()
    player.sent = [0, 0]
    player.play(rec)                         # the same recording again: stamps go back
    player.wait_received()
    _wait_processed(node, rec.imu().stamp_ns[-1])
    assert node.resumed_holds == 0
    aside = [p.name for p in tmp_path.iterdir() if '.previous-' in p.name]
    assert any(n.startswith('collection.jsonl.previous-') and n.count('.') == 2
               for n in aside), aside
    prog = player.latest_progress(lambda p: p['segments'] >= 2, 'the holds of the new session')
    assert prog['segments'] == first, prog
    resp = player.call('calibrate')
    assert 'resumed from' not in resp.message, resp.message


def test_a_second_recording_later_in_one_run_is_named_in_the_answer(ros, tmp_path):
    # stamps that jump ahead by hours in one run: another recording (a robot's stream does
    # not pause for hours); its holds are kept, as after a jump back, and the answer says so
    from conftest import replay_flow
    from thermal_imu_calib.io.columns import ImuColumns
    rec = recording(repetitions=1, faces=('+z', '-z', '+x', '-x', '+y', '-y'))
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    imu = rec.imu()
    (_, tc), = rec.temperatures.items()
    later = 2 * 3600 * 10 ** 9
    part = ImuColumns(imu.stamp_ns + later, imu.accel, imu.gyro, imu.frame_id)
    replay_flow(player.imu_pub, part, [(player.temp_pub, tc.stamp_ns + later,
                                        tc.temperature)], RATE,
                lambda: player.reported('imu_received') - len(imu),
                what='the second recording at the calibrator')
    _wait_processed(node, part.stamp_ns[-1])
    assert node.counts['time_gaps'] == 1 and not node.counts.get('time_resets')
    resp = player.call('calibrate')
    assert 'stamps jumped ahead by more than resume_max_gap 1 time(s) while collecting' \
        in resp.message, resp.message


def test_reset_judges_the_temperature_stamps_afresh(ros, tmp_path):
    # a driver that left its Temperature header stamp 0 (put on the IMU's clock, as
    # calibrate does) and was fixed since: after ~/reset its readings are judged again, as
    # calibrate judges each log, and keep their header stamps. Before, the choice was kept
    from conftest import imu_msg, temperature_msg
    t0 = 1_700_000_000 * 10 ** 9
    node = calibrator(ros, tmp_path)
    drv, imu_pub, temp_pub, progress = _driver(ros, 'driver_fixed_since', 'imu/temperature')
    ros.wait_matched(temp_pub, 1, timeout=WAIT)
    t0 = 1_700_000_000 * 10 ** 9
    imu_pub.publish(imu_msg(t0, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)))
    wait_for(lambda: progress[-1]['imu_received'] >= 1, WAIT, 'the first IMU message')
    temp_pub.publish(temperature_msg(0, 25.0))
    wait_for(lambda: node._clocks.choices[0].on_imu_clock is not None, WAIT, 'the choice')
    assert node._clocks.describe() == {
        'imu/temperature': "IMU's clock (header stamps 0 or on another clock)"}
    assert ros.call(drv, Trigger, '/thermal_imu_calibrator/reset', timeout=60).success
    assert node._clocks.describe() == {
        'imu/temperature': 'not chosen yet (no reading after the first IMU message)'}
    imu_pub.publish(imu_msg(t0 + 10 ** 9, (0.0, 0.0, 9.81), (0.0, 0.0, 0.0)))
    wait_for(lambda: progress[-1]['imu_received'] >= 1, WAIT, 'an IMU message after the reset')
    temp_pub.publish(temperature_msg(t0 + 10 ** 9, 25.0))
    wait_for(lambda: node._clocks.choices[0].on_imu_clock is not None, WAIT, 'the new choice')
    assert node._clocks.describe() == {'imu/temperature': 'header stamps'}


def imu_player(ros, name):
    """Return (node, IMU publisher, ~/progress list) of a driver ``name`` without a temperature.

    Waits until the calibrator has matched the publisher and reported its progress.
    """
    drv = ros.node(name)
    pub = drv.create_publisher(Imu, 'imu/data_raw', 1000)
    progress = []
    drv.create_subscription(String, '/thermal_imu_calibrator/progress',
                            lambda m: progress.append(json.loads(m.data)), 10)
    ros.wait_matched(pub, 1, timeout=WAIT)
    wait_for(lambda: progress, WAIT, 'progress')
    return drv, pub, progress


def _imu_only(ros, name, imu):
    """Replay ``imu`` (no temperature) from driver ``name``, then call ~/calibrate.

    Returns (the driver node, the response) once the calibrator reports every message.
    """
    from conftest import replay_flow
    drv, pub, progress = imu_player(ros, name)
    sent = replay_flow(pub, imu, [], RATE, lambda: progress[-1]['imu_received'],
                       what='the calibrator input')
    wait_for(lambda: progress[-1]['imu_received'] >= sent, WAIT, 'the IMU messages')
    return drv, ros.call(drv, Trigger, '/thermal_imu_calibrator/calibrate', timeout=180)


def test_no_temperature_published_collects_without_one_and_says_so(ros, tmp_path):
    # the shipped temperature_topics and nothing published on them: after the first IMU
    # messages the node collects without a temperature, as calibrate does a log without one
    # (nodes/absent_inputs), and says so in its log and in the file (a temperature
    # published afterwards: test_node_late_temperature.py)
    rec = recording(repetitions=1)
    node = calibrator(ros, tmp_path)
    drv, resp = _imu_only(ros, 'driver_without_temperature', rec.imu())
    assert resp.success, resp.message
    assert node.k == 0 and node.temperature_topics == [] and not node.temp_subs
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert cal.inputs == []
    assert [n for n in cal.notes if n.startswith('input: no temperature is published: nothing '
                                                 'on /imu/temperature')], cal.notes


def test_a_restart_without_a_temperature_resumes_its_collection(ros, tmp_path):
    # a calibrator restarted in a session where no temperature is published: the
    # collection it made without one is resumed once it has decided without one again
    # (absent_inputs.made_without); before, its inputs ([]) differed from the shipped ones
    # and the collection was moved aside
    rec = recording(repetitions=1)
    imu = rec.imu()
    cut = int(np.searchsorted(imu.stamp_ns, (rec.schedule[2].stamp_end_ns
                                             + rec.schedule[3].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path)
    _, first = _imu_only(ros, 'first_driver', imu.slice(slice(0, cut)))
    assert node.k == 0 and node.resumed_holds == 0
    held = len(node.windows.hold_ids)
    assert held >= 2, first.message
    ros.remove(node)
    node = calibrator(ros, tmp_path)
    assert node._resume_later and node.k == 1 and len(node.windows) == 0   # not yet
    _, second = _imu_only(ros, 'second_driver', imu.slice(slice(cut, None)))
    assert second.success, second.message
    assert node.k == 0 and node.resumed_holds == held
    assert f'{held} of the holds were resumed from' in second.message, second.message
    assert not list(tmp_path.glob('collection.jsonl.incompatible-*'))


def test_a_temperature_under_another_name_is_followed_and_resumed_after_a_restart(ros, tmp_path):
    # the shipped temperature_topics, nothing on imu/temperature, and the IMU's driver
    # publishing /imu/temp and /battery/temperature: the node subscribes /imu/temp (the one
    # in the IMU topic's namespace), as calibrate picks a log's temperature
    # (nodes/topic_follower); a temperature another node publishes is not a candidate. A
    # restart in that session resumes the collection (absent_inputs.made_without)
    from thermal_imu_calib.nodes import topic_follower
    motor = ros.node('motor_driver')
    motor.create_publisher(Temperature, '/motor/temperature', 10)
    rec = recording(repetitions=1)
    cut = int(np.searchsorted(rec.imu().stamp_ns, (rec.schedule[2].stamp_end_ns
                                                   + rec.schedule[3].stamp_start_ns) // 2))
    node = calibrator(ros, tmp_path)
    player = Player(ros, temperature_topic='/imu/temp', also=['/battery/temperature'])
    assert node.temperature_topics == ['/imu/temp']
    player.play(rec, 0, cut)
    player.wait_received()
    held = len(node.windows.hold_ids)
    assert held >= 2 and node.k == 1
    said = ('nothing is published on /imu/temperature; /imu/temp (sensor_msgs/msg/Temperature), '
            'published with the IMU topic by /player, is the one of its Temperature topics '
            "in the IMU topic's namespace: subscribed to it instead")
    assert [n for n in node.input_notes() if n.startswith(said)], node.input_notes()
    with open(tmp_path / 'collection.jsonl.inputs.json') as f:
        assert json.load(f)['temperature_topics'] == ['/imu/temp']
    ros.remove(node)
    node = calibrator(ros, tmp_path)
    assert node._resume_later and len(node.windows) == 0          # not yet: undecided
    player.forget_progress()
    player.sent = [0, 0]
    player.wait_connected()
    player.play(rec, cut)
    player.wait_received()
    resp = player.call('calibrate')
    assert resp.success, resp.message
    assert node.temperature_topics == ['/imu/temp'] and node.resumed_holds == held
    assert f'{held} of the holds were resumed from' in resp.message, resp.message
    assert not list(tmp_path.glob('collection.jsonl.incompatible-*'))
    cal = Calibration.load(str(tmp_path / 'calibration.yaml'))
    assert [i.topic for i in cal.inputs] == ['/imu/temp']
    assert [n for n in cal.notes if n.startswith('input: ' + said)], cal.notes
    # another node's temperature alone is not followed; a list the user set is never
    with ros.paused():      # a publisher's QoS event handlers are in the executor's wait set
        for name in ('/imu/temp', '/battery/temperature'):
            player.node.destroy_publisher(next(p for p in player.also + [player.temp_pub]
                                               if p.topic_name == name))
    wait_for(lambda: not node.get_publishers_info_by_topic('/imu/temp')
             and not node.get_publishers_info_by_topic('/battery/temperature')
             and node.get_publishers_info_by_topic('/motor/temperature'), WAIT, 'the graph')
    assert topic_follower.topic_to_follow(node, node.imu_sub, node.temp_subs[0])[0] == ''
    assert topic_follower.follows(['imu/temperature'])
    assert not topic_follower.follows(['imu/temp_die'])
    assert not topic_follower.follows(['imu/temperature', 'imu/board_temperature'])


def test_another_robots_temperature_is_not_followed(ros):
    # a player publishing two robots' topics (a multi-robot bag): robot2's calibrator
    # follows a temperature inside its namespace only (nodes/topic_follower)
    from rclpy.node import Node
    from thermal_imu_calib.nodes import topic_follower
    node = ros.add(Node('thermal_imu_calibrator', namespace='robot2', context=ros.context))
    imu_sub = node.create_subscription(Imu, 'imu/data_raw', lambda m: None, 10)
    temp_sub = node.create_subscription(Temperature, 'imu/temperature', lambda m: None, 10)
    player = ros.node('rosbag2_player')
    player.create_publisher(Imu, '/robot2/imu/data_raw', 10)
    player.create_publisher(Temperature, '/robot1/imu/temp', 10)
    wait_for(lambda: node.get_publishers_info_by_topic('/robot1/imu/temp')
             and imu_sub.get_publisher_count(), WAIT, 'the graph')
    assert topic_follower.topic_to_follow(node, imu_sub, temp_sub)[0] == ''
    player.create_publisher(Temperature, '/robot2/temperature', 10)
    wait_for(lambda: topic_follower.topic_to_follow(node, imu_sub, temp_sub)[0], WAIT,
             'the follower to see /robot2/temperature')
    assert topic_follower.topic_to_follow(node, imu_sub, temp_sub)[:3] == (
        '/robot2/temperature', 'sensor_msgs/msg/Temperature', 'only')


def test_of_several_temperatures_the_one_with_the_imus_frame_id_is_followed(ros, tmp_path):
    # a bag player publishing a robot's /temperature (the IMU's frame_id) and
    # /battery/temperature, neither in the IMU topic's namespace: calibrate picks the one
    # whose first message has the IMU's frame_id; the node probes both for theirs and
    # follows the same (nodes/topic_follower)
    from conftest import imu_msg, temperature_msg
    t0 = 1_700_000_000 * 10 ** 9
    node = calibrator(ros, tmp_path)
    player = ros.node('rosbag2_player')
    imu_pub = player.create_publisher(Imu, 'imu/data_raw', 1000)
    pubs = {t: player.create_publisher(Temperature, t, 10)
            for t in ('/temperature', '/battery/temperature')}

    def followed():
        imu_pub.publish(imu_msg(t0, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0), 'imu_link'))
        pubs['/temperature'].publish(temperature_msg(t0, 30.0, 'imu_link'))
        pubs['/battery/temperature'].publish(temperature_msg(t0, 40.0, 'battery'))
        return node.temperature_topics == ['/temperature']
    wait_for(followed, WAIT, lambda: f'the node to follow /temperature '
                                     f'({node.temperature_topics}, {node._name_follower})',
             poll=0.1)
    note = [n for n in node.input_notes() if n.startswith('nothing is published')]
    assert "is the one of its Temperature topics whose header.frame_id is the IMU " \
        "messages'" in note[0], note
    assert not [s for s in node.subscriptions if s.topic_name == '/battery/temperature']
