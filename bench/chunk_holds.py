"""Holds and pose changes of logs fed to the collector in chunks of several sizes.

Usage: ``python bench/chunk_holds.py LOG [LOG ...]`` (IMU topic and temperature topics as
``calibrate`` resolves them). Each log is read once through the input gate and the
temperature aligner; the aligned samples are then fed to ``MotionCollector`` in chunks of
20000, 777, 50, 10 and 1 samples and of random sizes (1-2999, seed 0). Prints the holds
and pose changes per chunking and whether windows, hold records and pose changes are
identical to the 20000-sample run (docs/real_recordings.md, "Chunk boundaries").
"""

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from thermal_imu_calib.collection.motion import MotionCollector  # noqa: E402
from thermal_imu_calib.collection.segments import Windows  # noqa: E402
from thermal_imu_calib.io.bag import open_log  # noqa: E402
from thermal_imu_calib.io.gate import InputGate  # noqa: E402
from thermal_imu_calib.io.topics import resolve_topics  # noqa: E402
from thermal_imu_calib.app.collect import aligned_chunks  # noqa: E402
from thermal_imu_calib.collection.feed import DEFAULT_MAX_GAP_S  # noqa: E402

SIZES = ['20000', '777', '50', '10', '1', 'random']


def aligned_columns(path, imu_topic=None):
    """Return (t, accel, gyro, temps) of a log as ``calibrate`` feeds them to the detector."""
    with open_log(path) as reader:
        imu, temps = resolve_topics(reader, imu_topic, None)
        gate = InputGate({t: '' for t in temps})
        parts = [(c.imu.t, c.imu.accel, c.imu.gyro, c.temps)
                 for c in aligned_chunks(reader, imu, temps, 20000, DEFAULT_MAX_GAP_S, gate=gate)]
    return tuple(np.concatenate(c) for c in zip(*parts))


def collect(cols, size):
    """Feed the columns in chunks of ``size`` samples (or random sizes); return the result."""
    n = len(cols[0])
    steps = (np.random.default_rng(0).integers(1, 3000, n) if size == 'random'
             else np.full(n // int(size) + 1, int(size)))
    ends = np.cumsum(steps)
    bounds = np.r_[0, ends[ends < n], n]
    col = MotionCollector(None, cols[3].shape[1])
    parts = [col.update(*(c[lo:hi] for c in cols)) for lo, hi in zip(bounds[:-1], bounds[1:])]
    parts.append(col.finish())
    w = Windows.concat(parts)
    tr = [(x.hold_from, x.hold_to, x.t, x.gyro, x.accel, x.temps) for x in col.transitions]
    return w, col.det.holds, tr, col.dropped


def same(a, b):
    wa, ha, ta, da = a
    wb, hb, tb, db = b
    return (ha == hb and da == db and len(ta) == len(tb)
            and all(np.array_equal(getattr(wa, k), getattr(wb, k)) for k in vars(wa))
            and all(np.array_equal(x, y) for p, q in zip(ta, tb) for x, y in zip(p, q)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('logs', nargs='+')
    ap.add_argument('--imu-topic')
    args = ap.parse_args(argv)
    print('log | ' + ' / '.join(SIZES) + ' | identical to 20000')
    for path in args.logs:
        cols = aligned_columns(path, args.imu_topic)
        runs = {s: collect(cols, s) for s in SIZES}
        ref = runs['20000']
        holds = ' / '.join(f'{len(r[1])}h {len(r[2])}pc' for r in runs.values())
        diff = [s for s, r in runs.items() if not same(r, ref)]
        print(f'{os.path.basename(path)} | {holds} | '
              f'{"yes" if not diff else "no: " + ", ".join(diff)}')


if __name__ == '__main__':
    main()
