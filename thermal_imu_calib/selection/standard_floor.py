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
  the RMS over each hold's windows of |a| - g (m/s^2), inputs clamped as the calibration
  would.
* **No time run can be held out** (a short session: each face held once or twice): the
  hold folds of the thermal comparison (``multi_select``: at most one hold per face out)
  at the hold tilts of one field fit on all holds (``heldout_hold_folds``). Per fold the
  family's thermal part and the *standard form* (constant scale factor, bias polynomial in
  T: the standard fit's thermal model in the same frame) are refitted on the training
  holds, and each held-out window's raw output is turned back into specific force at its
  clamped temperature: the score, per held-out hold the RMS over its windows of |a| - g
  (a hold of a warm-up spans a temperature range that its mean would average away), does
  not use that hold's tilt. Refitting the whole family instead (its tilts too) was tried
  and rejected: a held-out visit of a face leaves that face at one temperature, and the
  refitted tilts absorb it (on the simulated ``demo`` session that scored the field
  model 4849 ug against the standard fit's 602 ug, while against the simulation's truth
  the field model is 555 ug RMS and the standard fit 5127 ug; at fixed tilts: field 128
  ug, standard form 400 ug, paired z 2.81). Families this frame cannot refit
  (``whole_unit``), or too few held-out holds, are no evidence: the **standard fit** is
  returned, with a note saying so.
* **The decision** is the one-sided paired test of ``paired`` (level ``ALPHA``):
  the family replaces the standard fit only when it predicts the held-out holds better by
  more than the noise.

The figures of both go to the selection table and the reason (``fit.model_choice``).
"""

import numpy as np
from scipy.special import ndtri

from ..collection.segments import face_of
from ..estimation.calibrate import CalibrationRefused, FLOOR_REASON, input_margins
from ..estimation.context import estimator
from ..estimation.standard_fit import StandardFitError
from ..estimation.thermal_lag import lagged_axis_temperatures
from .heldout import _hold_folds, clamp_to_training, fold_masks, Selection
from .multi_select import (_field_design, _field_fit, _prior, _up_per_window, fit_rvm_multi,
                           resolved_order)
from .paired import (_fit, ALPHA, hold_positions, MIN_HELDOUT, paired_test,
                     window_rms)

#: contiguous runs of holds (in time) the thermal history is cut into
N_RUNS = 5
#: visits of every face the training holds must keep when a run is held out
MIN_FACE_VISITS = 2
#: families ``paired._fit`` refits quickly on training holds (the others through their
#: registered estimator)
FAST_FAMILIES = ('standard', 'field', 'whole_unit')
#: families ``heldout_hold_folds`` refits at fixed hold tilts (``multi_select``'s frame)
TILT_FAMILIES = ('field', 'field-lag', 'rvm')


def time_runs(windows, n_runs=N_RUNS, min_visits=MIN_FACE_VISITS):
    """Return (fold per window, number of folds): contiguous runs of holds in time.

    Fold -1: the window always trains (its run cannot be left out without leaving a face
    with fewer than ``min_visits`` visits, or fewer than ``min_visits`` visits of a face
    the data has fewer of: then every visit trains).
    """
    ids, means = windows.hold_means()
    faces = np.array([face_of(m) for m in means])
    start = windows.hold_starts()[1]
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
        est = estimator(name)(ctx.subset(rows))
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
            got, r = window_rms(a, w.n[scored], pos[scored], len(ids), g)
            out[k][got] = r[got]
    return out, ids


def _polynomial_correct(raw, y, f, dt, dtc, train, test, b0, k0, order, thermal_scale):
    """Return one axis' held-out specific force (m/s^2) of the linear thermal fit.

    raw = b0 + (k0 + c(dT)) f + d(dT), with c a polynomial of ``order`` when
    ``thermal_scale`` (the field model's thermal part, ``multi_select._field_design``,
    seed 000 eq. 8) else a constant (the standard form: the design's dT^0 scale column
    and the bias columns); fitted on ``y = raw - b0 - k0 f`` of the training windows,
    then inverted on the test windows at their clamped ``dtc``.
    """
    cols = (np.arange(2 * order + 2) if thermal_scale
            else np.r_[0, np.arange(order + 1, 2 * order + 2)])
    ns = order + 1 if thermal_scale else 1
    coef, *_ = np.linalg.lstsq(_field_design(dt, f, order)[train][:, cols], y[train],
                               rcond=None)
    vt = _field_design(dtc[test], np.ones(int(test.sum())), order)[:, cols]
    return (raw[test] - b0 - vt[:, ns:] @ coef[ns:]) / (k0 + vt[:, :ns] @ coef[:ns])


def heldout_hold_folds(ctx, sel):
    """Return ({'standard': r, family: r} per-hold held-out residual (m/s^2), folds).

    Hold folds (``heldout._hold_folds``: at most one hold per face out) at the hold tilts
    of one field fit on all holds. Per fold the family (field, lagged field: polynomial by
    linear least squares; RVM: its kernels) and the standard form (constant scale factor,
    bias polynomial in T, in the raw temperature) are refitted on the training holds and
    correct the held-out windows at their temperatures clamped to the training range; a
    hold's residual is the sample-weighted RMS of its windows' |a| - g. NaN:
    not held out (fewer than 2 folds, or a family outside ``TILT_FAMILIES``).
    """
    w, g, name = ctx.windows, ctx.options.gravity, sel.model
    ids = w.hold_ids
    out = {k: np.full(len(ids), np.nan) for k in ('standard', name)}
    folds, n = _hold_folds(w)
    if n < 2 or name not in TILT_FAMILIES or ctx.k == 0:
        return out, n
    pos = hold_positions(ids, w.hold)
    up = _up_per_window(w, _field_fit(ctx, w, ctx.ta, refine=False))
    k0, b0, s = _prior(ctx)
    f = g * up @ np.asarray(s).T
    y = w.accel - b0 - k0 * f
    s_inv = np.linalg.inv(s)
    temps = {'standard': ctx.ta, name: ctx.ta}
    if name == 'field-lag' and sel.tau_s is not None:
        temps[name] = lagged_axis_temperatures(w, np.asarray(sel.tau_s, float),
                                               ctx.accel_input)
    margin = input_margins(w, ctx.options)
    orders = {k: resolved_order(ctx, ta) for k, ta in temps.items()}
    for fold in range(n):
        test = folds == fold
        train = ~test
        for k, ta in temps.items():
            tc = clamp_to_training(ta, w, train, ctx.accel_input, margin)
            if k == 'rvm':
                model, _ = fit_rvm_multi(ctx, w.select(train), None,
                                         (sel.kernels or {}).get('rvm'), None, up[train])
                a = model.correct(w.accel[test], tc[test])
            else:
                order = orders[k]
                a = np.stack([_polynomial_correct(
                    w.accel[:, ax], y[:, ax], f[:, ax], ta[:, ax] - ctx.t0[ax],
                    tc[:, ax] - ctx.t0[ax], train, test, b0[ax], k0[ax], order,
                    k != 'standard') for ax in range(3)], 1) @ s_inv.T
            got, r = window_rms(a, w.n[test], pos[test], len(ids), g)
            out[k][got] = r[got]
    return out, n


def judge_family(ctx, sel):
    """Return the Selection after judging ``sel``'s family against the standard fit.

    ``sel``: what the thermal policy chose. The standard fit replaces it unless the
    family predicts held-out holds better by more than the noise: holds of contiguous
    time runs, or, when no run can be held out, hold folds at fixed tilts
    (``heldout_hold_folds``). Without ``MIN_HELDOUT`` held-out holds either way there
    is no evidence for the family, and the standard fit is returned.
    """
    g = ctx.options.gravity
    name = sel.model
    folds, n = time_runs(ctx.windows)
    res, _ = heldout_against_standard(ctx, name, folds, n)
    z, m = paired_test(res['standard'], res[name])
    how = (f'{n} contiguous runs of holds in time held out (training keeps every face at '
           f'least {MIN_FACE_VISITS} times), scored inside the training temperatures')
    if m < MIN_HELDOUT:
        res, n_folds = heldout_hold_folds(ctx, sel)
        z, m2 = paired_test(res['standard'], res[name])
        how = (f'no run of holds in time can be held out and keep every face '
               f'{MIN_FACE_VISITS} times in training ({m} holds); instead {n_folds} hold '
               'folds (at most one hold per face out) at the hold tilts of one field fit, '
               f'the standard form (constant scale factor, bias polynomial in T) against '
               f'{name}, refitted without the fold' if n_folds >= 2 else
               f'no run of holds in time can be held out and keep every face '
               f'{MIN_FACE_VISITS} times in training, nor a hold of a face (a face was '
               'held only once: no split keeps every axis up and down in training)')
        m = m2
    limit = float(-ndtri(ALPHA))
    rms = {k: float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2))) / g * 1e6
           if np.isfinite(r).any() else float('nan') for k, r in res.items()}
    table = dict(sel.table)
    table['standard (vs family, held out)'] = {
        'residual_ug': rms['standard'] if m >= MIN_HELDOUT else None, 'heldout_holds': m}
    if m < MIN_HELDOUT:
        why = (f'{FLOOR_REASON}: {how}: {m} held-out holds (< {MIN_HELDOUT}), no '
               f'held-out evidence that {name} is better, so the standard fit (bias '
               'polynomial in temperature) is used; to let auto judge a thermal family, '
               'hold every face at least twice, at different temperatures')
        return Selection('standard', f'{sel.reason}; {why}', table=table, groups='holds')
    wins = bool(np.isfinite(z) and z > limit)
    verdict = (f'{name} predicts them better by more than the noise: kept' if wins else
               f'{name} does not predict them better by more than the noise: the standard '
               'fit (bias polynomial in temperature)')
    why = (f'{FLOOR_REASON} ({how}): held-out |a|-g RMS over {m} holds, standard '
           f'{rms["standard"]:.1f} ug, {name} {rms[name]:.1f} ug, paired z {z:.2f} (limit '
           f'{limit:.2f}); {verdict}')
    table[f'{name} (vs standard, held out)'] = {'residual_ug': rms[name], 'z': z,
                                                'heldout_holds': m}
    if wins:
        sel.reason = f'{sel.reason}; {why}'
        sel.table = table
        return sel
    return Selection('standard', f'{sel.reason}; {why}', table=table, groups='holds')
