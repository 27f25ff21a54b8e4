"""Compensator node throughput and added latency against a plain rclpy pass-through relay.

Three processes per run, all on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a
private ROS_DOMAIN_ID): this script publishes ``imu/data_raw`` (+ ``imu/temperature``)
stamped with the wall clock, the device under test (DUT) subscribes and publishes
``imu/data_compensated``, and a sink process (this script with ``--sink``) records the
receive time of every message. Latency = receive wall time - header stamp (publish time),
so it includes both DDS hops; the relay row is the floor any rclpy node pays.

DUTs: ``relay`` (a minimal rclpy node: subscribe, publish the same message) and
``compensator`` (``compensator_node`` with the simulated device's true calibration).
Rates: 1 kHz evenly paced, and as fast as the publisher can go.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

N_PACED = 5000       # 5 s at 1 kHz
N_MAX = 20000
OUT_TOPIC = 'imu/data_compensated'


def _env():
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env['ROS_DOMAIN_ID'] = env.get('ROS_DOMAIN_ID') or str(102 + os.getpid() % 100)
    return env


def run_relay():
    """Run the pass-through relay (a DUT)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from thermal_imu_calib.nodes import common
    rclpy.init()
    node = rclpy.create_node('relay')
    pub = node.create_publisher(Imu, OUT_TOPIC, common.output_qos('reliable', 1000))
    node.create_subscription(Imu, 'imu/data_raw', pub.publish, common.sensor_qos(1000))
    try:
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def run_sink(out, expect, timeout):
    """Receive OUT_TOPIC, write receive/stamp times to ``out`` (JSON) when done."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from thermal_imu_calib.nodes import common
    rclpy.init()
    node = rclpy.create_node('sink')
    recv, stamps = [], []

    def cb(msg):
        now = time.time_ns()
        for m in [msg] + common.drain(sub, 1000, node):
            recv.append(now)
            stamps.append(m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec)

    sub = node.create_subscription(Imu, OUT_TOPIC, cb, common.output_qos('reliable', 10000))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    print('ready', flush=True)
    t_end = time.monotonic() + timeout
    last_n, last_change = 0, time.monotonic()
    while time.monotonic() < t_end and len(recv) < expect:
        ex.spin_once(timeout_sec=0.05)
        if len(recv) != last_n:
            last_n, last_change = len(recv), time.monotonic()
        elif last_n and time.monotonic() - last_change > 3.0:
            break
    with open(out, 'w') as f:
        json.dump({'recv': recv, 'stamp': stamps}, f)
    node.destroy_node()
    rclpy.try_shutdown()


def _start(cmd, env):
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def measure(node, imu_pub, temp_pub, env, dut, rate, n):
    """Publish n messages at ``rate`` (None: max) through a running DUT; return a result row."""
    from sensor_msgs.msg import Imu, Temperature
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, 'sink.json')
        sink = _start([sys.executable, os.path.abspath(__file__), '--sink', out, '--expect',
                       str(n), '--timeout', str(n / (rate or 5000) + 30)], env)
        assert sink.stdout.readline().strip() == 'ready'
        deadline = time.monotonic() + 30
        while (node.count_subscribers(OUT_TOPIC) < 1 or imu_pub.get_subscription_count() < 1
               or node.count_publishers(OUT_TOPIC) < 1):
            if time.monotonic() > deadline:
                raise RuntimeError(f'{dut}: the graph did not connect')
            time.sleep(0.05)
        time.sleep(1.0)  # let both matches settle before counting losses
        msg, tmsg = Imu(), Temperature()
        msg.header.frame_id = tmsg.header.frame_id = 'imu_link'
        msg.orientation_covariance[0] = -1.0
        msg.linear_acceleration.z = 9.81
        tmsg.temperature = 30.0
        period = 1.0 / rate if rate else 0.0
        t0 = time.perf_counter()
        for i in range(n):
            if period:
                delay = t0 + i * period - time.perf_counter()
                if delay > 0.0002:
                    time.sleep(delay)
            now = time.time_ns()
            if i % 10 == 0:
                tmsg.header.stamp.sec, tmsg.header.stamp.nanosec = divmod(now, 10 ** 9)
                temp_pub.publish(tmsg)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10 ** 9)
            imu_pub.publish(msg)
        t_pub = time.perf_counter() - t0
        sink.wait(n / (rate or 5000) + 60)
        with open(out) as f:
            res = json.load(f)
    recv = np.asarray(res['recv'], np.int64)
    lat = (recv - np.asarray(res['stamp'], np.int64)) / 1e6
    got = len(recv)
    span = (recv.max() - recv.min()) / 1e9 if got > 1 else float('nan')
    return {'dut': dut, 'rate': 'max' if not rate else f'{rate:.0f} Hz', 'sent': n,
            'in_per_s': n / t_pub, 'out_per_s': got / span if span else float('nan'),
            'received': got, 'loss_pct': 100.0 * (n - got) / n,
            'lat_p50_ms': float(np.percentile(lat, 50)) if got else float('nan'),
            'lat_p99_ms': float(np.percentile(lat, 99)) if got else float('nan')}


def main():
    """Run both DUTs at both rates; print a markdown table, optionally write JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--json', help='write the results here')
    ap.add_argument('--sink', help=argparse.SUPPRESS)
    ap.add_argument('--expect', type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument('--timeout', type=float, default=60, help=argparse.SUPPRESS)
    ap.add_argument('--relay', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--n-max', type=int, default=N_MAX, help='messages in the max-rate run')
    args = ap.parse_args()
    if args.sink:
        return run_sink(args.sink, args.expect, args.timeout)
    if args.relay:
        return run_relay()

    env = _env()
    os.environ.update(env)
    import rclpy
    from sensor_msgs.msg import Imu, Temperature

    from thermal_imu_calib.nodes import common
    from thermal_imu_calib.sim import simulate
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cal = simulate('demo', 0).truth
        cal_file = cal.save(os.path.join(tmp, 'cal.yaml'))
        comp_exe = os.path.join(os.path.dirname(sys.executable), 'compensator_node')
        duts = {'relay': [sys.executable, os.path.abspath(__file__), '--relay'],
                'compensator': [comp_exe, '--ros-args', '-p', f'calibration_file:={cal_file}',
                                '-p', 'temperature_timeout:=1.0']}
        rclpy.init()
        node = rclpy.create_node('bench_source')
        imu_pub = node.create_publisher(Imu, 'imu/data_raw', common.output_qos('reliable', 1000))
        temp_pub = node.create_publisher(Temperature, 'imu/temperature', 100)
        try:
            for dut, cmd in duts.items():
                proc = _start(cmd, env)
                try:
                    for rate, n in ((1000.0, N_PACED), (None, args.n_max)):
                        rows.append(measure(node, imu_pub, temp_pub, env, dut, rate, n))
                finally:
                    _stop(proc)
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    print('| DUT | input | sent | msgs/s in | msgs/s out | loss % | latency p50 ms | '
          'latency p99 ms |')
    print('|---|---|---:|---:|---:|---:|---:|---:|')
    for r in rows:
        print(f'| {r["dut"]} | {r["rate"]} | {r["sent"]} | {r["in_per_s"]:.0f} | '
              f'{r["out_per_s"]:.0f} | {r["loss_pct"]:.2f} | {r["lat_p50_ms"]:.3f} | '
              f'{r["lat_p99_ms"]:.3f} |')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'rows': rows, 'cpus': os.cpu_count()}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
