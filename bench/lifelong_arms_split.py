"""Where two runs of the same robot month part: the first decision whose outcome differs.

For two lifelong directories of one seed (``bench_lifelong.py month --work W``: ``W/seedN``;
a screen with ``--stop-day`` will do), run with different options: the decisions are
taken in order and compared by their action and, for swaps, by the models activated (the
calibration files' ``accel`` and ``gyro`` sections, read from each run's registry; the
ids differ whenever the files' notes do, so they are not compared). Printed: the
decisions of each run and the day of the first that differs ('no' when none does), with
both runs' texts there. Used to screen seeds for a judgement: a seed where the runs do
not part says nothing about the option.

    python bench/lifelong_arms_split.py 201 /tmp/sc/base201/seed201 /tmp/sc/opt201/seed201
"""

import argparse
import json
import os
import sys

import yaml

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from thermal_imu_calib.fleet import registry  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def decisions(d):
    """Return the decisions of a lifelong directory, each swap with its models (dicts)."""
    with open(os.path.join(d, 'decisions.jsonl')) as f:
        out = [json.loads(x) for x in f if x.strip()]
    rows = registry.read_index(os.path.join(d, 'registry'))
    swaps = [x for x in out if x['action'] == 'swap']
    for x, r in zip(swaps, rows):
        with open(os.path.join(d, 'registry', r['file'])) as f:
            cal = yaml.safe_load(f)
        x['models'] = {k: cal.get(k) for k in ('accel', 'gyro')}
    return out


def split(a, b):
    """Return the index of the first decision that differs between runs a and b, or None."""
    for i, (x, y) in enumerate(zip(a, b)):
        if x['action'] != y['action'] or x.get('models') != y.get('models'):
            return i
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('seed', type=int)
    ap.add_argument('base')
    ap.add_argument('option')
    ap.add_argument('--dock-fraction', type=float, default=0.0)
    args = ap.parse_args()
    start = robot_month(args.seed, days=30, dock_fraction=args.dock_fraction).start_ns * 1e-9
    a, b = decisions(args.base), decisions(args.option)
    i = split(a, b)
    head = f'seed {args.seed}: {len(a)} / {len(b)} decisions; '
    if i is None:
        print(head + f'no split in the first {min(len(a), len(b))}')
        return
    day = (a[i]['time'] - start) / DAY
    print(head + f'first split at decision {i}, day {day:.2f}')
    for name, x in (('base', a[i]), ('option', b[i])):
        print(f'  {name}: {x["action"]}: {x.get("text", "")[:300]}')


if __name__ == '__main__':
    main()
