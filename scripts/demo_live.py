"""Live part of `make demo`: both nodes over DDS, calibrated by a service call.

Starts the real ``bringup`` executable (compensator + calibrator in one process), replays
the simulated cold start into ``imu/data_raw`` / ``imu/temperature`` at 10x real time,
calls ``/thermal_imu_calibrator/calibrate``, then replays a second cold start of the same
device and prints the static error of ``imu/data_raw`` vs ``imu/data_compensated``.
DDS stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a private domain).
"""

import os
import signal
import subprocess
import sys
import threading
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(102 + os.getpid() % 100))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import Imu, Temperature  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.nodes.player import replay  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, 'demo_out', 'live')
RATE = 1000.0  # IMU messages per second (the recording is 100 Hz: 10x real time)


def hold_errors(rec, stamps, accel, guard_s=1.5):
    """Per simulated hold: |mean f| - g in micro-g over the samples received."""
    out = []
    for h in rec.schedule:
        m = ((stamps >= h.stamp_start_ns + guard_s * 1e9)
             & (stamps <= h.stamp_end_ns - guard_s * 1e9))
        if m.sum() > 50:
            out.append((np.linalg.norm(accel[m].mean(0)) - rec.gravity) / rec.gravity * 1e6)
    return np.array(out)


def main():
    """Run the live demo; exits non-zero when a step fails."""
    os.makedirs(OUT, exist_ok=True)
    for f in ('calibration.yaml', 'calibration.yaml.bak', 'collection.jsonl'):
        if os.path.exists(os.path.join(OUT, f)):
            os.unlink(os.path.join(OUT, f))
    exe = os.path.join(os.path.dirname(sys.executable), 'bringup')
    cmd = [exe, '--ros-args', '--log-level', 'warn',
           '-p', f'thermal_imu_calibrator:calibration_file:={OUT}/calibration.yaml',
           '-p', f'thermal_imu_calibrator:collection_file:={OUT}/collection.jsonl',
           '-p', f'thermal_imu_compensator:calibration_file:={OUT}/calibration.yaml']
    print(f'\n$ bringup --ros-args ... (ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]})',
          flush=True)
    proc = subprocess.Popen(cmd)
    rclpy.init()
    node = rclpy.create_node('demo_player')
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    received = []
    lock = threading.Lock()

    def on_comp(m):
        with lock:
            received.append((m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec,
                             m.linear_acceleration.x, m.linear_acceleration.y,
                             m.linear_acceleration.z))
    node.create_subscription(Imu, 'imu/data_compensated', on_comp, 10000)
    imu_pub = node.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = node.create_publisher(Temperature, 'imu/temperature', 100)
    client = node.create_client(Trigger, '/thermal_imu_calibrator/calibrate')
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    try:
        t_end = time.time() + 30
        while (imu_pub.get_subscription_count() < 2 or not client.service_is_ready()) \
                and time.time() < t_end:
            time.sleep(0.1)
        if not client.service_is_ready():
            sys.exit('demo: the nodes did not come up within 30 s')
        cal_run = sim.simulate('demo', 1)
        val_run = sim.simulate('demo-validation', 1)
        (_, temps), = cal_run.temperatures.items()
        print(f'replaying the cold start ({len(cal_run.imu())} Imu at {RATE:.0f} msgs/s)...',
              flush=True)
        replay(imu_pub, cal_run.imu(), [(temp_pub, temps.stamp_ns, temps.temperature)], RATE)
        time.sleep(1.0)
        print('\n$ ros2 service call /thermal_imu_calibrator/calibrate std_srvs/srv/Trigger')
        fut = client.call_async(Trigger.Request())
        t_end = time.time() + 60
        while not fut.done() and time.time() < t_end:
            time.sleep(0.05)
        if not fut.done():
            sys.exit('demo: ~/calibrate did not answer within 60 s')
        res = fut.result()
        print(f'success: {res.success}\nmessage: {res.message}')
        if not res.success:
            sys.exit('demo: calibration refused')
        time.sleep(1.0)  # the compensator picks the model up from imu/calibration
        with lock:
            received.clear()
        imu = val_run.imu()
        (_, vt), = val_run.temperatures.items()
        print(f'\nreplaying a second cold start ({len(imu)} Imu) and listening to '
              'imu/data_compensated...', flush=True)
        n = replay(imu_pub, imu, [(temp_pub, vt.stamp_ns, vt.temperature)], RATE)
        t_end = time.time() + 20
        while len(received) < n and time.time() < t_end:
            time.sleep(0.1)
        with lock:
            got = np.array(received)
        if os.environ.get('DEMO_DEBUG'):
            np.save(os.path.join(OUT, 'received.npy'), got)
        raw = hold_errors(val_run, imu.stamp_ns, imu.accel)
        comp = hold_errors(val_run, got[:, 0], got[:, 1:]) if len(got) else np.array([np.nan])
        print(f'\n{"":34s}{"imu/data_raw":>16s}{"imu/data_compensated":>22s}')
        print(f'{"messages":34s}{n:>16d}{len(got):>22d}')
        print(f'{"|mean f| - g per hold, RMS [ug]":34s}{np.sqrt(np.mean(raw ** 2)):>16.1f}'
              f'{np.sqrt(np.mean(comp ** 2)):>22.1f}')
        print(f'{"|mean f| - g per hold, max [ug]":34s}{np.max(np.abs(raw)):>16.1f}'
              f'{np.max(np.abs(comp)):>22.1f}')
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        ex.shutdown()
        spin.join(5)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
