"""Gyro error of each calibration a simulated robot month activated, by temperature band.

For a finished ``bench_lifelong.py month`` run (its ``--work`` directory), every stop is
scored with the calibration active when it began (the registry is the timeline), against
the truth, as ``bench_lifelong.py`` scores it; the RMS per axis (mrad/s) is printed per
activated calibration and 5-degC band, with the calibration's gyro family and valid range.
Shows a calibration that is good where the swap gate judged it and bad elsewhere. Then,
over all those stops: the mean error vector (what no temperature term explains: a bias
the calibrations lag behind, or the earth rate they took in) and what is left after a
cubic in temperature per calibration, by stop length (the noise of a short stop's mean
against a misfit of the thermal model).

    python bench/lifelong_by_temperature.py /tmp/lfg1/seed1 --seed 1 [--from-day 23]

``--accel``: the accelerometer instead, as the month's "accel drift" scores it (each stop's
error minus the median over the stops scored, mm/s^2): per calibration and band the drift
RMS and the mean error vector, which tells a step between two calibrations (a constant
vector in every band) from a drift with temperature.
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_lifelong import (  # noqa: E402
    active_index, registry_timeline, scored_stops, stop_error)
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

BANDS = (-np.inf, 20.0, 25.0, 30.0, 35.0, np.inf)
#: stop lengths (s) the residual is split by
LENGTHS = (0.0, 30.0, 100.0, np.inf)


def residual_summary(scored):
    """Print the mean error and the residual after a cubic in T per calibration (mrad/s)."""
    rows = [(k, *r) for k, v in scored.items() for r in v]
    x = np.array([r[1:] for r in rows])            # temp, ex, ey, ez, stop length
    ks = np.array([r[0] for r in rows])
    err = x[:, 1:4]
    res = err.copy()
    for k in np.unique(ks):
        s = ks == k
        for j in range(3):
            deg = 3 if s.sum() > 8 else 0
            res[s, j] -= np.polyval(np.polyfit(x[s, 0], err[s, j], deg), x[s, 0])
    print(f'all {len(x)} stops: gyro error RMS {np.sqrt(np.mean(np.sum(err ** 2, 1))) * 1e3:.3f}'
          f' mrad/s, mean x y z {" ".join(f"{v:+.3f}" for v in err.mean(0) * 1e3)} mrad/s')
    for lo, hi in zip(LENGTHS[:-1], LENGTHS[1:]):
        s = (x[:, 4] >= lo) & (x[:, 4] < hi)
        if s.any():
            rms = np.sqrt(np.mean(res[s] ** 2, 0)) * 1e3
            print(f'  stops of {lo:.0f}..{hi:.0f} s ({s.sum()}): left after a cubic in T per '
                  f'calibration, RMS x y z {rms[0]:.3f} {rms[1]:.3f} {rms[2]:.3f} mrad/s')


def _header(cal, start_ns, sensor):
    """Return 'calibration ID active from day D: <sensor> KIND, valid LO..HI degC'."""
    lo, hi = cal.valid_range[0] if cal.valid_range is not None else (np.nan, np.nan)
    return (f'calibration {cal.id} active from day {start_ns / DAY:.2f}: {sensor} '
            f'{getattr(cal, sensor).kind}, valid {lo:.1f}..{hi:.1f} degC')


def _bands(temps):
    """Yield ('LO..HI degC' label, mask) for each band of ``BANDS`` holding a stop (degC)."""
    for b0, b1 in zip(BANDS[:-1], BANDS[1:]):
        s = (temps >= b0) & (temps < b1)
        if s.any():
            yield f'{b0:>5.0f}..{b1:<4.0f} degC', s


def accel_summary(scored, starts, cals):
    """Print the accelerometer drift (error minus the median over all stops) per calibration."""
    med = np.median(np.concatenate([np.array(v)[:, 1:4] for v in scored.values()]), 0)
    alld = []
    for k, v in sorted(scored.items()):
        x = np.array(v)
        d = x[:, 1:4] - med
        alld.append(d)
        print(f'{_header(cals[k], starts[k], "accel")}, {len(x)} stops, drift RMS '
              f'{np.sqrt(np.mean(np.sum(d ** 2, 1))) * 1e3:.1f} mm/s^2')
        for band, s in _bands(x[:, 0]):
            rms = np.sqrt(np.mean(np.sum(d[s] ** 2, 1))) * 1e3
            mean = ' '.join(f'{m:+.1f}' for m in d[s].mean(0) * 1e3)
            print(f'  {band} {s.sum():4d} stops: drift RMS {rms:.1f}, mean x y z {mean} mm/s^2')
    d = np.concatenate(alld)
    print(f'all {len(d)} stops: drift RMS {np.sqrt(np.mean(np.sum(d ** 2, 1))) * 1e3:.1f} mm/s^2')


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('work_seed', help="a month's lifelong directory (…/seed<N>)")
    p.add_argument('--seed', type=int, required=True)
    p.add_argument('--days', type=float, default=30.0)
    p.add_argument('--from-day', type=float, default=0.0)
    p.add_argument('--accel', action='store_true', help='the accelerometer drift instead')
    a = p.parse_args()
    m = robot_month(a.seed, days=a.days)
    starts, cals = registry_timeline(a.work_seed, m.start_ns)
    scored = {}
    for seg, ch in scored_stops(m, a.from_day * DAY):
        k = active_index(starts, seg.stop.t0)
        if k < 0:
            continue
        eg, ea = stop_error(cals[k], ch)
        scored.setdefault(k, []).append((float(np.mean(ch['temp'])), *(ea if a.accel else eg),
                                         seg.stop.t1 - seg.stop.t0))
    if a.accel:
        accel_summary(scored, starts, cals)
        return
    for k, v in sorted(scored.items()):
        x = np.array(v)
        print(f'{_header(cals[k], starts[k], "gyro")}, {len(x)} stops')
        for band, s in _bands(x[:, 0]):
            rms = np.sqrt(np.mean(x[s, 1:4] ** 2, 0)) * 1e3
            print(f'  {band} {s.sum():4d} stops: gyro RMS x y z '
                  f'{rms[0]:.3f} {rms[1]:.3f} {rms[2]:.3f} mrad/s')
    residual_summary(scored)


if __name__ == '__main__':
    main()
