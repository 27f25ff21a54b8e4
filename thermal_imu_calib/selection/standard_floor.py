"""Several orientations across a temperature span: the standard fit stays the floor.

On holds in several orientations with a temperature span, ``auto`` first chooses among
the thermal families (``select.auto_policy``: field, lagged field, RVM, whole-unit). That
choice is then judged against the **standard fit with its bias polynomial in
temperature** (imu_tk's model with the flight stacks' bias-vs-T form,
``estimation/standard_fit.py``), the model every richer one must beat on data it did not
see:

* **Folds over the thermal history** (``time_runs``): the holds in time order are cut
  into ``N_RUNS`` contiguous runs; a run is held out only when the holds left for
  training still visit every face the data has at least ``MIN_FACE_VISITS`` times, so
  both fits can still separate bias from scale factor on every axis. Each fit is refitted
  on the other runs and scored on the held-out run's holds whose temperatures lie inside
  the training temperatures (interpolation: neither model is asked to extrapolate), by
  |a| - g of each hold's mean, inputs clamped as the calibration would.
* **No time run can be held out** (a short session: each face held once or twice): there
  is no held-out evidence either way, and the family the thermal comparison chose is kept,
  with a note saying the standard fit was not judged. Folds of single holds are not used
  instead: a held-out visit of a face leaves that face at one temperature in training, so
  they test extrapolation in temperature (on the simulated ``demo`` session, 12 holds,
  they scored the field model 4849 ug against the standard fit's 602 ug, while against
  the simulation's truth the field model is 555 ug RMS and the standard fit 5127 ug).
* **The decision** is the one-sided paired test of ``paired`` (level ``ALPHA``):
  the family replaces the standard fit only when it predicts the held-out holds better by
  more than the noise.

The figures of both go to the selection table and the reason (``fit.model_choice``).
"""

import numpy as np
from scipy.special import ndtri

from ..collection.segments import face_of
from ..estimation.calibrate import CalibrationRefused, ESTIMATORS, input_margins
from ..estimation.standard_fit import StandardFitError
from ..estimation.thermal_lag import lagged_axis_temperatures
from .heldout import clamp_to_training, fold_masks, Selection
from .paired import _fit, ALPHA, hold_magnitudes, hold_positions, MIN_HELDOUT, paired_test

#: contiguous runs of holds (in time) the thermal history is cut into
N_RUNS = 5
#: visits of every face the training holds must keep when a run is held out
MIN_FACE_VISITS = 2
#: families ``paired._fit`` refits quickly on training holds (the others through their
#: registered estimator)
FAST_FAMILIES = ('standard', 'field', 'whole_unit')


def time_runs(windows, n_runs=N_RUNS, min_visits=MIN_FACE_VISITS):
    """Return (fold per window, number of folds): contiguous runs of holds in time.

    Fold -1: the window always trains (its run cannot be left out without leaving a face
    with fewer than ``min_visits`` visits, or fewer than ``min_visits`` visits of a face
    the data has fewer of: then every visit trains).
    """
    ids, means = windows.hold_means()
    faces = np.array([face_of(m) for m in means])
    start = np.array([windows.t0[windows.hold == h].min() for h in ids])
    order = np.argsort(start, kind='stable')
    count = {f: int(np.sum(faces == f)) for f in set(faces) - {'tilted'}}
    fold_of = np.full(len(ids), -1)
    n = 0
    for run in np.array_split(order, min(n_runs, len(ids))):
        rest = np.setdiff1d(order, run)
        ok = all(np.sum(faces[rest] == f) >= min(min_visits, c) for f, c in count.items())
        if ok and len(run):
            fold_of[run] = n
            n += 1
    return fold_of[hold_positions(ids, windows.hold)], n


def _family_model(ctx, name, train):
    """Return (accel model, per-window model inputs) of ``name`` fitted on ``train``."""
    if name in FAST_FAMILIES:
        return _fit(ctx, name, train), ctx.ta
    rows = train if ctx.accel_rows is None else train & ctx.accel_rows
    try:
        est = ESTIMATORS[name](ctx.subset(rows))
    except (CalibrationRefused, StandardFitError, ValueError, np.linalg.LinAlgError):
        return None, None
    filt = getattr(est, 'temperature_filter', None)
    ta = ctx.ta if filt is None else lagged_axis_temperatures(
        ctx.windows, np.asarray(filt.tau_s, float), ctx.accel_input)
    return est.accel, ta


def _inside(ctx, train, test_holds):
    """Return a bool per hold id: its windows' inputs lie inside the training range."""
    w = ctx.windows
    if ctx.k == 0:
        return np.ones(len(test_holds), bool)
    lo, hi = w.temp[train].min(0), w.temp[train].max(0)
    return np.array([bool(np.all((w.temp[w.hold == h] >= lo) & (w.temp[w.hold == h] <= hi)))
                     for h in test_holds])


def heldout_against_standard(ctx, name, folds, n):
    """Return ({'standard': r, name: r} per-hold held-out |a| - g in m/s^2, hold ids).

    NaN: the hold was not held out, or lies outside the training temperatures; inf: the
    candidate could not be fitted without it.
    """
    w, g = ctx.windows, ctx.options.gravity
    ids = w.hold_ids
    pos = hold_positions(ids, w.hold)
    out = {k: np.full(len(ids), np.nan) for k in ('standard', name)}
    margin = input_margins(w, ctx.options) if ctx.k else 0.0
    for test, train in fold_masks(folds, n):
        held = np.unique(pos[test])
        keep = _inside(ctx, train, ids[held])
        if not keep.any():
            continue
        scored = np.isin(pos, held[keep]) & test
        for k in out:
            model, ta = _family_model(ctx, k, train)
            if model is None:
                out[k][held[keep]] = np.inf
                continue
            tc = clamp_to_training(ta, w, train, ctx.accel_input, margin)
            a = model.correct(w.accel[scored], tc[scored])
            got, r = hold_magnitudes(a, w.n[scored], pos[scored], len(ids), g)
            out[k][got] = r[got]
    return out, ids


def judge_family(ctx, sel):
    """Return the Selection after judging ``sel``'s family against the standard fit.

    ``sel``: what the thermal policy chose. The standard fit replaces it unless the
    family predicts the holds of held-out time runs better by more than the noise.
    Without ``MIN_HELDOUT`` held-out holds the family is kept (no evidence).
    """
    g = ctx.options.gravity
    name = sel.model
    folds, n = time_runs(ctx.windows)
    res, _ = heldout_against_standard(ctx, name, folds, n)
    z, m = paired_test(res['standard'], res[name])
    how = (f'{n} contiguous runs of holds in time held out (training keeps every face at '
           f'least {MIN_FACE_VISITS} times), scored inside the training temperatures')
    limit = float(-ndtri(ALPHA))
    rms = {k: float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2))) / g * 1e6
           if np.isfinite(r).any() else float('nan') for k, r in res.items()}
    if m < MIN_HELDOUT:
        sel.reason = (f'{sel.reason}; not judged against the standard fit: {m} holds can be '
                      f'held out in runs of time that keep every face {MIN_FACE_VISITS} times '
                      f'in training (< {MIN_HELDOUT}), no held-out evidence either way, so '
                      f'{name} is kept (collect each face at more temperatures for the '
                      'comparison)')
        sel.table = dict(sel.table, **{'standard (vs family, held out)': {
            'residual_ug': None, 'heldout_holds': m}})
        return sel
    wins = bool(np.isfinite(z) and z > limit)
    verdict = (f'{name} predicts them better by more than the noise: kept' if wins else
               f'{name} does not predict them better by more than the noise: the standard '
               'fit (bias polynomial in temperature)')
    why = (f'against the standard fit ({how}): held-out |a|-g RMS over {m} holds, standard '
           f'{rms["standard"]:.1f} ug, {name} {rms[name]:.1f} ug, paired z {z:.2f} (limit '
           f'{limit:.2f}); {verdict}')
    table = dict(sel.table)
    table['standard (vs family, held out)'] = {'residual_ug': rms['standard'],
                                               'heldout_holds': m}
    table[f'{name} (vs standard, held out)'] = {'residual_ug': rms[name], 'z': z,
                                                'heldout_holds': m}
    if wins:
        sel.reason = f'{sel.reason}; {why}'
        sel.table = table
        return sel
    return Selection('standard', f'{sel.reason}; {why}', table=table, groups='holds')
