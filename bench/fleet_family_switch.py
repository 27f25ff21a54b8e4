"""Are the drift alarms' stds honest across a model-family switch?

A unit whose consecutive calibrations come from different accelerometer families (the
standard-fit floor returning ``standard`` for one log and ``field`` for the next) has its
change tested only if the two families' alarm terms (bias and scale factor at T0 with
stds, ``models/alarm_terms.py``) are comparable. This bench decides that on fleets the
alarm bench never used (held-out seeds): every log of a simulated 8 x 3 fleet is
calibrated twice, pinned to each family (``fleet calibrate --model field`` and
``--model standard``), and each consecutive change of a unit is tested across the two
families, in both directions (field on log k against standard on log k+1, and standard
on log k against field on log k+1), with the same-family changes beside them.

On the stable units (the simulator's truth) z must look N(0, 1): std, robust std, the
tails and a KS test against N(0, 1) are printed per comparison kind. On drifting and step
units the cross-family |z| say what the test can detect. Registries are cached in
``--cache`` (DIR/seed_N/<model>/); results go to bench/results/fleet_family_switch.json.

Since the alarm yardstick (2026-12-02, ``estimation/alarm_yardstick.py``) a standard-fit
calibration's alarm terms are the field model's on the same holds, so ``standard`` here
compares those; ``standard-own`` is the standard fit's own terms (the rows rebuilt
without the yardstick, ``registry_alarms.reindex``), what was compared before.

    nice -n 10 .venv/bin/python bench/fleet_family_switch.py --first-seed 20 --seeds 5
"""

import argparse
import functools
import json
import os
import shutil
import sys
import time


HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_fleet import _z_summary  # noqa: E402
from registry_alarms import reindex  # noqa: E402
from thermal_imu_calib import cli  # noqa: E402
from thermal_imu_calib.app.fleet import calibrate_unit  # noqa: E402
from thermal_imu_calib.cli.fleet import fleet_settings  # noqa: E402
from thermal_imu_calib.fleet import registry as reg  # noqa: E402
from thermal_imu_calib.fleet.inputs import expand_inputs, GroupBy  # noqa: E402
from thermal_imu_calib.fleet.runner import run_fleet  # noqa: E402
from thermal_imu_calib.fleet.simulate import FleetDesign, read_truth, simulate_fleet  # noqa

MODELS = ('field', 'standard')


def calibrated(client, cache, seed, units, logs_per_unit):
    """Return DIR with DIR/<model>/ (a registry per pinned family) and fleet_truth.csv."""
    d = os.path.join(cache, f'seed_{seed}')
    if all(os.path.isfile(os.path.join(d, m, reg.INDEX)) for m in MODELS):
        return d
    tmp = d + '.tmp'
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    design = FleetDesign(units=units, logs_per_unit=logs_per_unit, seed=seed)
    logs = os.path.join(tmp, 'logs')
    simulate_fleet(logs, design, client)
    paths = expand_inputs([logs])
    for m in MODELS:
        args = cli.build_parser().parse_args(['fleet', 'calibrate', '-', '-o', '-',
                                              '--model', m])
        fn = functools.partial(calibrate_unit, fleet_settings(args), None)
        out, failed = run_fleet(client, paths, GroupBy('frame_id'), fn, {},
                                design.spacing_days * 2 / 3, progress=False)
        reg.add(os.path.join(tmp, m), [(u.sensor, u.result.calibration, u.end_ns,
                                        u.start_ns, u.logs) for u in out if not u.error])
        print(f'seed {seed} {m}: {len(out)} calibrations, {len(failed)} logs failed, '
              f'{sum(bool(u.error) for u in out)} refused', flush=True)
    shutil.copy(os.path.join(logs, 'fleet_truth.csv'), tmp)
    shutil.rmtree(logs)
    shutil.rmtree(d, ignore_errors=True)
    os.replace(tmp, d)
    return d


def changes(d):
    """Return {(kind, comparison): [z]}: kind 'stable' or 'changing', all change z."""
    truth = read_truth(d)
    per = {m: reg.by_sensor(reg.read_index(os.path.join(d, m))) for m in MODELS}
    per['standard-own'] = reg.by_sensor(reindex(os.path.join(d, 'standard'), yardstick=False))
    out = {}
    for s in per[MODELS[0]]:
        kind = 'stable' if truth[s]['kind'] == 'stable' else 'changing'
        rows = {m: per[m].get(s, []) for m in per}
        n = min(len(r) for r in rows.values())
        for k in range(n - 1):
            for a in per:
                for b in per:
                    z = reg.compare(rows[a][k], rows[b][k + 1], reg.ALARM_ON)
                    for name, v in z.items():
                        out.setdefault((kind, f'{a} -> {b} {name}'), []).extend(v.tolist())
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--first-seed', type=int, default=20)
    ap.add_argument('--seeds', type=int, default=5)
    ap.add_argument('--units', type=int, default=8)
    ap.add_argument('--logs-per-unit', type=int, default=3)
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--cache', default='/tmp/family_switch_cache')
    args = ap.parse_args()
    from distributed import Client, LocalCluster
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    t = time.perf_counter()
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=':0') as cluster, Client(cluster) as client:
        dirs = [calibrated(client, args.cache, s, args.units, args.logs_per_unit)
                for s in seeds]
    zs = {}
    for d in dirs:
        for k, v in changes(d).items():
            zs.setdefault(k, []).extend(v)
    summary = {f'{kind}: {what}': _z_summary(v) for (kind, what), v in sorted(zs.items())}
    for k, v in summary.items():
        print(f'{k}: {v}')
    out = {'seeds': seeds, 'units': args.units, 'logs_per_unit': args.logs_per_unit,
           'models': list(MODELS), 'minutes': round((time.perf_counter() - t) / 60, 1),
           'z': summary}
    os.makedirs(os.path.join(HERE, 'results'), exist_ok=True)
    with open(os.path.join(HERE, 'results', 'fleet_family_switch.json'), 'w') as f:
        json.dump(out, f, indent=1)


if __name__ == '__main__':
    main()
