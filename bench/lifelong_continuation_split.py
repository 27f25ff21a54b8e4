"""Where the two continuation verdicts of a lifelong run part: 'history' against 'explained'.

For a run's lifelong directory (``bench_lifelong.py month --work W``: ``W/seedN``; a screen
with ``--stop-day`` will do), each estimate's gyro continuation is judged both ways on the
evidence rows (``state.json``, ``continuation``) up to its time: 'history' on every row,
'explained' without the rows both policies miss by the change alarm's limit
(``lifelong.continuation.verdict``). Printed per run: the estimates, the rows (and how
many both policies miss), the alarms, and the first estimate where the verdicts differ
(the run's day; 'no' when they never do). Rows cut by an alarm are gone from the state,
so after an alarm the figures are those of the rows kept.

    python bench/lifelong_continuation_split.py 182:/tmp/ex/s182/seed182 183:/tmp/ex/s183/seed183
"""

import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from thermal_imu_calib.lifelong import continuation  # noqa: E402
from thermal_imu_calib.lifelong.config import LifelongConfig  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def split(seed, d, sigmas=LifelongConfig.swap_sigmas):
    """Return (estimates, rows, rows both missed, alarms, first split or None) of one run."""
    base = robot_month(seed, days=30).start_ns * 1e-9
    with open(os.path.join(d, 'state.json')) as f:
        rows = json.load(f).get('continuation') or []
    with open(os.path.join(d, 'decisions.jsonl')) as f:
        decisions = [json.loads(x) for x in f if x.strip()]
    first, n = None, 0
    for x in decisions:
        if 'continuation' not in x:
            continue
        n += 1
        upto = [r for r in rows if r[0] <= x['time']]
        history = continuation.verdict(upto, sigmas)[0]
        go, text = continuation.verdict(upto, sigmas, only_explained=True)
        if go != history and first is None:
            first = ((x['time'] - base) / DAY, x['action'], text)
    both = len(rows) - len(continuation.explained(rows)[0])
    alarms = sum(x['action'] == 'alarm' for x in decisions)
    return n, len(rows), both, alarms, first


def main():
    for spec in sys.argv[1:]:
        seed, d = spec.split(':', 1)
        n, rows, both, alarms, first = split(int(seed), d)
        where = f'day {first[0]:.2f} ({first[1]}): {first[2]}' if first else 'no'
        print(f'{seed}: {n} estimates, {rows} rows ({both} both missed), alarms {alarms}, '
              f'split: {where}')


if __name__ == '__main__':
    main()
