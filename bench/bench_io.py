"""Benchmark log I/O: read, calibrate-read, compensate and write next to reference loops.

On one log (by default a simulated ``nav-coldstart``: 2.5 h of a 100 Hz IMU, 0.93 M Imu +
0.28 M Temperature messages; or ``--log`` with ``--calibration``), measures in the same
run, each stage with wall and CPU (process) time, messages/s and MB/s of the input file:

* ``mcap library raw loop``: ``mcap.reader`` ``iter_messages`` over every message (the
  practical limit of a per-message Python reader);
* ``rosbags AnyReader + deserialize_cdr``: the plain rosbags loop every comparison is
  made against;
* ``bulk read (chunks)``: ``io.mcap_read`` decompress + CRC + parse every message record;
* ``stream Imu+temperature``: ``LogReader.stream`` to IMU/temperature columns;
* ``calibrate read+detect+collect``: ``app.collect.collect_windows(motion=True)``, what
  ``calibrate`` does before fitting;
* ``compensate end to end``: ``app.compensate.compensate_log`` (read, copy every message,
  compensate, write a bare .mcap);
* ``write (LogWriter.write_many)`` vs ``mcap library add_message``: the Imu messages
  written again.

``--repeat N`` measures the bulk-read, stream and calibrate-collect stages N times and
keeps the run with the least CPU time (the machine is shared: other processes only ever
add to it).  ``--e2e N`` also runs, N times in turn, each in a fresh process (CPU = user +
sys from ``getrusage``): a plain rosbags raw iteration (``Reader.messages()``, no
decoding), ``thermal-imu-calib calibrate --model field`` and ``--model auto`` (with
``--prior`` when ``LOG.prior.yaml`` exists), and reports each one's least CPU time and the
ratios to the rosbags iteration.

``--stages`` splits the calibrate-collect stage by component (CPU of the reader, input
gate, temperature aligner, stationary detector and pose-change collector, one run each).

``--rss-messages N`` also writes an N-message log (1 kHz Imu + 10 Hz temperature) and
reports the peak RSS of ``calibrate``-style reading and of ``compensate`` on it, each in a
fresh process.  Run: ``python bench/bench_io.py [--json out.json] [--rss-messages 10000000]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _rosbags_loop(path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    store = get_typestore(Stores.ROS2_JAZZY)
    n = 0
    with AnyReader([Path(path)], default_typestore=store) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def _mcap_loop(path):
    from mcap.reader import make_reader

    n = 0
    with open(path, 'rb') as f:
        for _ in make_reader(f).iter_messages(log_time_order=True):
            n += 1
    return n


def _bulk_loop(path):
    from thermal_imu_calib.io.mcap_read import iter_batches, McapBulkReader

    with McapBulkReader(path) as r:
        return sum(len(b) for b in iter_batches(r))


def _stream(path, imu, temps):
    from thermal_imu_calib.io.bag import open_log

    with open_log(path) as log:
        return sum(len(c) for c in log.stream(imu, temps))


def _topics(path):
    from thermal_imu_calib.io.bag import open_log

    with open_log(path) as log:
        types = log.topic_types()
        count = log.message_count
    imu = [t for t, ty in types.items() if ty == 'sensor_msgs/msg/Imu'][0]
    temps = sorted(t for t, ty in types.items() if ty == 'sensor_msgs/msg/Temperature')
    return imu, temps, count


def _best(fn, repeat):
    """Run ``fn`` ``repeat`` times; return (result, wall, cpu) of the least-CPU run."""
    runs = [_timed(fn) for _ in range(max(1, repeat))]
    return min(runs, key=lambda r: r[2])


def run(path, calibration, tmp, repeat=1) -> dict:
    """Measure every stage on ``path``; returns {stage: figures}."""
    from thermal_imu_calib.calibration import Calibration
    from thermal_imu_calib.io.bag import open_log
    from thermal_imu_calib.io.bag_writer import LogWriter
    from thermal_imu_calib.app.collect import collect_windows
    from thermal_imu_calib.app.compensate import compensate_log

    imu, temps, total = _topics(path)
    size_mb = os.path.getsize(path) / 1e6
    out: dict[str, dict] = {}

    def record(name, n, wall, cpu, mb=size_mb):
        out[name] = {'messages': n, 'wall_s': wall, 'cpu_s': cpu, 'msgs_per_s': n / wall,
                     'msgs_per_cpu_s': n / max(cpu, 1e-9), 'MB_per_s': mb / wall}

    n, w, c = _timed(lambda: _mcap_loop(path))
    record('mcap library raw loop', n, w, c)
    n, w, c = _timed(lambda: _rosbags_loop(path))
    record('rosbags AnyReader + deserialize_cdr', n, w, c)
    n, w, c = _best(lambda: _bulk_loop(path), repeat)
    record('bulk read (chunks, all messages)', n, w, c)
    n, w, c = _best(lambda: _stream(path, imu, temps), repeat)
    record('stream Imu+temperature (Imu msgs)', n, w, c)
    col, w, c = _best(lambda: collect_windows(path, imu, temps, motion=True, progress=False),
                      repeat)
    record('calibrate read+detect+collect (Imu msgs)', col.imu_messages, w, c)
    cal = Calibration.load(calibration)
    dst = Path(tmp) / 'compensated.mcap'
    _, w, c = _timed(lambda: compensate_log(path, dst, cal, imu, progress=False))
    record('compensate end to end (all msgs)', total, w, c)
    with open_log(path) as log:
        raws = [(t, raw) for _, _, t, raw in log.iter_raw([imu])]
    times = [t for t, _ in raws]
    data = [r for _, r in raws]
    mb = sum(map(len, data)) / 1e6

    def ours():
        with LogWriter(Path(tmp) / 'w1.mcap', overwrite=True) as wr:
            wr.add_topic(imu, 'sensor_msgs/msg/Imu')
            wr.write_many(imu, times, data)

    def library():
        from mcap.writer import CompressionType, Writer
        with open(Path(tmp) / 'w2.mcap', 'wb') as f:
            wr = Writer(f, compression=CompressionType.NONE)
            wr.start(profile='ros2', library='bench')
            sid = wr.register_schema('sensor_msgs/msg/Imu', 'ros2msg', b'')
            cid = wr.register_channel(imu, 'cdr', sid)
            for seq, (t, raw) in enumerate(zip(times, data)):
                wr.add_message(cid, log_time=t, data=raw, publish_time=t, sequence=seq)
            wr.finish()
    _, w, c = _timed(ours)
    record('write Imu (LogWriter.write_many)', len(data), w, c, mb)
    _, w, c = _timed(library)
    record('write Imu (mcap library add_message)', len(data), w, c, mb)
    return out


def collect_stages(path, imu, temps) -> dict:
    """CPU seconds per component of ``collect_windows(motion=True)`` (one run)."""
    from thermal_imu_calib.app import collect
    from thermal_imu_calib.collection import motion, stationary
    from thermal_imu_calib.io import align, bag, gate

    acc = dict.fromkeys(('read', 'gate', 'align', 'detector', 'motion+detector'), 0.0)
    saved = []

    def wrap(owner, name, key):
        f = getattr(owner, name)
        saved.append((owner, name, f))

        def timed(*a, **k):
            c = time.process_time()
            try:
                return f(*a, **k)
            finally:
                acc[key] += time.process_time() - c
        setattr(owner, name, timed)

    def stream(self, *a, **k):
        it = stream_orig(self, *a, **k)
        while True:
            c = time.process_time()
            try:
                x = next(it)
            except StopIteration:
                return
            finally:
                acc['read'] += time.process_time() - c
            yield x
    stream_orig = bag.LogReader.stream
    saved.append((bag.LogReader, 'stream', stream_orig))
    bag.LogReader.stream = stream
    wrap(align.StreamAligner, 'push', 'align')
    wrap(gate.InputGate, 'push', 'gate')
    for name in ('update', 'finish'):
        wrap(stationary.StationaryDetector, name, 'detector')
        wrap(motion.MotionCollector, name, 'motion+detector')
    try:
        c = time.process_time()
        collect.collect_windows(path, imu, temps, motion=True, progress=False)
        acc['total'] = time.process_time() - c
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
    acc['motion (besides the detector)'] = acc.pop('motion+detector') - acc['detector']
    return acc


_ROSBAGS_RAW = ("from rosbags.rosbag2 import Reader; import sys; r = Reader(sys.argv[1]); "
                "r.open(); print(sum(1 for _ in r.messages()))")


def _child_cpu(cmd) -> tuple[float, float]:
    """Run ``cmd`` to completion; return (wall s, CPU s = user + sys of the child)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def end_to_end(path, tmp, repeat) -> dict:
    """CPU of rosbags' raw iteration and of ``calibrate --model field|auto``, in turn."""
    script = os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib')
    cli = ([script] if os.path.exists(script) else
           [sys.executable, '-m', 'thermal_imu_calib.cli.entry']) + ['calibrate', str(path)]
    if os.path.exists(f'{path}.prior.yaml'):
        cli += ['--prior', f'{path}.prior.yaml']
    raw = [sys.executable, '-c', _ROSBAGS_RAW, str(path)]
    cmds = {'rosbags raw iteration (Reader.messages())': raw}
    for model in ('field', 'auto'):
        cmds[f'calibrate --model {model}'] = cli + ['--model', model, '-o',
                                                    str(Path(tmp) / f'e2e_{model}.yaml')]
    runs: dict[str, list] = {k: [] for k in cmds}
    for _ in range(max(1, repeat)):
        for name, cmd in cmds.items():
            out = cmd[-1] if name.startswith('calibrate') else None
            if out and os.path.exists(out):
                os.unlink(out)
            runs[name].append(_child_cpu(cmd))
    res = {k: {'wall_s': min(v, key=lambda r: r[1])[0], 'cpu_s': min(r[1] for r in v),
               'cpu_s_all': [r[1] for r in v], 'wall_s_all': [r[0] for r in v],
               'cpu_s_median': float(np.median([r[1] for r in v])),
               'wall_s_median': float(np.median([r[0] for r in v]))}
           for k, v in runs.items()}
    ref = res['rosbags raw iteration (Reader.messages())']['cpu_s']
    ref_med = res['rosbags raw iteration (Reader.messages())']
    for v in res.values():
        v['cpu_over_rosbags_raw'] = v['cpu_s'] / ref
        v['median_cpu_over_rosbags_raw'] = v['cpu_s_median'] / ref_med['cpu_s_median']
        v['median_wall_over_rosbags_raw'] = v['wall_s_median'] / ref_med['wall_s_median']
    return res


_RSS_CHILD = r'''
import sys, time
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.app.collect import collect_windows
from thermal_imu_calib.app.compensate import compensate_log
what, path, cal, dst = sys.argv[1:5]
t = time.perf_counter()
if what == 'calibrate':
    c = collect_windows(path, '/imu', ['/temp'], motion=True, progress=False)
    n = c.imu_messages
else:
    n = compensate_log(path, dst, Calibration.load(cal), '/imu', progress=False)['copied']
hwm = [int(x.split()[1]) for x in open('/proc/self/status') if x.startswith('VmHWM')][0]
print(n, time.perf_counter() - t, time.process_time(), hwm)
'''


def rss(n_messages: int, tmp: str, calibration: str) -> dict:
    """Write an ``n_messages`` log (1 kHz Imu, 10 Hz temperature); peak RSS of each stage."""
    from thermal_imu_calib.io.bag_writer import write_columns
    from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

    path = Path(tmp) / 'big.mcap'
    n_imu = n_messages * 100 // 101
    step = 200_000

    def imu_chunks():
        rng = np.random.default_rng(0)
        for i in range(0, n_imu, step):
            k = min(step, n_imu - i)
            st = 1_700_000_000_000_000_000 + (i + np.arange(k, dtype=np.int64)) * 1_000_000
            acc = np.tile([0.0, 0.0, 9.81], (k, 1)) + 1e-3 * rng.normal(size=(k, 3))
            yield ImuColumns(st, acc, 1e-4 * rng.normal(size=(k, 3)), 'imu_link')

    def temp_chunks():
        for i in range(0, n_imu, step):
            st = 1_700_000_000_000_000_000 + np.arange(i, min(i + step, n_imu), 100,
                                                       dtype=np.int64) * 1_000_000
            yield TemperatureColumns(st, 25.0 + 1e-9 * (st - st[0]), 'imu_link')
    _, w, _ = _timed(lambda: write_columns(path, '/imu', imu_chunks(), {'/temp': temp_chunks()}))
    out = {'messages': n_imu + (n_imu + 99) // 100, 'file_MB': os.path.getsize(path) / 1e6,
           'write_wall_s': w}
    for what in ('calibrate', 'compensate'):
        res = subprocess.run([sys.executable, '-c', _RSS_CHILD, what, str(path), calibration,
                              str(Path(tmp) / 'big_out.mcap')], capture_output=True, text=True,
                             check=True)
        n, wall, cpu, kb = res.stdout.split()
        out[what] = {'messages': int(n), 'wall_s': float(wall), 'cpu_s': float(cpu),
                     'peak_rss_MB': int(kb) / 1024}
        if os.path.exists(Path(tmp) / 'big_out.mcap'):
            os.unlink(Path(tmp) / 'big_out.mcap')
    return out


def _rss_calibration(tmp: str) -> str:
    """A calibration for topic /temp (the field model of a simulated device)."""
    from thermal_imu_calib import sim
    from thermal_imu_calib.calibration import Calibration

    log = os.path.join(tmp, 'rsscal.mcap')
    sim.write_scenario(log, 'demo', 0)
    cal = Calibration.load(log + '.truth.yaml')
    for inp in cal.inputs:
        inp.topic = '/temp'
    path = os.path.join(tmp, 'rss_cal.yaml')
    cal.save(path)
    return path


def main(argv=None) -> int:
    """Print the table (and write JSON)."""
    ap = argparse.ArgumentParser(description='log I/O benchmark (docs/speed.md)')
    ap.add_argument('--log', help='an existing log (default: simulate --scenario)')
    ap.add_argument('--calibration', help='calibration for compensate (default: the '
                    "simulation's truth)")
    ap.add_argument('--scenario', default='nav-coldstart')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--rss-messages', type=int, default=0,
                    help='also measure peak RSS on a log of this many messages')
    ap.add_argument('--repeat', type=int, default=1,
                    help='measure the read/stream/calibrate-collect stages this many times, '
                    'keep the least CPU')
    ap.add_argument('--e2e', type=int, default=0, metavar='N',
                    help='also time rosbags raw iteration and calibrate field/auto N times '
                    'each, in turn, in fresh processes')
    ap.add_argument('--stages', action='store_true',
                    help='also split calibrate read+detect+collect by component')
    ap.add_argument('--json', help='write the figures here')
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits
    threadpool_limits(1, 'blas')
    with tempfile.TemporaryDirectory() as tmp:
        path, cal = args.log, args.calibration
        if path is None:
            from thermal_imu_calib import sim
            path = os.path.join(tmp, 'log.mcap')
            sim.write_scenario(path, args.scenario, args.seed)
            cal = cal or path + '.truth.yaml'
        if cal is None:
            ap.error('--calibration is needed with --log')
        figures = {'log': str(args.log or f'{args.scenario} seed {args.seed}'),
                   'file_MB': os.path.getsize(path) / 1e6, 'repeat': args.repeat,
                   'stages': run(path, cal, tmp, args.repeat)}
        if args.stages:
            imu, temps, _ = _topics(path)
            figures['calibrate_collect_stages_cpu_s'] = collect_stages(path, imu, temps)
        if args.e2e:
            figures['calibrate_end_to_end'] = end_to_end(path, tmp, args.e2e)
        if args.rss_messages:
            if args.log is None:
                os.unlink(path)
            figures['rss'] = rss(args.rss_messages, tmp, _rss_calibration(tmp))
    st = figures['stages']
    ref = st['rosbags AnyReader + deserialize_cdr']
    comp = st['compensate end to end (all msgs)']
    figures['ratios'] = {
        'compensate / rosbags loop (wall)': comp['wall_s'] / ref['wall_s'],
        'compensate / rosbags loop (cpu)': comp['cpu_s'] / ref['cpu_s'],
    }
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(figures, f, indent=1)
    print(f'log: {figures["log"]} ({figures["file_MB"]:.0f} MB)')
    width = max(map(len, st))
    print(f'{"stage":<{width}}  {"messages":>9} {"wall s":>7} {"cpu s":>7} {"msgs/s":>11} '
          f'{"msgs/cpu-s":>11} {"MB/s":>7}')
    for name, f in st.items():
        print(f'{name:<{width}}  {f["messages"]:9d} {f["wall_s"]:7.2f} {f["cpu_s"]:7.2f} '
              f'{f["msgs_per_s"]:11,.0f} {f["msgs_per_cpu_s"]:11,.0f} {f["MB_per_s"]:7.0f}')
    for name, v in figures['ratios'].items():
        print(f'{name}: {v:.2f}')
    if 'calibrate_collect_stages_cpu_s' in figures:
        print('calibrate read+detect+collect, CPU s: ' + ', '.join(
            f'{k} {v:.3f}' for k, v in figures['calibrate_collect_stages_cpu_s'].items()))
    for name, f in figures.get('calibrate_end_to_end', {}).items():
        print(f'{name:<{width}}  wall {f["wall_s"]:6.2f} s  cpu {f["cpu_s"]:5.2f} s  '
              f'(runs {", ".join(f"{c:.2f}" for c in f["cpu_s_all"])})  '
              f'{f["cpu_over_rosbags_raw"]:.2f}x rosbags raw; median wall '
              f'{f["wall_s_median"]:.2f} s, cpu {f["cpu_s_median"]:.2f} s: '
              f'{f["median_wall_over_rosbags_raw"]:.2f}x / '
              f'{f["median_cpu_over_rosbags_raw"]:.2f}x')
    if 'rss' in figures:
        r = figures['rss']
        print(f'peak RSS on {r["messages"]:,} messages ({r["file_MB"]:.0f} MB): ' + ', '.join(
            f'{k} {r[k]["peak_rss_MB"]:.0f} MB ({r[k]["cpu_s"]:.1f} cpu-s)'
            for k in ('calibrate', 'compensate')))
    print(f'bench peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB')
    return 0


if __name__ == '__main__':
    sys.exit(main())
