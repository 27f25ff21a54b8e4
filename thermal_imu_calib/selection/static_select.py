"""Several orientations: the standard static fit is the floor; richer models must beat it.

``auto`` on holds in several orientations starts from the standard fit (imu_tk's bias,
scale and misalignment on every hold, ``estimation/standard_fit.py``), and everything
beyond it is a claim that held-out holds must support:

* **rules that leave holds out** (``hold_consistency``: pose repeats that disagree, sensor-
  state epochs): the standard fit with and without those holds is refitted on the training
  holds of each fold and scored on every held-out hold. The rule is applied only when
  leaving the holds out predicts them better, by more than the noise;
* **richer families** (seed 000 ``field``, seed 002 ``whole_unit``): refitted on the same
  folds and scored on the same held-out holds; one replaces the standard fit only when it
  predicts them better by more than the noise. Among several that do, the best.

"Better by more than the noise" is a one-sided paired test at level ``ALPHA`` on the held-
out holds: per hold h the difference of squared residuals d_h = r_std,h^2 - r_cand,h^2 (each
r the held-out |a| - g of the hold's mean), significant when mean(d) exceeds
``z(ALPHA)`` standard errors of the mean. No figure of any one recording sets it. With
fewer than ``MIN_HELDOUT`` held-out holds there is no evidence, and the standard fit stays.

The folds (``heldout_folds``) leave out one hold at a time, and only holds whose absence
loses no face (repeats and tilted poses), so a training set always keeps each axis up and
down when the data had it. The summary and ``fit.model_choice`` list every candidate's
held-out figure, and ``fit.hold_consistency.heldout`` what a rule would have gained.
"""

import dataclasses

import numpy as np
from scipy.special import ndtri

from ..estimation.calibrate import (AUTO_POLICY, check_faces_up_and_down, CalibrationRefused,
                                    HOLD_RULE_JUDGE)
from ..estimation.standard_fit import weak_axes
from ..collection.segments import face_of
from .paired import (_fit, ALPHA, hold_magnitudes, hold_positions,  # noqa: F401
                     MIN_HELDOUT, paired_test)
from .select import clamp_to_training, fold_masks
from .standard_floor import judge_family

#: most folds (refits per candidate); more foldable holds share folds round robin
MAX_FOLDS = 24


def heldout_folds(windows, max_folds=MAX_FOLDS, within=None):
    """Return (fold per window, number of folds); -1: the hold always trains.

    A hold is held out alone (leave one hold out) when leaving it loses no face: a tilted
    pose, or a face held more than once. With more such holds than ``max_folds`` they are
    dealt round robin in time order, and a fold that would take every visit of a face
    keeps those visits in training. So every training set has each axis up and down when
    the data had it, and as many of the repeated visits (other temperatures, other times)
    as possible: two face-wise folds would leave each face once and test extrapolation.
    ``within`` (bool mask over windows): a fit that trains only on those rows is compared
    too, so a hold among them counts as repeated only when its face is repeated among them.
    """
    ids, means = windows.hold_means()
    faces = [face_of(m) for m in means]
    count = {f: faces.count(f) for f in set(faces)}
    inside = (np.ones(len(ids), bool) if within is None
              else np.isin(ids, np.unique(windows.hold[within])))
    inner = [f for f, i in zip(faces, inside) if i]
    count_in = {f: inner.count(f) for f in set(inner)}
    order = np.argsort(windows.hold_starts()[1])
    foldable = [j for j in order if faces[j] == 'tilted' or (
        count[faces[j]] > 1 and (not inside[j] or count_in[faces[j]] > 1))]
    n = min(len(foldable), max_folds)
    fold_of = np.full(len(ids), -1)
    for r, j in enumerate(foldable):
        fold_of[j] = r % n
    for f in range(n):
        members = np.flatnonzero(fold_of == f)
        for face in {faces[j] for j in members} - {'tilted'}:
            mine = [j for j in members if faces[j] == face]
            mine_in = [j for j in mine if inside[j]]
            if len(mine) == count[face] or (mine_in and len(mine_in) == count_in[face]):
                fold_of[mine] = -1
    return fold_of[hold_positions(ids, windows.hold)], n


def heldout_residuals(ctx, names, accel_rows=None, within=None):
    """Return ({name: per-hold held-out |a| - g (m/s^2), NaN where not held out}, hold ids).

    Each candidate is refitted on the training holds of every fold (``accel_rows``, if
    given, further restricts what it may train on) and applied to the held-out windows,
    inputs clamped to the training range; the residual of a hold is that of its mean.
    ``within``: the rows the most restricted candidate trains on (``heldout_folds``).
    """
    w, o = ctx.windows, ctx.options
    folds, n = heldout_folds(w, within=within if within is not None else ctx.accel_rows)
    ids = w.hold_ids
    pos = hold_positions(ids, w.hold)
    out = {name: np.full(len(ids), np.nan) for name in names}
    for test, train in fold_masks(folds, n):
        ta = clamp_to_training(ctx.ta, w, train, ctx.accel_input, o.range_margin)
        for name in names:
            rows = accel_rows.get(name) if accel_rows else None
            c = ctx if rows is None else dataclasses.replace(ctx, accel_rows=rows)
            model = _fit(c, name, train)
            if model is None:
                out[name][np.unique(pos[test])] = np.inf
                continue
            a = model.correct(w.accel[test], ta[test])
            held, r = hold_magnitudes(a, w.n[test], pos[test], len(ids), o.gravity)
            out[name][held] = r[held]
    return out, ids


def _rms(r, mask=None):
    ok = ~np.isnan(r) if mask is None else (~np.isnan(r) & mask)
    return float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float('nan')


def judge_rule(ctx, keep):
    """Decide held out whether leaving the holds ``~keep`` (window mask) out is supported.

    The standard fit with and without those holds is refitted on every fold and scored on
    every held-out hold, the ones the rule would leave out included: scored on the holds it
    keeps only, leaving out any group of holds looks better, as the fit then serves just
    them (on imu_tk's xsens recording a rule that called model error a sensor change would
    pass so). Returns (applied, report dict).
    """
    g = ctx.options.gravity
    res, ids = heldout_residuals(ctx, ['standard', 'standard-kept'],
                                 {'standard-kept': keep}, within=keep)
    z, n = paired_test(res['standard'], res['standard-kept'])
    limit = float(-ndtri(ALPHA))
    applied = bool(np.isfinite(z) and z > limit)
    rep = {'heldout_holds': n, 'z': z, 'z_limit': limit,
           'all_holds_ug': _rms(res['standard']) / g * 1e6,
           'holds_left_out_ug': _rms(res['standard-kept']) / g * 1e6,
           'applied': applied}
    if not n:   # e.g. one orientation: no standard fit, so nothing to judge by
        rep.update(all_holds_ug=None, holds_left_out_ug=None, z=None)
        rep['text'] = ('no hold can be held out and scored by the standard fit (it needs '
                       'several orientations), so nothing supports leaving them out')
        return applied, rep
    rep['text'] = (f'leaving them out {"predicts" if applied else "does not predict"} the '
                   f'{n} held-out holds better by more than the noise (standard fit '
                   f'{rep["all_holds_ug"]:.1f} ug with them, {rep["holds_left_out_ug"]:.1f} '
                   f'ug without; paired z {z:.2f}, limit {limit:.2f})')
    return applied, rep


def select_static(ctx, candidates=('field', 'whole_unit')):
    """Return (model name, reason, table): the standard fit unless a candidate wins held out."""
    g = ctx.options.gravity
    names = ['standard'] + [c for c in candidates if _available(ctx, c)]
    res, ids = heldout_residuals(ctx, names)
    limit = float(-ndtri(ALPHA))
    kept = (np.isin(ids, np.unique(ctx.windows.hold[ctx.accel_rows]))
            if ctx.accel_rows is not None else None)
    table = {'standard': {'residual_ug': _rms(res['standard'], kept) / g * 1e6}}
    winners = []
    for name in names[1:]:
        z, n = paired_test(res['standard'], res[name], kept)
        table[name] = {'residual_ug': _rms(res[name], kept) / g * 1e6, 'z': z,
                       'heldout_holds': n}
        if np.isfinite(z) and z > limit:
            winners.append(name)
    n_held = int(np.sum(~np.isnan(res['standard']) & (True if kept is None else kept)))
    chosen = min(winners, key=lambda k: table[k]['residual_ug']) if winners else 'standard'
    parts = ', '.join(f'{k} {v["residual_ug"]:.1f} ug' for k, v in table.items())
    if n_held < MIN_HELDOUT:
        why = (f'{n_held} holds can be held out without losing a face (< {MIN_HELDOUT}): no '
               'held-out evidence for anything beyond the standard fit')
    else:
        why = (f'held-out |a|-g RMS over {n_held} holds ({parts}); a candidate replaces the '
               f'standard fit only when it predicts them better by more than the noise '
               f'(paired one-sided test at {ALPHA:g}, z > {limit:.2f})')
    return chosen, why + f': chose {chosen}', table


def _available(ctx, name):
    if name == 'field':
        try:
            check_faces_up_and_down(ctx.accel_view())
        except CalibrationRefused:
            return False
        return True
    ids, means = ctx.accel_view().windows.hold_means()
    return ctx.n_orientations >= 4 and not weak_axes(
        means / np.linalg.norm(means, axis=1)[:, None])


def auto_policy(ctx):
    """``--model auto``: the standard fit unless held-out holds prefer another.

    One orientation: ``select.auto_policy`` (offset models). Several orientations with a
    temperature input that spans enough for thermal terms and every axis held up and down:
    the thermal families as before (``select.select_multi``, ``select.select_whole_unit``),
    then the chosen one judged against the standard fit with its bias polynomial in
    temperature over the thermal history (``standard_floor.judge_family``: contiguous runs
    of holds held out, scored inside the training temperatures). Otherwise (no
    temperature, a flat one, or faces missing) the standard fit, replaced only by a family
    that predicts held-out holds better (``select_static``).
    When ``field`` wins, its thermal variants are chosen as before (``select_multi``).
    """
    from .select import auto_policy as thermal_policy, select_multi, Selection
    if ctx.n_orientations == 1:
        return thermal_policy(ctx)
    if ctx.k and _available(ctx, 'field'):
        thermal_policy(ctx)
        sel = judge_family(ctx, ctx.thermal_selection)
        ctx.thermal_selection = sel
        return sel.model, sel.reason
    name, why, table = select_static(ctx)
    if name == 'field':
        sel = select_multi(ctx)
        sel.reason = f'{why}; {sel.reason}'
        sel.table.update({f'{k} (vs standard)': v for k, v in table.items()})
    else:
        sel = Selection(name, why, table=table, groups='holds')
    ctx.thermal_selection = sel
    return sel.model, sel.reason


AUTO_POLICY[0] = auto_policy
HOLD_RULE_JUDGE[0] = judge_rule
