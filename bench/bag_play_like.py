"""Replay a log the way ``ros2 bag play`` does, into the launched calibrator; compare offline.

Usage (from the repository root; a ROS domain of your own)::

    ROS_DOMAIN_ID=83 .venv/bin/python bench/bag_play_like.py LOG --gravity G
        [--imu-topic /imu] [--rate 1] [--delay 0] [--work DIR]

``bench/live_replay.py`` waits until the node has matched its publishers and paces the
replay by the node's counts, so that every message is delivered and live can be compared
with offline to 1e-9. A user's ``ros2 bag play`` does neither: one player node publishes
every topic of the log in log order at the recorded pace (``--rate`` times faster), from
the moment its publishers exist, with the log's topic names (the IMU topic remapped to
``imu/data_raw``, as a user does; every other topic under its own name). This bench does
the same with the calibrator started as ``launch/thermal_imu_calib.launch.py`` describes
it (the shipped config, ``gravity:=G``, nothing else), then calls ``~/calibrate`` and
compares the file with ``calibrate LOG --imu-topic ... --gravity G`` (``scoreboard.compare``).
Messages published before the node has discovered the player are lost, as with ``ros2
bag play``; the node's counts (``~/progress``) say how many arrived. ``--delay`` waits
between creating the publishers and the first message, as ``ros2 bag play --delay`` does.
"""

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import live_replay  # noqa: E402
from scoreboard import compare, REL_TOL  # noqa: E402
from thermal_imu_calib.io.bag import open_log  # noqa: E402
from thermal_imu_calib.io.topics import resolve_topics  # noqa: E402


def read(log, imu_topic):
    """Return (IMU columns, {topic: TemperatureColumns}) as calibrate would pick them."""
    from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
    import numpy as np
    with open_log(log) as r:
        imu_topic, temps = resolve_topics(r, imu_topic, None)
        imus, parts = [], {t: [] for t in temps}
        for ch in r.stream(imu_topic, temps):
            imus.append(ch.imu)
            for t in temps:
                parts[t].append(ch.temps[t])
    out = {}
    for t, cols in parts.items():
        cols = [c for c in cols if len(c)]
        out[t] = TemperatureColumns(np.concatenate([c.stamp_ns for c in cols]),
                                    np.concatenate([c.temperature for c in cols]))
    return ImuColumns.concat(imus), out


def play(imu, temps, rate, domain_id, delay=0.0):
    """Publish like ``ros2 bag play``: one node, log order, the recorded pace / ``rate``.

    ``delay``: seconds between creating the publishers and the first message (``ros2 bag
    play --delay``), time for the node to discover them.
    """
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, Temperature
    from thermal_imu_calib.nodes.player import imu_msg, temperature_msg
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('rosbag2_player', context=context)
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = [node.create_publisher(Imu, '/imu/data_raw', qos)] + [
        node.create_publisher(Temperature, t, qos) for t in temps]
    events = sorted([(int(s), 0, i) for i, s in enumerate(imu.stamp_ns)] + [
        (int(s), j + 1, i) for j, tc in enumerate(temps.values())
        for i, s in enumerate(tc.stamp_ns)])
    accel, gyro, series = imu.accel.tolist(), imu.gyro.tolist(), list(temps.values())
    time.sleep(delay)
    t0, start = events[0][0], time.perf_counter()
    for stamp, k, i in events:
        delay = start + (stamp - t0) / 1e9 / rate - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        pubs[k].publish(imu_msg(stamp, accel[i], gyro[i], imu.frame_id or 'imu') if k == 0
                        else temperature_msg(stamp, float(series[k - 1].temperature[i])))
    seconds = time.perf_counter() - start
    context.try_shutdown()
    return len(events), seconds


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('log')
    ap.add_argument('--gravity', type=float, required=True)
    ap.add_argument('--imu-topic', default=None)
    ap.add_argument('--rate', type=float, default=1.0)
    ap.add_argument('--delay', type=float, default=0.0,
                    help='seconds from the publishers to the first message (ros2 bag play '
                    '--delay)')
    ap.add_argument('--work', default=None)
    a = ap.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='bagplay-')
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '0'))
    live_replay.install_cleanup()
    try:
        live_replay.check_domain(domain)
    except live_replay.DomainBusy as e:
        sys.exit(f'bag_play_like: {e}')
    off = os.path.join(work, 'offline.yaml')
    cmd = [os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib'), 'calibrate',
           a.log, '--gravity', repr(a.gravity), '-o', off]
    cmd += ['--imu-topic', a.imu_topic] if a.imu_topic else []
    import subprocess
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        sys.exit(f'bag_play_like: calibrate failed: {r.stderr[-1000:]}')
    imu, temps = read(a.log, a.imu_topic)
    node = live_replay.LiveCalibrator(os.path.join(work, 'live'), {'gravity': repr(a.gravity)},
                                      {}, domain)
    try:
        import rclpy
        from std_msgs.msg import String
        from std_srvs.srv import Trigger
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        caller = rclpy.create_node('caller', context=context)
        client = caller.create_client(Trigger, '/thermal_imu_calibrator/calibrate')
        progress = []
        caller.create_subscription(String, '/thermal_imu_calibrator/progress',
                                   lambda m: progress.append(json.loads(m.data)), 10)
        while not client.wait_for_service(timeout_sec=1.0):
            if node.dead() is not None:
                sys.exit(f'bag_play_like: the node exited: {node.log_tail(5)}')
        n, seconds = play(imu, temps, a.rate, domain, a.delay)
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor(context=context)
        end = time.monotonic() + 3.0      # the last messages through the node's queue
        while time.monotonic() < end:
            rclpy.spin_once(caller, executor=executor, timeout_sec=0.1)
        got = progress[-1] if progress else {}
        future = client.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(caller, future, executor,
                                         timeout_sec=live_replay.CALL_S)
        resp = future.result()
        context.try_shutdown()
    finally:
        node.stop()
    print(f'played {n} messages ({len(imu)} IMU, topics {["/imu/data_raw"] + list(temps)}) '
          f'in {seconds:.1f} s; the node received {got.get("imu_received")} IMU messages and '
          f'{got.get("temperature_readings")} readings (the rest published before it had '
          f'matched the player); ~/calibrate: success {resp.success}')
    print(resp.message[:600])
    with open(node.log_path) as f:
        print(''.join(x for x in f if 'WARN' in x)[:2000], end='')
    if not resp.success:
        return 1
    live = os.path.join(work, 'live', 'home', '.ros', 'thermal_imu_calib', 'calibration.yaml')
    with open(off) as f1, open(live) as f2:
        c = compare(f1.read(), f2.read())
    same = (c['same_holds'] and c['same_model'] and not c['structure']
            and c['max_rel_diff'] <= REL_TOL)
    print(f"live == offline: {same} (holds {c['same_holds']}, model {c['same_model']}, "
          f"{c['numbers_compared']} numbers, max rel {c['max_rel_diff']:.3g})")
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
