r"""Drift alarms on simulated 8 x 3 fleets whose parts have a datasheet's cross-axis terms.

Per fleet seed: ``fleet/simulate.py`` writes 8 units x 3 logs (its design: stable, drifting
and step units; the ``mems`` devices), with the devices' non-orthogonality S below the
diagonal drawn from the variant (``alarm_truth_z.VARIANTS``; ``base``: the design's own
2e-4 - 8e-4); ``fleet calibrate --period 20`` with default options (Dask, 2 workers), then
``registry.assess``. Per unit: its truth kind, flagged or not, its largest |z| and first
alarm. Before 2026-12-03 this was a throw-away script (docs/fleet.md, seeds 91-93).

    .venv/bin/python bench/datasheet_fleets.py --seeds 97 98 99 \
        --json bench/results/datasheet_fleets_97_99.json        # ~3 min a fleet

SI units; z unitless. No ROS import.
"""

import argparse
import json
import os
import shutil
import sys
import tempfile
import time


def one_fleet(seed, variant, work):
    """Return {'threshold', 'tests', 'units': {unit: {kind, flagged, max_abs_z, first}}}."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from alarm_truth_z import use_variant
    use_variant(variant)
    from thermal_imu_calib.cli import main
    from thermal_imu_calib.fleet import registry as reg
    from thermal_imu_calib.fleet.simulate import FleetDesign, read_truth, simulate_fleet
    d = os.path.join(work, f'{variant}_{seed}')
    simulate_fleet(os.path.join(d, 'logs'), FleetDesign(units=8, logs_per_unit=3, seed=seed))
    try:
        main(['fleet', 'calibrate', '--period', '20', '--workers', '2', '--no-progress',
              '-o', os.path.join(d, 'reg'), os.path.join(d, 'logs')])
    except SystemExit as e:
        if e.code:
            raise RuntimeError(f'fleet calibrate exited {e.code} on seed {seed}') from None
    from thermal_imu_calib.fleet.pooled_s import without_given_s
    rows = reg.read_index(os.path.join(d, 'reg'))
    found, info = reg.assess(rows)
    # the same calibrations on the terms' own stds (before the pooled S, fleet/pooled_s.py)
    found_m, info_m = reg.assess(without_given_s(rows))
    truth = read_truth(os.path.join(d, 'logs'))
    units = {s: {'kind': truth[s]['kind'], 'flagged': bool(a),
                 'max_abs_z': round(float(info['max_abs_z'][s]), 2),
                 'first': a[0] if a else '', 'flagged_marginal': bool(found_m[s]),
                 'max_abs_z_marginal': round(float(info_m['max_abs_z'][s]), 2)}
             for s, a in sorted(found.items())}
    return {'threshold': round(float(info['threshold_sigma']), 2), 'tests': info['tests'],
            'units': units}


def main():
    """Run the fleets of ``--seeds`` and print / write the per-unit outcome."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', required=True)
    ap.add_argument('--variant', choices=('base', 'datasheet-cross-axis'),
                    default='datasheet-cross-axis')
    ap.add_argument('--json', help='write the results here')
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix='datasheet_fleets_')
    t = time.perf_counter()
    fleets = {}
    try:
        for seed in args.seeds:
            fleets[seed] = r = one_fleet(seed, args.variant, work)
            for s, u in r['units'].items():
                print(f"seed {seed} {s} {u['kind']:8s} {'FLAGGED' if u['flagged'] else 'ok':7s} "
                      f"max |z| {u['max_abs_z']:5.1f} (own stds {u['max_abs_z_marginal']:5.1f}) "
                      f"{u['first'][:80]}", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    stable = [u for r in fleets.values() for u in r['units'].values() if u['kind'] == 'stable']
    special = [u for r in fleets.values() for u in r['units'].values() if u['kind'] != 'stable']
    summary = {'stable_flagged': f"{sum(u['flagged'] for u in stable)} of {len(stable)}",
               'special_flagged': f"{sum(u['flagged'] for u in special)} of {len(special)}",
               'stable_max_abs_z': max((u['max_abs_z'] for u in stable), default=None),
               'marginal_stable_flagged': f"{sum(u['flagged_marginal'] for u in stable)} of "
                                          f"{len(stable)}",
               'marginal_special_flagged': f"{sum(u['flagged_marginal'] for u in special)} "
                                           f"of {len(special)}",
               'weakest_special': min((u['max_abs_z'] for u in special), default=None),
               'weakest_special_marginal': min((u['max_abs_z_marginal'] for u in special),
                                               default=None)}
    print(summary)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'command': ' '.join([os.path.basename(sys.executable), *sys.argv]),
                       'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime()),
                       'variant': args.variant, 'seconds': round(time.perf_counter() - t, 1),
                       'summary': summary, 'fleets': fleets}, f, indent=1)


if __name__ == '__main__':
    main()
