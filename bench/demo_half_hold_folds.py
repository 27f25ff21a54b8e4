"""Short six-face sessions: whether half-hold folds pick whole_unit where it generalises.

A measurement, not a default (criteria written before the run: docs/thermal_models.md).
On a ``demo`` log (six faces twice) ``auto`` does not offer ``whole_unit``: with hold folds
each fit sees one hold per face and the held-out score is extrapolation. Here the
whole-unit check (``selection.whole_unit_select``) is run with other folds, patched in for
this process only: the earlier half of every hold (by window start) against the later half,
so every face stays in training (holds of one window always train); no tilted-hold minimum,
two folds allowed. Its decision (whole_unit chosen or field) is read from the calibration's
reason; the floor's later step is recorded too but is not the measured rule. Each pick is
scored on the device's next cold start (``demo-validation``, |a| - g RMS over its holds, ug)
against ``--model field`` and ``--model whole_unit`` on the same log.

    .venv/bin/python bench/demo_half_hold_folds.py --first-seed 95100 --devices 12 \
        [--variant datasheet-cross-axis] --json out.json

No ROS import.
"""

import os
import re
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from demo_next_coldstart import calibrate_and_score, device_rows, report  # noqa: E402


def half_hold_folds(windows):
    """Return (fold per window, 2): each hold's earlier windows fold 0, its later ones 1."""
    folds = np.full(len(windows), -1)
    for h in np.unique(windows.hold):
        idx = np.flatnonzero(windows.hold == h)
        if len(idx) < 2:
            continue                    # a one-window hold always trains
        idx = idx[np.argsort(windows.t0[idx], kind='stable')]
        half = (len(idx) + 1) // 2
        folds[idx[:half]], folds[idx[half:]] = 0, 1
    return folds, 2


def _patch():
    from thermal_imu_calib.selection import whole_unit_select as wus
    wus._whole_unit_folds = half_hold_folds
    wus.WHOLE_UNIT_MIN_TILTED = 0
    wus.WHOLE_UNIT_MIN_FOLDS = 2


def one_device(seed, work, variant):
    """Return the scores on the next cold start (ug) and the patched check's decision."""
    from thermal_imu_calib.formats import read_calibration
    out, cals, _ = calibrate_and_score(seed, work, variant, [
        ('field', 'field', None), ('whole_unit', 'whole_unit', None),
        ('auto_half_hold', 'auto', _patch)])
    with open(cals['auto_half_hold']) as f:
        text = f.read()
    out['check_chose_whole_unit'] = 'chose whole_unit (seed 002)' in text
    out['check_ran'] = 'candidates compared held out: field, whole_unit' in text
    m = re.search(r'\|a\|-g RMS field ([0-9.]+) ug, whole_unit ([0-9.]+) ug', text)
    out['heldout_field_ug'], out['heldout_whole_unit_ug'] = (
        (float(m.group(1)), float(m.group(2))) if m else (None, None))
    out['final_kind'] = read_calibration(cals['auto_half_hold']).accel.kind
    out['pick'] = out['whole_unit'] if out['check_chose_whole_unit'] else out['field']
    return out


def summary(rows):
    """Return the criteria's figures over ``rows`` (pick against field and the better one)."""
    f = np.array([r['field'] for r in rows.values()], float)
    w = np.array([r['whole_unit'] for r in rows.values()], float)
    p = np.array([r['pick'] for r in rows.values()], float)
    return {'geometric_mean_pick_over_field': round(float(np.exp(np.mean(np.log(p / f)))), 3),
            'worst_pick_over_field': round(float(np.max(p / f)), 3),
            'picked_the_better': f'{int(np.sum(p == np.minimum(f, w)))} of {len(f)}',
            'whole_unit_better': f'{int(np.sum(w < f))} of {len(f)}',
            'check_chose_whole_unit': int(sum(r['check_chose_whole_unit']
                                              for r in rows.values())),
            'check_ran': int(sum(r['check_ran'] for r in rows.values())),
            'geometric_mean_whole_unit_over_field': round(float(np.exp(np.mean(
                np.log(w / f)))), 3)}


def main():
    """Run the devices, print each row and the summary, optionally write the JSON."""
    args, rows = device_rows(__doc__, 95100, one_device)
    report(args, summary(rows), rows)


if __name__ == '__main__':
    main()
