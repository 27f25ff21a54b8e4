"""RVM compensation throughput: the speed claim moved out of test_rvm.py (issue 15 item 7).

Fits an RVM accelerometer + gyro calibration on two simulated 10..50 degC legs (the same
windows as ``test_rvm.py``) and times ``Calibration.apply`` on 200,000 samples with distinct
temperatures (1000 s at 200 Hz). Target: > 60,000 samples/s on the 2-core reference
machine. The RVM training-time target (3 h of segments < 10 s) is measured by
``bench/bench_thermal.py`` (``rvm_timing``).

Usage: python bench/bench_rvm_apply.py [--repeat 3]   (exit 1 when the target is missed)
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'test'))

from test_rvm import rvm_calibration  # noqa: E402

TARGET = 60_000.0   # samples/s


def main(argv=None):
    """Print the apply throughput; return 0 when it meets TARGET."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--repeat', type=int, default=3)
    args = ap.parse_args(argv)
    cal = rvm_calibration()
    rng = np.random.default_rng(5)
    n = 200_000
    temps = np.linspace(12, 48, n)[:, None] + rng.normal(0, 1e-3, (n, 1))
    a = rng.normal(0, 1, (n, 3))
    best = np.inf
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        cal.apply(a, a, temps)
        best = min(best, time.perf_counter() - t0)
    rate = n / best
    print(f'RVM Calibration.apply: {n} samples in {best:.3f} s (best of {args.repeat}): '
          f'{rate:,.0f} samples/s (target > {TARGET:,.0f})')
    return 0 if rate > TARGET else 1


if __name__ == '__main__':
    sys.exit(main())
