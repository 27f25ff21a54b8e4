"""The standard fit as a candidate across a temperature span, judged on the next log.

For each unit of a simulated fleet (``FleetDesign(units, logs_per_unit=3, seed)``) each
of the first two logs is calibrated alone, as ``fleet calibrate --period`` does, with
``auto`` (which now judges the thermal family against the standard fit with its bias
polynomial in T, ``selection/standard_floor.py``), with ``--model field`` and with
``--model standard``; each calibration is applied to the unit's next log (``evaluate``:
every still hold the detector finds there) and scored by the gravity residual RMS of the
hold means, micro-g. The unit ages between logs (the fleet simulator's drifting and step
units: 10 mg per 30 days, a 40 mg step), so the next log also measures what ageing does.
The simulator's devices follow the seed 000 field model, so the field family is the truth
here by construction; the bench measures what the floor rule costs when it is.

    nice -n 10 .venv/bin/python bench/standard_floor.py [--units 3] [--seeds 0] \
        [--json bench/results/standard_floor.json]
"""

import argparse
import json
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from thermal_imu_calib.app.calibrate import calibrate_logs, CalibrateSettings  # noqa: E402
from thermal_imu_calib.app.evaluate import evaluate_files  # noqa: E402
from thermal_imu_calib.fleet.simulate import FleetDesign, read_truth, simulate_fleet  # noqa


def unit_row(logs, tmp, sensor, k):
    """Return the choice and the next-log residuals of one unit's calibrations of log k."""
    files, row = [], {'unit': sensor, 'log': k}
    for model in ('auto', 'field', 'standard'):
        out = os.path.join(tmp, f'{sensor}_{k}_{model}.yaml')
        run = calibrate_logs(CalibrateSettings(model=model), [logs[k]], out)
        files.append(out)
        if model == 'auto':
            choice = run.result.calibration.fit['model_choice']
            row['auto_chose'] = choice['model']
            row['auto_reason_tail'] = choice['reason'].split('; against the standard fit')[-1]
    ev = evaluate_files(logs[k + 1], files)
    for model, f in zip(('auto', 'field', 'standard'), files):
        label = os.path.splitext(os.path.basename(f))[0]
        row[f'{model}_next_log_ug'] = ev['results'][label]['gravity_residual_ug']['rms']
    row['raw_next_log_ug'] = ev['results']['raw']['gravity_residual_ug']['rms']
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--units', type=int, default=3)
    ap.add_argument('--seeds', type=int, nargs='+', default=[0])
    ap.add_argument('--json', default=None)
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            design = FleetDesign(units=args.units, logs_per_unit=3, seed=seed)
            paths = sorted(simulate_fleet(os.path.join(tmp, 'fleet'), design))
            truth = read_truth(os.path.join(tmp, 'fleet'))
            for sensor in sorted(truth):
                logs = sorted(p for p in paths if os.sep + sensor + os.sep in p)
                for k in range(2):
                    row = dict(unit_row(logs, tmp, sensor, k), seed=seed,
                               kind=truth[sensor]['kind'])
                    rows.append(row)
                    print(f"seed {seed} {sensor} ({row['kind']}) log {k}: auto chose "
                          f"{row['auto_chose']}; next log |a|-g RMS: raw "
                          f"{row['raw_next_log_ug']:.0f}, auto {row['auto_next_log_ug']:.0f}, "
                          f"field {row['field_next_log_ug']:.0f}, standard "
                          f"{row['standard_next_log_ug']:.0f} ug", flush=True)
    ratio = {m: float(np.mean([r[f'{m}_next_log_ug'] / r['field_next_log_ug'] for r in rows]))
             for m in ('auto', 'standard')}
    chose = sum(r['auto_chose'] == 'standard' for r in rows)
    print(f'{len(rows)} calibrations: auto chose the standard fit on {chose}; next-log '
          f'residual / field\'s, mean: auto {ratio["auto"]:.3f}, standard '
          f'{ratio["standard"]:.3f}')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'units': args.units, 'seeds': args.seeds, 'mean_ratio_to_field': ratio,
                       'auto_chose_standard': chose, 'rows': rows}, f, indent=1)


if __name__ == '__main__':
    main()
