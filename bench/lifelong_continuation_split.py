"""Where a run with ``gyro_continuation='span'`` parts from 'history' (the default).

For the lifelong directory of a run with ``--gyro-continuation span`` (``bench_lifelong.py
month --work W``: ``W/seedN``; a screen with ``--stop-day`` will do), each estimate's
logged continuation (what 'span' chose) is set against the 'history' verdict on every
evidence row up to its time (``state.json``, ``continuation``;
``lifelong.continuation.verdict``). The two runs are the same up to the first estimate where
they differ: printed per run are the estimates, the rows, the alarms and that estimate
(the run's day; 'no' when there is none). Rows cut by an alarm are gone from the state, so
after an alarm the figures are those of the rows kept.

    python bench/lifelong_continuation_split.py 190:/tmp/sp/s190/seed190 [--dock-fraction F]
"""

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from thermal_imu_calib.lifelong import continuation  # noqa: E402
from thermal_imu_calib.lifelong.config import LifelongConfig  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def split(seed, d, dock_fraction=0.0, sigmas=LifelongConfig.swap_sigmas):
    """Return (estimates, rows, alarms, first split (day, action, both texts) or None)."""
    base = robot_month(seed, days=30, dock_fraction=dock_fraction).start_ns * 1e-9
    with open(os.path.join(d, 'state.json')) as f:
        rows = json.load(f).get('continuation') or []
    with open(os.path.join(d, 'decisions.jsonl')) as f:
        decisions = [json.loads(x) for x in f if x.strip()]
    first, n = None, 0
    for x in decisions:
        if 'continuation' not in x:
            continue
        n += 1
        chose = x['continuation'].startswith('gyro continued')
        history, text = continuation.verdict([r for r in rows if r[0] <= x['time']], sigmas)
        if chose != history and first is None:
            first = ((x['time'] - base) / DAY, x['action'], x['continuation'], text)
    return n, len(rows), sum(x['action'] == 'alarm' for x in decisions), first


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('runs', nargs='+', help='SEED:WORK_DIR/seedSEED of a run with span')
    ap.add_argument('--dock-fraction', type=float, default=0.0)
    args = ap.parse_args()
    for spec in args.runs:
        seed, d = spec.split(':', 1)
        n, rows, alarms, first = split(int(seed), d, args.dock_fraction)
        where = (f'day {first[0]:.2f} ({first[1]}): span: {first[2]}; history: {first[3]}'
                 if first else 'no')
        print(f'{seed}: {n} estimates, {rows} rows, alarms {alarms}, split: {where}')


if __name__ == '__main__':
    main()
