"""CPU time of ``gyro_static.fit_gyro_static`` per call (issue 13, speed).

Inputs: ``--args PATH``, a pickle of ``(ctx, est, poly, rep)`` as passed to
``selection.gyro_select.turns_gyro`` (all windows, omega1 = None, the log's latitude,
robust); without it, synthetic still windows of the same size (1800 windows, 30 holds,
order 2). Prints the process CPU time per call (best and mean of ``--repeat``); run it
single-threaded (``OPENBLAS_NUM_THREADS=1``) for comparable figures. Target: <= 20 ms per
call on the 2-core reference machine. Measured 2026-11-24 (load ~0.5, one BLAS thread) on the
nav cold start seed 0 arguments: 72-75 ms per call before (main 9074125), 16-17 ms after
(4.4-4.6x); synthetic windows 119-122 ms before, 19 ms after. With the default 2 BLAS threads
the CPU time doubles for both (150 -> 33 ms: OpenBLAS threads spin on these small products).

Usage: OPENBLAS_NUM_THREADS=1 python bench/bench_gyro_static.py [--args PATH] [--repeat 5]
(exit 1 when the target is missed)
"""

import argparse
import pickle
import sys
import time

import numpy as np

import thermal_imu_calib  # noqa: F401  (the pickle refers to its classes)
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.gyro_static import EARTH_RATE, fit_gyro_static
from thermal_imu_calib.estimation.observability import Priors

TARGET = 0.020   # s of CPU per call


def synthetic(n_holds=30, per=60, seed=0):
    """Return fit_gyro_static arguments for still windows in random orientations."""
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(seed)
    m = n_holds * per
    hold = np.repeat(np.arange(n_holds), per)
    rots = Rotation.from_rotvec(rng.normal(0, 1.5, (n_holds, 3)))
    up = rots.inv().apply([0, 0, 1.0])[hold]
    w_e = rots.inv().apply(EARTH_RATE * np.array([0, 0.7, 0.7]))[hold]
    temp = 22 + 15 * (1 - np.exp(-np.linspace(0, 3.5, m)))
    dx = (temp - 30.0)[:, None]
    acc = 9.81 * up
    sigma = 2e-6
    gyro = 1e-3 + 1e-4 * dx + 2e-6 * dx ** 2 + acc @ rng.uniform(-7e-5, 7e-5, (3, 3)).T \
        + w_e + rng.normal(0, sigma, (m, 3))
    w = Windows(hold=hold, t0=np.arange(m) * 5.0, t1=np.arange(m) * 5.0 + 5,
                n=np.full(m, 500), accel=acc, gyro=gyro, accel_var=np.full((m, 3), 1e-4),
                gyro_var=np.full((m, 3), sigma ** 2 * 500), temp=temp[:, None],
                temp_rate=np.zeros((m, 1)))
    return (w, np.repeat(temp[:, None], 3, axis=1), acc, np.full(3, 30.0)), dict(
        latitude=None, omega1=None, priors=Priors(), order=2, robust=True)


def from_pickle(path):
    """Return fit_gyro_static arguments as ``turns_gyro`` passes them for all windows."""
    with open(path, 'rb') as f:
        ctx, est, _, _ = pickle.load(f)
    o = ctx.options
    acc = est.accel.correct(ctx.windows.accel, ctx.ta)
    k = ctx.k
    return (ctx.windows, ctx.tg if k else None, acc, ctx.gyro_t0 if k else np.zeros(3)), dict(
        latitude=o.latitude, omega1=None, priors=o.whole_unit_priors or Priors(),
        order=o.order if k else 0, robust=True)


def main(argv=None):
    """Print the CPU time per call; return 0 when it meets TARGET."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--args', help='pickle of the turns_gyro arguments (ctx, est, poly, rep)')
    ap.add_argument('--repeat', type=int, default=5)
    args = ap.parse_args(argv)
    pos, kw = from_pickle(args.args) if args.args else synthetic()
    fit_gyro_static(*pos, **kw)                   # warm-up
    times = []
    for _ in range(args.repeat):
        t0 = time.process_time()
        fit_gyro_static(*pos, **kw)
        times.append(time.process_time() - t0)
    best, mean = min(times), float(np.mean(times))
    print(f'fit_gyro_static: {len(pos[0])} windows, {len(np.unique(pos[0].hold))} holds: '
          f'CPU {1e3 * best:.1f} ms best, {1e3 * mean:.1f} ms mean per call '
          f'(target {1e3 * TARGET:.0f} ms)')
    return 0 if best <= TARGET else 1


if __name__ == '__main__':
    sys.exit(main())
