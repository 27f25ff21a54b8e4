r"""The gyro-bias alarm tests of cached simulated fleets: their tails against N(0, 1).

The drift alarms put the gyro-bias z in units of the registry's own robust spread
(``fleet/alarms.gyro_scale``, an empirical null). This reads the fleets that
``bench_fleet.py alarms`` cached (``--cache``: one ``seed_N`` folder per fleet with ``reg/``
and ``fleet_truth.csv``) and gives, over the stable units (truth), the gyro z as judged
(divided by the scale) and raw: std, robust std, excess kurtosis and the fractions beyond 3
and 4 sigma; per fleet the scale and the largest stable |z|; and every stable test beyond
``--show`` sigma.

    .venv/bin/python bench/bench_fleet.py alarms --seeds 20 --units 20 --logs-per-unit 5 \\
        --cache /tmp/alarms_cache_z --out /tmp/bench_fleet_alarms_20x5_z.json
    .venv/bin/python bench/gyro_null_tails.py /tmp/alarms_cache_z/20x5 --json out.json

z unitless; no ROS import.
"""

import argparse
import glob
import json
import os

import numpy as np

from thermal_imu_calib.fleet import alarms as al
from thermal_imu_calib.fleet import registry as reg
from thermal_imu_calib.fleet.simulate import read_truth


def _summary(v):
    from scipy import stats
    v = np.asarray(v, float)
    return {'n': int(v.size), 'std': round(float(v.std()), 3),
            'robust_std': round(float(1.4826 * np.median(np.abs(v))), 3),
            'excess_kurtosis': round(float(stats.kurtosis(v)), 2),
            'frac_abs_gt_3': round(float(np.mean(np.abs(v) > 3)), 5),
            'frac_abs_gt_4': round(float(np.mean(np.abs(v) > 4)), 5),
            'max_abs': round(float(np.abs(v).max()), 2)}


def fleets(cache):
    """Return the cached fleet folders of ``cache`` in seed order (unfinished ones left out)."""
    out = [d for d in glob.glob(os.path.join(cache, 'seed_*'))
           if os.path.isfile(os.path.join(d, 'reg', reg.INDEX))]
    return sorted(out, key=lambda d: int(d.rsplit('_', 1)[1]))


def main():
    """Summarise the stable units' gyro tests of every cached fleet."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('cache', help='a --cache folder of bench_fleet.py alarms, e.g. X/20x5')
    ap.add_argument('--show', type=float, default=3.5)
    ap.add_argument('--json', default=None)
    args = ap.parse_args()
    raw_z, judged, per, extreme = [], [], [], []
    for d in fleets(args.cache):
        truth = read_truth(d)
        by = reg.by_sensor(reg.read_index(os.path.join(d, 'reg')))
        tests = {s: al.unit_tests(rs) for s, rs in by.items()}
        scaled, g = al.scaled_tests(tests)      # the z as ``assess`` judges them
        if not g:
            continue
        stable = [s for s in tests if truth[s]['kind'] == 'stable']
        raw_z += [z for s in stable for lbl, z in tests[s] if lbl.startswith(al.GYRO_PREFIX)]
        judged_fleet = [(s, lbl, z) for s in stable for lbl, z in scaled[s]
                        if lbl.startswith(al.GYRO_PREFIX)]
        judged += [z for _, _, z in judged_fleet]
        per.append({'fleet': os.path.basename(d), 'scale': round(g, 3),
                    'max_abs_stable': round(max(abs(z) for _, _, z in judged_fleet), 2)})
        extreme += [{'fleet': os.path.basename(d), 'unit': s, 'test': lbl, 'z': round(z, 2)}
                    for s, lbl, z in judged_fleet if abs(z) > args.show]
    out = {'cache': args.cache, 'fleets': len(per), 'judged': _summary(judged),
           'raw': _summary(raw_z), 'normal_0_1': {'frac_abs_gt_3': 0.0027,
                                                  'frac_abs_gt_4': 0.000063},
           'per_fleet': per, f'beyond_{args.show:g}_sigma': extreme}
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(out, f, indent=1)


if __name__ == '__main__':
    main()
