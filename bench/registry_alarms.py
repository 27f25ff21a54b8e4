"""The registry's drift alarms re-evaluated on registries that exist: fleets and robots.

Each registry's index rows are rebuilt from its calibration files with today's
``registry.index_row`` (so the alarm terms are today's: the gyro bias, an offset model's
relative bias left out) and judged by ``registry.assess``:

* ``fleet DIR ...``: the cached fleets of ``bench_fleet.py alarms --cache DIR`` (``DIR/reg``
  and ``DIR/fleet_truth.csv``): units flagged, stable and not (drifting, step), and the
  stable units' gyro-bias z (their std: how honest the fit's stds are);
* ``robot DIR ...``: lifelong registries (``bench_lifelong.py month --work W``: W/seedN/
  registry, or a node's ``<lifelong_dir>/registry``): every test over the threshold.

``--without-yardstick``: the accelerometer's alarm terms are each model's own, as before
the alarm yardstick (``estimation/alarm_yardstick.py``): the before figure of the same
calibrations. ``--family-rate P``: the fleet-wide false-alarm rate the threshold follows
from (``history --family-rate``; default ``registry.FAMILY_RATE``).

    .venv/bin/python bench/registry_alarms.py fleet /tmp/alarms_cache/8x3/seed_*
    .venv/bin/python bench/registry_alarms.py robot /tmp/ws2/seed2/registry
"""

import argparse
import csv
import os
import sys

import numpy as np

from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.fleet import registry as reg


def reindex(directory, yardstick=True):
    """Return the index rows of ``directory`` rebuilt from its calibration files.

    ``yardstick`` False: without the calibrations' ``fit.alarm_yardstick``.
    """
    out = []
    for r in reg.read_index(directory):
        cal = Calibration.load(os.path.join(directory, r['file']))
        if not yardstick:
            cal.fit = {k: v for k, v in (cal.fit or {}).items() if k != 'alarm_yardstick'}
        row = reg.index_row(r['sensor'], cal, reg.parse_time(r['time']),
                            reg.parse_time(r['valid_from']), r['file'], [])
        row['logs'] = r['logs']
        out.append({k: '' if v is None else str(v) for k, v in row.items()})
    return out


def over(rows, family_rate=reg.FAMILY_RATE):
    """Return ([(sensor, label, z)] over the threshold, assess info)."""
    _, info = reg.assess(rows, family_rate)
    return [(s, lbl, z) for s, ts in info['unit_tests'].items() for lbl, z in ts
            if abs(z) > info['threshold_sigma']], info


def fleet(dirs, yardstick=True, family_rate=reg.FAMILY_RATE):
    counts = {'stable': [0, 0], 'drifting or step': [0, 0]}
    gz = []
    for d in dirs:
        truth = {r['unit']: r['kind'] for r in csv.DictReader(
            open(os.path.join(d, 'fleet_truth.csv')))}
        rows = reindex(os.path.join(d, 'reg'), yardstick)
        found, info = reg.assess(rows, family_rate)
        for s, rs in reg.by_sensor(rows).items():
            stable = truth.get(s) == 'stable'
            counts['stable' if stable else 'drifting or step'][0] += 1
            counts['stable' if stable else 'drifting or step'][1] += bool(found.get(s))
            if stable:
                gz += [z for lbl, z in reg.unit_tests(rs) if lbl.startswith(reg.GYRO_PREFIX)]
        print(f'{os.path.basename(d)}: {info["tests"]} tests, threshold '
              f'{info["threshold_sigma"]:.2f}, gyro spread {info["gyro_scale"] or 0:.2f}, '
              f'flagged: {sorted(s for s in found if found[s])}', flush=True)
    for k, (n, f) in counts.items():
        print(f'{k} units: {f} of {n} flagged')
    gz = np.asarray(gz)
    if len(gz):
        print(f'stable units\' gyro-bias z with the fit\'s stds: {len(gz)} tests, std '
              f'{gz.std():.2f}, robust std {1.4826 * np.median(np.abs(gz)):.2f}')


def robot(dirs, family_rate=reg.FAMILY_RATE):
    for d in dirs:
        rows = reindex(d)
        hits, info = over(rows, family_rate)
        print(f'{d}: {len(rows)} calibrations, {info["tests"]} tests, threshold '
              f'{info["threshold_sigma"]:.2f}, gyro spread {info["gyro_scale"] or 0:.2f}')
        for s, lbl, z in hits:
            print(f'  {s}: {lbl}: {z:+.1f} sigma')


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('what', choices=('fleet', 'robot'))
    ap.add_argument('dirs', nargs='+')
    ap.add_argument('--without-yardstick', action='store_true',
                    help="each model's own accelerometer alarm terms (the before figure)")
    ap.add_argument('--family-rate', type=float, default=reg.FAMILY_RATE, metavar='P')
    args = ap.parse_args(argv)
    if args.what == 'fleet':
        fleet(args.dirs, not args.without_yardstick, args.family_rate)
    else:
        robot(args.dirs, args.family_rate)


if __name__ == '__main__':
    sys.exit(main())
