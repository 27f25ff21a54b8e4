"""A month's last-week accelerometer drift, as it ran and with another calibration instead.

Usage::

    python bench/lifelong_last_week_with.py SEED WORK/seedSEED [CAL.yaml ...] [--from-day D]

Scores every stop from ``--from-day`` (default: the last week of 30 days) as
``bench_lifelong.py`` does (``stop_error``): with the calibration active at the stop (the
run's registry), with each given calibration file for every stop, raw and with the true
model. Prints the accel drift (mm/s^2, RMS of the stop errors less their median) and the
error's slope against temperature per axis (mm/s^2 per degC), which shows a wrong
temperature slope (docs/lifelong.md, seed 1).
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

from bench_lifelong import (  # noqa: E402
    active_index, drift_rms, registry_timeline, scored_stops, stop_error)
from thermal_imu_calib.calibration import Calibration  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('seed', type=int)
    p.add_argument('work_seed', help="the month's lifelong directory (…/seed<N>)")
    p.add_argument('calibrations', nargs='*', help='calibration files to score instead')
    p.add_argument('--from-day', type=float, default=23.0)
    a = p.parse_args()
    m = robot_month(a.seed, days=30.0)
    starts, cals = registry_timeline(a.work_seed, m.start_ns)
    others = {os.path.basename(f): Calibration.load(f) for f in a.calibrations}
    rows = {'as it ran': [], **{k: [] for k in others}, 'raw': [], 'true model': []}
    for seg, ch in scored_stops(m, a.from_day * DAY):
        k = active_index(starts, seg.stop.t0)
        temp = float(np.mean(ch['temp']))
        use = {'as it ran': cals[k] if k >= 0 else None, **others, 'raw': None,
               'true model': m.true_calibration(seg.stop.t0)}
        for name, cal in use.items():
            rows[name].append((temp, *stop_error(cal, ch)[1]))
    for name, v in rows.items():
        x = np.array(v)
        drift = drift_rms(x[:, 1:]) * 1e3
        slope = [np.polyfit(x[:, 0], x[:, 1 + j], 1)[0] * 1e3 for j in range(3)]
        print(f'{name:>14s}: accel drift {drift:6.1f} mm/s^2 over {len(x)} stops; error slope '
              f'x y z {slope[0]:+.2f} {slope[1]:+.2f} {slope[2]:+.2f} mm/s^2/degC')


if __name__ == '__main__':
    main()
