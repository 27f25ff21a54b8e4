"""Live delivery of compensator_node against a plain rclpy relay at evenly paced IMU rates.

Three processes per run, all on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, the
ROS_DOMAIN_ID of the environment): this script publishes ``imu/data_raw`` (+ a 1/10-rate
``imu/temperature`` ramp) stamped with the wall clock, the device under test (DUT) subscribes
and publishes ``imu/data_compensated``, and a sink process (this script with ``--sink``)
records every message it receives. Latency = receive wall time - header stamp (both DDS
hops); the relay row is the floor any rclpy node pays.

Every stage is counted: the publisher's sent messages and its actual pacing (rate, interval
jitter, lateness), the DUT's own counters (``/diagnostics``: messages taken, published, and
DDS-reported input losses), and the sink's messages by sequence number (carried in
``orientation.x``; orientation is marked unavailable). Before each run the whole path is
warmed up: the publisher sends marked messages until the sink has received one, so a run
only starts once the DUT's output writer has matched the sink (graph settled). Every output
is checked against its input: the relay's must be unchanged, the compensator's must be
``Calibration.apply`` of it at the temperature ramp's value some age before its stamp
(interpolated or held readings); the age is solved per message and reported (p99/max), and a
message matching no age in [-1 ms, temperature_timeout] (uncompensated, compensated twice,
another message's values) is counted as ``wrong``.

DUTs: ``relay`` (subscribe, publish the same message; counters on /diagnostics) and
``compensator`` (``compensator_node`` with the simulated device's true calibration).
Default run (one command, < 5 min): both DUTs at 1, 2 and 4 kHz x ``--repeat``, a step search
for the highest rate each sustains with >= 99.9 % delivered, the compensator under cProfile at
its limit, and a flood (publisher as fast as it can).
"""

import argparse
import ctypes
import json
import os
import select
import subprocess
import sys
import tempfile
import time

import numpy as np

OUT_TOPIC = 'imu/data_compensated'
DIAG_PERIOD = 0.2           # s, DUT /diagnostics period
TEMP_EVERY = 10             # one temperature reading per this many IMU messages
T_START, T_SLOPE = 24.0, 1.0   # degC, degC/s: the temperature ramp through t0 ...
T_MIN, T_MAX = 22.0, 33.0      # degC: ... clipped inside the calibration's valid range
SUSTAINED = 99.9            # % delivered that counts as sustained
QUIET_S = 2.0               # sink: stop this long after 'sent' without a new message


def _env():
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env['ROS_DOMAIN_ID'] = env.get('ROS_DOMAIN_ID') or str(102 + os.getpid() % 100)
    return env


def _loadavg():
    with open('/proc/loadavg') as f:
        return [float(x) for x in f.read().split()[:3]]


def _fine_sleep():
    """Set this thread's timer slack to 1 ns so time.sleep wakes within ~10 us, not 50 us."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)  # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        pass


def imu_values(seq):
    """Return the raw (accel (n, 3), gyro (n, 3)) the publisher sends as message ``seq``."""
    s = np.asarray(seq, float)
    ph = (s % 997) / 997.0
    accel = np.stack([0.2 * ph - 0.1, 0.05 - 0.1 * ph, 9.81 + 0.01 * ph], 1)
    gyro = np.stack([0.01 * ph, -0.02 * ph, 0.005 + 0.0 * ph], 1)
    return accel, gyro


def temperature_at(stamp_ns, t0_ns):
    """The temperature ramp (degC) at header stamps: T_START at t0, T_SLOPE per s, clipped.

    Linear on both sides of t0 (the warm-up readings lie on it too), so a held or
    interpolated reading maps to one age along the ramp.
    """
    dt = (np.asarray(stamp_ns, np.int64) - t0_ns) / 1e9
    return np.clip(T_START + T_SLOPE * dt, T_MIN, T_MAX)


# ------------------------------------------------------------------------------ processes


def run_relay():
    """Run the pass-through relay (a DUT) with received/published counters on /diagnostics."""
    import rclpy
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from thermal_imu_calib.nodes import common
    rclpy.init()
    node = rclpy.create_node('relay')
    counts = {'received': 0, 'published': 0, 'input_lost': 0}
    pub = node.create_publisher(Imu, OUT_TOPIC, common.output_qos('reliable', 1000))

    def relay(msg):
        counts['received'] += 1
        pub.publish(msg)
        counts['published'] += 1

    def lost(info):
        counts['input_lost'] += info.total_count_change

    node.create_subscription(Imu, 'imu/data_raw', relay, common.sensor_qos(1000),
                             event_callbacks=SubscriptionEventCallbacks(message_lost=lost))
    diag = common.Diagnostics(node)
    node.create_timer(DIAG_PERIOD, lambda: diag.publish([common.diagnostic_status(
        'relay', 'relay', common.OK, 'relaying', counts)]))
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
    """Receive OUT_TOPIC and the DUT's /diagnostics; write what arrived to ``out`` (JSON).

    stdout: 'ready' once subscribed, 'warm' at the first warm-up message. stdin: 'go' (the
    measured run starts: snapshot the DUT counters), 'sent' (the publisher is done).
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from thermal_imu_calib.nodes import common
    rclpy.init()
    node = rclpy.create_node('sink')
    rows = []
    state = {'warm': False, 'diag': None, 'diag_t': 0.0}

    def cb(msg):
        now = time.time_ns()
        for m in [msg] + common.drain(sub, 1000, node):
            seq = m.orientation.x
            if seq < 0:
                if not state['warm']:
                    state['warm'] = True
                    print('warm', flush=True)
                continue
            a, g, st = m.linear_acceleration, m.angular_velocity, m.header.stamp
            rows.append((int(seq), now, st.sec * 10 ** 9 + st.nanosec, a.x, a.y, a.z,
                         g.x, g.y, g.z))

    def on_diag(msg):
        for st in msg.status:
            state['diag'] = {kv.key: kv.value for kv in st.values}
            state['diag_t'] = time.monotonic()

    sub = node.create_subscription(Imu, OUT_TOPIC, cb, common.output_qos('reliable', 10000))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    print('ready', flush=True)
    t_end = time.monotonic() + timeout
    diag_go = None
    t_sent = None
    last_n, last_change = 0, time.monotonic()
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.02)
        if select.select([sys.stdin], [], [], 0)[0]:
            cmd = sys.stdin.readline().strip()
            if cmd == 'go':
                diag_go = state['diag']
            elif cmd == 'sent':
                t_sent = time.monotonic()
        if len(rows) != last_n:
            last_n, last_change = len(rows), time.monotonic()
        if t_sent is not None and (len(rows) >= expect
                                   or time.monotonic() - last_change > QUIET_S):
            break
    # the DUT counters after the last message: a /diagnostics message published later
    t_done = time.monotonic()
    while state['diag_t'] < t_done + 0.05 and time.monotonic() < t_done + 5 * DIAG_PERIOD + 1:
        ex.spin_once(timeout_sec=0.02)
    with open(out, 'w') as f:
        json.dump({'rows': rows, 'diag_go': diag_go, 'diag_end': state['diag']}, f)
    node.destroy_node()
    rclpy.try_shutdown()


def _start(cmd, env, stdin=None):
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=stdin, text=True)


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


# ------------------------------------------------------------------------------ the source


class Source:
    """The publisher: paced IMU + temperature, warm-up, per-run bookkeeping."""

    def __init__(self, node):
        from sensor_msgs.msg import Imu, Temperature

        from thermal_imu_calib.nodes import common
        self.node = node
        self.imu_pub = node.create_publisher(Imu, 'imu/data_raw',
                                             common.output_qos('reliable', 1000))
        self.temp_pub = node.create_publisher(Temperature, 'imu/temperature', 100)
        self.msg, self.tmsg = Imu(), Temperature()
        self.msg.header.frame_id = self.tmsg.header.frame_id = 'imu_link'
        self.msg.orientation_covariance[0] = -1.0   # orientation unavailable: carries seq

    def wait_graph(self, what, timeout=30.0):
        """Wait until the DUT and the sink are in the graph."""
        deadline = time.monotonic() + timeout
        while (self.node.count_subscribers(OUT_TOPIC) < 1
               or self.imu_pub.get_subscription_count() < 1
               or self.node.count_publishers(OUT_TOPIC) < 1):
            if time.monotonic() > deadline:
                raise RuntimeError(f'{what}: the graph did not connect in {timeout:.0f} s')
            time.sleep(0.02)

    def _send(self, seq, now, t0_ns, temp):
        msg, tmsg = self.msg, self.tmsg
        if temp:
            tmsg.header.stamp.sec, tmsg.header.stamp.nanosec = divmod(now, 10 ** 9)
            tmsg.temperature = float(temperature_at(now, t0_ns))
            self.temp_pub.publish(tmsg)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10 ** 9)
        msg.orientation.x = float(seq)
        if seq >= 0:
            a, g = self._values[seq]
            msg.linear_acceleration.x, msg.linear_acceleration.y, \
                msg.linear_acceleration.z = a
            msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = g
        self.imu_pub.publish(msg)

    def warm_up(self, sink, rate, t0_ns, timeout=30.0):
        """Send marked messages at ``rate`` until the sink reports one; return how many."""
        period = 1.0 / rate
        deadline = time.monotonic() + timeout
        i = 0
        while time.monotonic() < deadline:
            self._send(-1, time.time_ns(), t0_ns, i % TEMP_EVERY == 0)
            i += 1
            if select.select([sink.stdout], [], [], period)[0]:
                line = sink.stdout.readline().strip()
                if line == 'warm':
                    return i
                if not line:
                    raise RuntimeError('the sink died during warm-up')
        raise RuntimeError(f'nothing reached the sink within {timeout:.0f} s of warm-up')

    def paced(self, n, rate, t0_ns):
        """Publish seq 0..n-1 at ``rate`` (None: as fast as possible); return send times (s)."""
        a, g = imu_values(np.arange(n))
        self._values = list(zip(a.tolist(), g.tolist()))
        sent = np.empty(n)
        period = 1.0 / rate if rate else 0.0
        perf, sleep, now_ns = time.perf_counter, time.sleep, time.time_ns
        t0 = perf() + 0.001
        for i in range(n):
            if period:
                target = t0 + i * period
                d = target - perf()
                while d > 0:
                    sleep(d)
                    d = target - perf()
            sent[i] = perf()
            self._send(i, now_ns(), t0_ns, i % TEMP_EVERY == 0)
        return sent - t0


def _pacing(sent, rate):
    """Publisher stats: achieved rate, interval p50/p99/max (us), lateness p99/max (us)."""
    iv = np.diff(sent) * 1e6
    out = {'in_per_s': (len(sent) - 1) / (sent[-1] - sent[0]) if len(sent) > 1 else 0.0,
           'interval_p50_us': float(np.percentile(iv, 50)),
           'interval_p99_us': float(np.percentile(iv, 99)),
           'interval_max_us': float(iv.max())}
    if rate:
        late = (sent - np.arange(len(sent)) / rate) * 1e6
        out['late_p99_us'] = float(np.percentile(late, 99))
        out['late_max_us'] = float(late.max())
    return out


def _cpu_s(pid):
    """User + system CPU seconds of process ``pid`` so far (None if unknown)."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return None


def _int(d, key):
    try:
        return int(float(d[key]))
    except (TypeError, KeyError, ValueError):
        return None


def measure(src, env, dut, rate, n, cal, warm_up=True, pid=None):
    """One run of n messages at ``rate`` (None: flood) through a running DUT; a result row.

    ``warm_up=False`` is the old bench's start: 1 s after the graph shows every endpoint.
    """
    load = _loadavg()
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, 'sink.json')
        sink = _start([sys.executable, os.path.abspath(__file__), '--sink', out, '--expect',
                       str(n), '--timeout', str(n / (rate or 5000) + 60)], env,
                      stdin=subprocess.PIPE)
        try:
            if sink.stdout.readline().strip() != 'ready':
                raise RuntimeError('the sink did not start: ' + sink.stdout.read()[-2000:])
            src.wait_graph(dut)
            t0_ns = time.time_ns()   # the temperature ramp runs through warm-up and run
            if warm_up:
                warm = src.warm_up(sink, min(rate or 1000.0, 1000.0), t0_ns)
                time.sleep(3 * DIAG_PERIOD)   # a DUT /diagnostics after the warm-up, then go
            else:
                warm = 0
                time.sleep(1.0)
            sink.stdin.write('go\n')
            sink.stdin.flush()
            time.sleep(0.05)
            cpu0 = _cpu_s(pid)
            sent = src.paced(n, rate, t0_ns)
            sink.stdin.write('sent\n')
            sink.stdin.flush()
            sink.wait(n / (rate or 5000) + 90)
            cpu1 = _cpu_s(pid)
        finally:
            _stop(sink)
        with open(out) as f:
            res = json.load(f)
    rows = np.asarray(res['rows'], float).reshape(-1, 9)
    seq = rows[:, 0].astype(np.int64)
    recv = rows[:, 1].astype(np.int64)
    stamp = rows[:, 2].astype(np.int64)
    uniq, first = np.unique(seq, return_index=True)
    lost = np.setdiff1d(np.arange(n), uniq)
    got = len(uniq)
    lat = (recv[first] - stamp[first]) / 1e6
    span = (recv.max() - recv.min()) / 1e9 if len(recv) > 1 else float('nan')
    row = {'dut': dut, 'rate': 'flood' if not rate else f'{rate:.0f} Hz',
           'rate_hz': rate or 0.0, 'sent': n, 'load_avg': load, 'warm_up_msgs': warm,
           **_pacing(sent, rate),
           'out_per_s': got / span if span else float('nan'),
           'received': got, 'duplicates': int(len(seq) - got),
           'delivered_pct': 100.0 * got / n,
           'lost_first_seq': int(lost[0]) if len(lost) else None,
           'lost_last_seq': int(lost[-1]) if len(lost) else None,
           'lost_bursts': int(1 + np.count_nonzero(np.diff(lost) > 1)) if len(lost) else 0,
           'lat_p50_ms': float(np.percentile(lat, 50)) if got else float('nan'),
           'lat_p99_ms': float(np.percentile(lat, 99)) if got else float('nan'),
           'lat_max_ms': float(lat.max()) if got else float('nan')}
    # DUT counters over the run (diagnostics after the warm-up -> after the last message)
    # (no /diagnostics before the run yet: the DUT had just started, count from zero)
    go, end = res['diag_go'] or {}, res['diag_end'] or {}
    row['dut_counted_from_start'] = not go
    for key in ('received', 'published', 'compensated', 'passthrough', 'dropped',
                'temperature_held', 'temperature_missing', 'input_lost'):
        a, b = _int(go, key) if go else 0, _int(end, key)
        if a is not None and b is not None:
            row[f'dut_{key}'] = b - a
    if cpu0 is not None and cpu1 is not None:
        row['dut_cpu_s'] = cpu1 - cpu0
        row['dut_cpu_us_per_msg'] = 1e6 * (cpu1 - cpu0) / max(row.get('dut_received', n), 1)
    row['wrong'], row['temperature_age_p99_ms'], row['temperature_age_max_ms'] = \
        _check_values(rows[first], t0_ns, cal, dut)
    return row


def _check_values(rows, t0_ns, cal, dut, timeout_s=1.0):
    """Check every output against its input; return (wrong count, temperature age p99/max ms).

    Relay: output == input. Compensator: output == ``cal.apply`` of the input at the ramp's
    temperature ``age`` seconds before its stamp, for some age in [-1 ms, ``timeout_s``]
    (the node interpolates readings or holds the newest one it has; the age is solved per
    message along the ramp, linearised). Anything else (uncompensated, compensated twice,
    another message's values, a temperature from outside the ramp) is ``wrong``.
    """
    if not len(rows):
        return 0, None, None
    accel_in, gyro_in = imu_values(rows[:, 0])
    out = rows[:, 3:9]
    if dut == 'relay':
        bad = ~np.isclose(out, np.hstack([accel_in, gyro_in]), 0, 1e-12).all(1)
        return int(np.count_nonzero(bad)), None, None
    stamp = rows[:, 2].astype(np.int64)

    def comp(age_s):
        t = temperature_at(stamp - (age_s * 1e9).astype(np.int64), t0_ns)[:, None]
        r = cal.apply(accel_in, gyro_in, t)
        return np.hstack([r.accel, r.gyro])
    age = np.zeros(len(rows))
    for _ in range(3):                            # Newton steps along the ramp
        at = comp(age)
        step = comp(age + 0.01) - at              # d(output) per 10 ms of age
        den = np.maximum((step * step).sum(1), 1e-300)
        age = age + 0.01 * ((out - at) * step).sum(1) / den
    ok = ((np.abs(out - comp(age)).max(1) <= 1e-8) & (age >= -1e-3) & (age <= timeout_s))
    age_ms = 1e3 * np.clip(age[ok], 0.0, None)
    return (int(np.count_nonzero(~ok)),
            float(np.percentile(age_ms, 99)) if len(age_ms) else None,
            float(age_ms.max()) if len(age_ms) else None)


# ------------------------------------------------------------------------------ the plan


class Dut:
    """A running DUT process (restarted on demand)."""

    def __init__(self, name, cmd, env, src):
        self.name, self.cmd, self.env, self.src = name, cmd, env, src
        self.proc = None

    def __enter__(self):
        self.proc = _start(self.cmd, self.env)
        return self

    def __exit__(self, *exc):
        _stop(self.proc)
        out = self.proc.stdout.read()
        if self.proc.returncode not in (0, -2, -15) and out:
            print(out[-2000:], file=sys.stderr)


def _f(x):
    return '' if x is None else f'{x:.1f}'


def _print_row(r):
    print(f'| {r["dut"]} | {r["rate"]} | {r["sent"]} | {r["in_per_s"]:.0f} | '
          f'{r["interval_p99_us"]:.0f} | {r["out_per_s"]:.0f} | {r["delivered_pct"]:.2f} | '
          f'{r.get("dut_received", "")} | {r.get("dut_published", "")} | '
          f'{r.get("dut_input_lost", "")} | {r["lost_first_seq"]}..{r["lost_last_seq"]} | '
          f'{r["wrong"]} | {_f(r.get("temperature_age_max_ms"))} | {r["lat_p50_ms"]:.2f} | '
          f'{r["lat_p99_ms"]:.2f} | '
          f'{r["load_avg"][0]:.2f} |', flush=True)


HEADER = ('| DUT | input | sent | msgs/s in | interval p99 us | msgs/s out | delivered % | '
          'DUT in | DUT out | DDS lost | lost seqs | wrong | temp. age max ms | '
          'latency p50 ms | latency p99 ms | load 1 min |\n'
          '|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|')


def search(run, rows, name, steps):
    """Highest evenly paced rate ``name`` sustains (>= SUSTAINED % delivered in every run).

    Starts from the paced runs in ``rows``: steps up through ``steps`` from the highest rate
    sustained there until one fails, then bisects twice (250 Hz grid). ``run(rate)`` returns
    a row. Returns the best rate or None.
    """
    mine = [r for r in rows if r['dut'] == name and r['rate_hz']]
    failed = [r['rate_hz'] for r in mine if r['delivered_pct'] < SUSTAINED]
    fail = min(failed) if failed else None
    passed = [r['rate_hz'] for r in mine if r['delivered_pct'] >= SUSTAINED
              and (fail is None or r['rate_hz'] < fail)]
    best = max(passed) if passed else None
    if fail is None:
        for rate in steps:
            if best is not None and rate <= best:
                continue
            if run(rate)['delivered_pct'] >= SUSTAINED:
                best = rate
            else:
                fail = rate
                break
    lo = best or 0.0
    for _ in range(2):
        if fail is None:
            break
        mid = round((lo + fail) / 2 / 250) * 250
        if mid in (lo, fail) or mid <= 0:
            break
        if run(mid)['delivered_pct'] >= SUSTAINED:
            lo = best = mid
        else:
            fail = mid
    return best


def main():
    """Run the plan; print a markdown table per stage, optionally write JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--json', help='write the results here')
    ap.add_argument('--rates', default='1000,2000,4000', help='paced rates, Hz (comma list)')
    ap.add_argument('--seconds', type=float, default=5.0, help='duration of each paced run')
    ap.add_argument('--repeat', type=int, default=3, help='runs per DUT and paced rate')
    ap.add_argument('--duts', default='relay,compensator', help='comma list of DUTs')
    ap.add_argument('--no-search', action='store_true', help='skip the max-rate search')
    ap.add_argument('--no-profile', action='store_true', help='skip the cProfile run')
    ap.add_argument('--flood', type=int, default=20000, help='messages of the flood run '
                    '(0: none)')
    ap.add_argument('--dut-args', default='', help='extra --ros-args -p settings for the '
                    'compensator, e.g. "max_batch:=50"')
    ap.add_argument('--no-warm-up', action='store_true', help='start each run 1 s after the '
                    'graph shows all endpoints (the old bench) instead of after a warm-up '
                    'message went through')
    ap.add_argument('--sink', help=argparse.SUPPRESS)
    ap.add_argument('--expect', type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument('--timeout', type=float, default=60, help=argparse.SUPPRESS)
    ap.add_argument('--relay', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.sink:
        return run_sink(args.sink, args.expect, args.timeout)
    if args.relay:
        return run_relay()

    _fine_sleep()
    env = _env()
    os.environ.update(env)
    import rclpy

    from thermal_imu_calib.sim import simulate
    rates = [float(r) for r in args.rates.split(',') if r]
    t_start = time.monotonic()
    result = {'cpus': os.cpu_count(), 'nice': os.nice(0), 'load_avg_start': _loadavg(),
              'seconds_per_run': args.seconds, 'rows': [], 'max_sustained_hz': {}}
    with tempfile.TemporaryDirectory() as tmp:
        cal = simulate('demo', 0).truth
        cal_file = cal.save(os.path.join(tmp, 'cal.yaml'))
        extra = [a for kv in args.dut_args.split() for a in ('-p', kv)]
        comp = [sys.executable, '-m', 'thermal_imu_calib.nodes.compensator', '--ros-args',
                '-p', f'calibration_file:={cal_file}', '-p', 'temperature_timeout:=1.0',
                '-p', f'diagnostics_period:={DIAG_PERIOD}', *extra]
        prof = os.path.join(tmp, 'compensator.prof')
        cmds = {'relay': [sys.executable, os.path.abspath(__file__), '--relay'],
                'compensator': comp}
        duts = [d for d in args.duts.split(',') if d]
        rclpy.init()
        node = rclpy.create_node('bench_source')
        src = Source(node)
        rows = result['rows']

        def run(d, rate, n=None, tag='paced'):
            r = measure(src, env, d.name, rate, n or int(round(rate * args.seconds)), cal,
                        not args.no_warm_up, d.proc.pid)
            r['stage'] = tag
            rows.append(r)
            _print_row(r)
            return r

        try:
            print(HEADER)
            for name in duts:
                for _ in range(args.repeat):
                    with Dut(name, cmds[name], env, src) as d:
                        for rate in rates:
                            run(d, rate)
            if not args.no_search:
                steps = [4000, 6000, 8000, 10000, 12000, 14000, 16000, 20000, 25000]
                for name in duts:
                    with Dut(name, cmds[name], env, src) as d:
                        best = search(lambda r: run(d, r, tag='search'), list(rows), name,
                                      steps)
                    result['max_sustained_hz'][name] = best
                    print(f'{name}: highest evenly paced rate with >= {SUSTAINED} % '
                          f'delivered: {best} Hz', flush=True)
            best = result['max_sustained_hz'].get('compensator')
            if 'compensator' in duts and not args.no_profile and best:
                pcmd = [sys.executable, '-m', 'cProfile', '-o', prof] + comp[1:]
                with Dut('compensator', pcmd, env, src) as d:
                    run(d, float(best), tag='profile')
                result['profile'] = _profile_summary(prof)
            if args.flood:
                for name in duts:
                    with Dut(name, cmds[name], env, src) as d:
                        run(d, None, args.flood, tag='flood')
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    result['load_avg_end'] = _loadavg()
    result['wall_s'] = time.monotonic() - t_start
    _print_summary(result)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(result, f, indent=1)
    return 0


def _profile_summary(path, top=25):
    """The top functions by own time of a cProfile dump, as (name, calls, tottime, cumtime)."""
    import pstats
    if not os.path.exists(path):
        return None
    st = pstats.Stats(path)
    total = st.total_tt
    items = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:top]

    def name(fn, line, func):
        return f'{os.path.basename(fn)}:{line}({func})'
    out = {'total_s': total, 'top_tottime': [
        {'function': name(*k), 'calls': v[1], 'tottime_s': round(v[2], 4),
         'cumtime_s': round(v[3], 4)} for k, v in items]}
    # where the node's own code spends its time (cumulative, callees included)
    ours = ('_on_imu', 'process', 'imu_to_arrays', 'write_imu', '_publish', 'drain', 'apply',
            '_take_queued_temperatures', 'resolve', 'spin_once', '_wait_for_ready_callbacks')
    out['cumtime'] = {name(*k): round(v[3], 4) for k, v in st.stats.items()
                      if k[2] in ours and ('thermal_imu_calib' in k[0] or 'rclpy' in k[0])}
    print(f'\ncProfile of the compensator at its limit (total {total:.2f} s); own time:')
    for e in out['top_tottime'][:12]:
        print(f'  {e["tottime_s"]:8.3f} s  {e["calls"]:8d}  {e["function"]}')
    print('cumulative:')
    for k, v in sorted(out['cumtime'].items(), key=lambda kv: -kv[1]):
        print(f'  {v:8.3f} s  {k}')
    return out


def _print_summary(result):
    """Median and spread of the repeated paced runs."""
    print('\n| DUT | rate | runs | delivered % (min..max) | latency p50 ms | '
          'latency p99 ms (min..max) | load 1 min |\n|---|---|---:|---|---:|---|---|')
    groups = {}
    for r in result['rows']:
        if r['stage'] == 'paced':
            groups.setdefault((r['dut'], r['rate']), []).append(r)
    summary = []
    for (dut, rate), rs in groups.items():
        d = [r['delivered_pct'] for r in rs]
        p50 = [r['lat_p50_ms'] for r in rs]
        p99 = [r['lat_p99_ms'] for r in rs]
        ld = [r['load_avg'][0] for r in rs]
        summary.append({'dut': dut, 'rate': rate, 'runs': len(rs),
                        'delivered_pct_min': min(d), 'delivered_pct_max': max(d),
                        'lat_p50_ms_median': float(np.median(p50)),
                        'lat_p99_ms_median': float(np.median(p99)),
                        'lat_p99_ms_min': min(p99), 'lat_p99_ms_max': max(p99),
                        'load_avg_1min': ld})
        print(f'| {dut} | {rate} | {len(rs)} | {min(d):.2f}..{max(d):.2f} | '
              f'{np.median(p50):.2f} | {np.median(p99):.2f} ({min(p99):.2f}..{max(p99):.2f}) '
              f'| {", ".join(f"{x:.1f}" for x in ld)} |')
    result['summary'] = summary
    print('max sustained (>= %.1f %% delivered): %s' % (SUSTAINED, result['max_sustained_hz']))


if __name__ == '__main__':
    sys.exit(main())
