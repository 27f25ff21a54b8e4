"""Trace of whole_unit's term-selection folds inside ``auto`` (docs/whole_unit.md, fix 3).

Calibrates ``mems-coldstart`` SEED with ``auto`` (as ``bench/auto_validation.py``), with the
term selection's folds either as on main (``main``: holds dealt round robin in time) or dealt
per face as the held-out model choice deals them (``faces``: ``_whole_unit_folds``, fix 3,
not adopted), and prints for every term selection run (the full fit and ``auto``'s held-out
refits) its number of holds and folds, the fold fits stopped by their budget and the
cross-validation scores; then ``auto``'s reason and the vector error on ``mems-validation``
(ug).

Usage: ``python bench/wu_folds_trace.py {main,faces} SEED`` (about a minute a seed)
"""

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import bench_mems as bm  # noqa: E402
from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.estimation import whole_unit_accel as wua  # noqa: E402
from thermal_imu_calib.selection.heldout import _whole_unit_folds  # noqa: E402

_SELECT = wua._select_by_cv
RUNS = []


def face_folds(windows, k=wua.CV_FOLDS):
    """Fix 3: the folds of the held-out model choice (a face held once: not handled)."""
    folds, _ = _whole_unit_folds(windows)
    if (folds < 0).any():
        raise SystemExit('a face was held once: fix 3 is not defined here')
    return folds


def traced(lay, free, p1, run, resid, windows, ns, no, tol):
    """``_select_by_cv``, recording what each run saw and scored."""
    current, scores = _SELECT(lay, free, p1, run, resid, windows, ns, no, tol)
    folds = wua.hold_folds(windows, min(wua.CV_FOLDS, len(windows.hold_ids)))
    RUNS.append({'holds': len(windows.hold_ids), 'folds': len(np.unique(folds)),
                 'free terms before / after': [int(free.sum()), int(current.sum())],
                 'scores': {k: round(v, 3) if isinstance(v, float) else v
                            for k, v in scores.items()}})
    return current, scores


def main(argv=None):
    """Run one variant on one seed; print a JSON line per term selection and the result."""
    variant, seed = (argv or sys.argv[1:])[:2]
    if variant == 'faces':
        wua.hold_folds = face_folds
    elif variant != 'main':
        raise SystemExit('variant: main or faces')
    wua._select_by_cv = traced
    res, _ = bm.calibrate([sim.simulate('mems-coldstart', int(seed))], 'auto')
    for r in RUNS:
        print(json.dumps(r))
    val = sim.simulate('mems-validation', int(seed))
    vw, f_true, w_true = bm.validation_windows(val)
    m = bm.metrics(vw, res.calibration, f_true, w_true, val.gravity)
    print(json.dumps({'variant': variant, 'seed': int(seed),
                      'model': res.report['model_choice']['model'],
                      'vector_ug': m['vector_error_ug'],
                      'reason': res.report['model_choice']['reason']}))


if __name__ == '__main__':
    main()
