"""The scale factor's change tests on cached alarm fleets, at the pooled S and on own stds.

``bench_fleet.py alarms`` reports the weakest test that flags each drifting or step unit,
which on its fleets is always a bias test. This prints, over the cached fleets of
``bench_fleet.py alarms --cache DIR``, the largest |z| of the scale factor's change tests
(``dk0 .. changed``) of every step unit (its dk0 steps by ``FleetDesign.step_scale`` on one
axis) and of every stable unit, with the scale factor at the unit's pooled S (its curvature
on S, ``fleet/pooled_s.py``) and on its own stds (the curvature columns left out), from the
same calibrations::

    python bench/alarm_dk0_z.py --cache /tmp/k2/cache --units 8 --logs-per-unit 3 --seeds 20
"""

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_fleet as bf  # noqa: E402
from thermal_imu_calib.fleet import registry as reg  # noqa: E402


def largest_dk0(d, pooled_k):
    """Return {unit: largest |z| of its dk0 change tests} of one cached fleet."""
    _, info = reg.assess(bf.read_rows(d, True, pooled_k))
    out = {}
    for u, tests in info['unit_tests'].items():
        z = [abs(v) for lbl, v in tests
             if lbl.startswith('dk0') and 'changed' in lbl and np.isfinite(v)]
        out[u] = max(z) if z else float('nan')
    return out


def main():
    """Print and write the summary."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--cache', required=True)
    ap.add_argument('--units', type=int, default=8)
    ap.add_argument('--logs-per-unit', type=int, default=3)
    ap.add_argument('--first-seed', type=int, default=0)
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--json', default=None)
    args = ap.parse_args()
    got = {(kind, pk): [] for kind in ('step', 'stable') for pk in (True, False)}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        d = bf.cache_dir(args.cache, args.units, args.logs_per_unit, seed)
        truth = bf.read_truth(d)
        for pk in (True, False):
            for u, z in largest_dk0(d, pk).items():
                if truth[u]['kind'] in ('step', 'stable'):
                    got[(truth[u]['kind'], pk)].append(z)
    out = {}
    for (kind, pk), v in got.items():
        a = np.array(v, float)
        key = f'{kind} units, dk0 change |z| max per unit, ' + (
            'at the pooled S' if pk else 'own stds')
        out[key] = {'n': int(len(a)), 'median': round(float(np.nanmedian(a)), 2),
                    'min': round(float(np.nanmin(a)), 2), 'max': round(float(np.nanmax(a)), 2)}
        print(key, out[key])
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'command': ' '.join(sys.argv), 'summary': out}, f, indent=1)


if __name__ == '__main__':
    main()
