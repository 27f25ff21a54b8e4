"""The first day's figures of a month run, finished or not, from its registry.

Usage::

    python bench/lifelong_first_day.py SEED:WORK/seedSEED [...] \
        [--base bench/results/bench_lifelong_month_cut_fix_20.json]

For each month: the accelerometer drift (mm/s^2, RMS of the stop errors less their
median) and the gyro error (mrad/s, RMS of |error|) over the first day's stops, scored
as ``bench_lifelong.py`` scores them (``stop_error`` with the calibration active when the
stop began, from the run's registry), next to the base file's row for that seed (the
default's figures and the raw output's). For runs stopped before the month ended.
"""

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

from bench_lifelong import (  # noqa: E402
    active_index, drift_rms, registry_timeline, scored_stops, stop_error)
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def first_day(seed, work_seed):
    """Return (accel drift m/s^2, gyro rad/s, stops) over the first day of a month run."""
    m = robot_month(seed, days=30.0)
    starts, cals = registry_timeline(work_seed, m.start_ns)
    ea, eg = [], []
    for seg, ch in scored_stops(m, 0.0, DAY):
        k = active_index(starts, seg.stop.t0)
        g, a = stop_error(cals[k] if k >= 0 else None, ch)
        ea.append(a)
        eg.append(np.linalg.norm(g))
    drift = drift_rms(ea)
    return drift, float(np.sqrt(np.mean(np.square(eg)))), len(ea)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('runs', nargs='+', help='SEED:DIR, DIR a month\'s lifelong directory')
    p.add_argument('--base', default=os.path.join(HERE, 'results',
                                                  'bench_lifelong_month_cut_fix_20.json'))
    a = p.parse_args()
    with open(a.base) as f:
        base = {r['seed']: r for r in json.load(f)['rows']}
    for arg in a.runs:
        seed, work = arg.split(':', 1)
        drift, gyro, n = first_day(int(seed), work)
        b = base.get(int(seed))
        ref = '' if b is None else (
            f' (base {b["active"]["accel_drift_first_day"] * 1e3:.1f}, raw '
            f'{b["raw"]["accel_drift_first_day"] * 1e3:.1f})')
        refg = '' if b is None else (
            f' (base {b["active"]["gyro_first_day"] * 1e3:.3f}, raw '
            f'{b["raw"]["gyro_first_day"] * 1e3:.3f})')
        print(f'seed {seed}: first day accel drift {drift * 1e3:.1f} mm/s^2{ref}; gyro '
              f'{gyro * 1e3:.3f} mrad/s{refg}; {n} stops')


if __name__ == '__main__':
    main()
