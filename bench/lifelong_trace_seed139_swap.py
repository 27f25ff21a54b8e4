"""Seed 139's day-7.83 swap of the gyro-continuation arm, against the base's day-7.72 swap.

After the fact, for the judgement of 2026-12-05 (docs/lifelong.md, seeds 139-140): the
next day's stops after each arm's swap, scored (gyro error RMS, as ``bench_lifelong.py``
scores a stop) with the arm's new calibration, the same with its gyro clamped beyond its
range, and the calibration it replaced; then every one of the four calibrations on the
candidate's window. Reads the two months' work directories.

    python bench/lifelong_trace_seed139_swap.py --base /tmp/j42b/base139/seed139 \\
        --candidate /tmp/j42b/cont139/seed139
"""

import argparse
import os
import sys
from dataclasses import replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_lifelong import registry_timeline, scored_stops, stop_error  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def gyro_rms(cal, stops):
    """Return the gyro error RMS (mrad/s) of ``cal`` over [(segment, chunks)]."""
    return 1e3 * float(np.sqrt(np.mean([np.sum(stop_error(cal, ch)[0] ** 2)
                                        for _, ch in stops])))


def swap_at(work, start_ns, day):
    """Return (activation s, new calibration, replaced calibration) of the swap nearest day."""
    starts, cals = registry_timeline(work, start_ns)
    k = int(np.argmin(np.abs(np.asarray(starts) / DAY - day)))
    return starts[k], cals[k], cals[k - 1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--base', default='/tmp/j42b/base139/seed139')
    ap.add_argument('--candidate', default='/tmp/j42b/cont139/seed139')
    args = ap.parse_args()
    m = robot_month(139, days=30.0)
    swaps = {'base': swap_at(args.base, m.start_ns, 7.72),
             'candidate': swap_at(args.candidate, m.start_ns, 7.83)}
    for arm, (t0, new, old) in swaps.items():
        stops = list(scored_stops(m, t0, t0 + DAY))
        temps = [float(np.median(ch['temp'])) for _, ch in stops]
        print(f'{arm}: swap at day {t0 / DAY:.3f} ({new.out_of_range}, range '
              f'{np.round(new.valid_range, 2).tolist()} degC); next day {len(stops)} stops at '
              f'{min(temps):.1f}..{max(temps):.1f} degC; gyro mrad/s: new '
              f'{gyro_rms(new, stops):.4f}, new clamped '
              f'{gyro_rms(replace(new, out_of_range="clamp"), stops):.4f}, replaced '
              f'{gyro_rms(old, stops):.4f}')
    t0 = swaps['candidate'][0]
    stops = list(scored_stops(m, t0, t0 + DAY))
    print(f'on the candidate\'s window (day {t0 / DAY:.3f} + 1 day):')
    for arm, (_, new, old) in swaps.items():
        print(f'  {arm}: new {gyro_rms(new, stops):.4f}, replaced {gyro_rms(old, stops):.4f}')


if __name__ == '__main__':
    main()
