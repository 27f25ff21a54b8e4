"""Short six-face sessions judged on the next cold start: `auto` (field) against the others.

Per device (``sim`` 'mems' design, device seeds ``--first-seed`` ..): the ``demo`` log (six
faces twice, 15-20 s holds, a ~4-min warm-up) is calibrated with ``--model auto``,
``standard``, ``whole_unit`` and ``field`` (default options otherwise; ``--gravity`` the
simulation's), and each calibration is scored on the same device's ``demo-validation`` log
(the next cold start: six 30-40 s holds) by ``thermal-imu-calib evaluate``: the static
|a| - g RMS over its holds (ug). On such sessions ``auto`` does not offer ``whole_unit`` (too
few holds off the faces, each face held twice; docs/thermal_models.md), so it returns
``field``. Variant ``datasheet-cross-axis``: the devices' non-orthogonality S below the
diagonal drawn from 1e-3 - 2e-2 (``alarm_truth_z.VARIANTS``).

    .venv/bin/python bench/demo_next_coldstart.py --devices 12 --json out.json
    .venv/bin/python bench/demo_next_coldstart.py --devices 12 --variant datasheet-cross-axis

Device seeds 95000 + i by default (no other bench uses them). No ROS import.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

MODELS = ('auto', 'standard', 'whole_unit', 'field')


def calibrate_and_score(seed, work, variant, runs):
    """Calibrate one device's ``demo`` log each way of ``runs``; score on its next cold start.

    ``runs``: (name, ``--model``, ``before`` or None: called first, e.g. a patch). Returns
    ({name: |a|-g RMS ug on ``demo-validation``, None when refused}, {name: calibration
    file}, the raw log's ug).
    """
    from thermal_imu_calib import sim
    from thermal_imu_calib.cli import main
    from thermal_imu_calib.gravity import normal_gravity
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from alarm_truth_z import use_variant
    use_variant(variant)
    g = repr(normal_gravity(45.0))
    d = os.path.join(work, str(seed))
    os.makedirs(d)
    sim.write_scenario(os.path.join(d, 'cal.mcap'), 'demo', seed)
    sim.write_scenario(os.path.join(d, 'val.mcap'), 'demo-validation', seed)
    cals = {}
    for name, model, before in runs:
        if before is not None:
            before()
        path = os.path.join(d, f'{name}.yaml')
        try:
            main(['calibrate', os.path.join(d, 'cal.mcap'), '-o', path, '--gravity', g,
                  '--model', model, '--no-progress'])
        except SystemExit as e:
            if e.code:
                continue
        cals[name] = path
    cmd = [os.path.join(sys.prefix, 'bin', 'thermal-imu-calib'), 'evaluate',
           os.path.join(d, 'val.mcap'), '--gravity', g, '--json', '--no-progress']
    for path in cals.values():
        cmd += ['--calibration', path]
    res = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
    scores = {name: res['results'][name]['gravity_residual_ug']['rms'] if name in cals
              else None for name, _, _ in runs}
    return scores, cals, res['results']['raw']['gravity_residual_ug']['rms']


def one_device(seed, work, variant):
    """Return {model: |a|-g RMS ug on the next cold start} of one device (None: refused)."""
    from thermal_imu_calib.formats import read_calibration
    out, cals, raw = calibrate_and_score(seed, work, variant, [(m, m, None) for m in MODELS])
    out['raw'] = raw
    out['auto_chose'] = read_calibration(cals['auto']).accel.kind
    return out


def run_devices(first_seed, devices, one):
    """Return {seed: one(seed, work)} over the devices (a temporary work folder), printed."""
    work = tempfile.mkdtemp(prefix='demo_devices_')
    rows = {}
    try:
        for seed in range(first_seed, first_seed + devices):
            rows[seed] = one(seed, work)
            print(seed, {k: (round(v, 1) if isinstance(v, float) else v)
                         for k, v in rows[seed].items()}, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows


def device_rows(doc, first_seed, one, argv=None):
    """Parse the device options (``doc``'s first line the description); run ``one``.

    ``one(seed, work, variant)``; returns (the options, {seed: row}).
    """
    ap = argparse.ArgumentParser(description=doc.split('\n')[0])
    ap.add_argument('--devices', type=int, default=12)
    ap.add_argument('--first-seed', type=int, default=first_seed)
    ap.add_argument('--variant', choices=('base', 'datasheet-cross-axis'), default='base')
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    return args, run_devices(args.first_seed, args.devices,
                             lambda seed, work: one(seed, work, args.variant))


def report(args, summary, rows):
    """Print ``summary``; write it with the rows to ``args.json`` when given."""
    print(json.dumps(summary, indent=1))
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump({'command': ' '.join(['python', *sys.argv]), 'variant': args.variant,
                       'summary': summary, 'devices': rows}, fh, indent=1)


def main():
    """Run the devices and print (and optionally write) the table and its summary."""
    args, rows = device_rows(__doc__, 95000, one_device)
    f = np.array([r['field'] for r in rows.values()], float)
    w = np.array([r['whole_unit'] for r in rows.values()], float)
    summary = {m: {'median_ug': round(float(np.nanmedian([r[m] for r in rows.values()])), 1),
                   'rms_over_devices_ug': round(float(np.sqrt(np.nanmean(
                       np.square([r[m] for r in rows.values()], dtype=float)))), 1)}
               for m in MODELS}
    summary['whole_unit_better_than_field'] = f'{int(np.sum(w < f))} of {len(f)}'
    summary['geometric_mean_whole_unit_over_field'] = round(float(np.exp(np.nanmean(
        np.log(w / f)))), 3)
    report(args, summary, rows)


if __name__ == '__main__':
    main()
