"""The gyroscope model of calibrations whose estimator fits only the accelerometer.

Estimators such as ``field`` return no gyro model; ``calibrate_windows`` then asks
``DEFAULT_GYRO[0](ctx, estimate)``. This module installs ``default_gyro``:

* one orientation, fewer than six distinct orientations, a lagged temperature, or too few
  holds to leave some out: the per-axis bias polynomial (``calibrate._gyro_bias``), as
  before;
* otherwise the bias polynomial and the seed 002 static gyro model (thermal bias +
  g-sensitivity C, earth rate removed with the latitude when it is given; ``gyro_fit``)
  are refitted with hold folds left out (at most one hold per face, ``select._hold_folds``)
  and scored on the held-out still windows by | |w| - earth rate |: a still gyro reads the
  earth rate in every pose, so a pose-dependent bias (g-sensitivity) or an earth rate
  absorbed into the bias shows as a spread of |w|. The seed 002 model is kept when it is
  ``GYRO_MARGIN`` better; the note says which and why.

With pose changes (the CLI and the calibrator node collect them) they are evidence for the
gyro's scale and misalignment whatever the accelerometer model, and ``turns_gyro`` compares
(``POSE_CANDIDATES``, simplest first): the bias polynomial, the seed 002 static model
(when the conditions above hold) and the seed 002 gyro with scale and misalignment from the
pose changes (``gyro_fit.fit_gyro`` with the transitions). Each is scored held out on

* still windows: | |w| - earth rate | RMS, hold folds (``select._whole_unit_folds``: one
  hold per face, or the repeated and tilted holds one at a time), refitted without them
  (the pose changes touching a left-out hold leave with it);
* pose changes: leave one out (``gyro_rotations.heldout_rotation_errors``), the angle
  between the measured gravity direction after it and the one before carried through the
  corrected gyro, or the closure angle of a full turn (deg). The static candidates have no
  scale terms: their error is that of every pose change with Omega1 = I.

Rule: a candidate whose figure is more than ``KEEP_RATIO`` times the best on either figure
is dropped (if that drops all, the one nearest the best on its worse figure stays); of the
rest the simplest is kept unless a richer one is ``GYRO_MARGIN`` better on the figure its
extra terms explain (g-sensitivity: still; scale and misalignment: pose changes). When the
pose changes determine no Omega1 term (no rotation about any axis), the rotation fit equals
the static one and the comparison above runs as without pose changes.
"""

import numpy as np

from ..estimation.gyro_rotations import HELDOUT_FOLDS
from ..estimation.gyro_static import EARTH_RATE
#: the seed 002 static gyro model must beat the bias polynomial by this much (relative)
GYRO_MARGIN = 0.25
#: distinct orientations needed: g-sensitivity needs gravity along every axis
MIN_ORIENTATIONS = 6
#: a candidate more than this many times the best held-out figure is never kept (issue 10)
KEEP_RATIO = 1.5
#: candidates with pose changes, simplest first, and the figure their extra terms explain
POSE_CANDIDATES = (('polynomial', None), ('whole_unit_static', 'still'),
                   ('whole_unit_turns', 'pose'))
LABELS = {'polynomial': 'bias polynomial', 'whole_unit_static': 'seed 002 static model',
          'whole_unit_turns': 'seed 002 with scale/misalignment from the pose changes'}

POLYNOMIAL_NOTE = ('gyroscope: bias polynomial from stationary windows; earth rotation is not '
                   'removed (up to 7.3e-5 rad/s)')


def still_rate_error(gyro):
    """Return | |w| - earth rate | per row of corrected still-gyro readings (rad/s)."""
    return np.abs(np.linalg.norm(gyro, axis=1) - EARTH_RATE)


def _whole_unit_gyro(ctx, rows, acc, accel_model, transitions=None, priors=None,
                     first_static=None):
    """Fit the seed 002 gyro on the windows ``rows`` (corrected accel ``acc`` per window).

    ``first_static``: the ``static`` of a fit without transitions on the same rows (its
    static stage is this fit's first one; the priors differ only in the rotation terms).
    """
    from ..estimation.gyro_fit import fit_gyro
    from ..estimation.observability import Priors
    o, k = ctx.options, ctx.k
    w = ctx.windows.select(rows)
    return fit_gyro(w, ctx.tg[rows] if k else None, acc[rows],
                    ctx.gyro_t0 if k else np.zeros(3), latitude=o.latitude,
                    transitions=transitions, accel_model=accel_model,
                    accel_input=ctx.accel_input, gyro_input=ctx.gyro_input,
                    priors=priors or o.whole_unit_priors or Priors(),
                    order=o.order if k else 0, input_unit=ctx.gyro_unit,
                    first_static=first_static)


def heldout_gyro(ctx, accel_model, acc):
    """Return ({'polynomial': (m,), 'whole_unit': (m,)} held-out still errors, folds).

    ``acc``: (m, 3) specific force per window corrected by ``accel_model``.
    """
    from ..estimation.calibrate import _gyro_bias
    from .select import _hold_folds, clamp_to_training, fold_masks
    w, o = ctx.windows, ctx.options
    folds, n = _hold_folds(w)
    out = {'polynomial': np.zeros(len(w)), 'whole_unit': np.zeros(len(w))}
    for test, train in fold_masks(folds, n):
        tg = clamp_to_training(ctx.tg, w, train, ctx.gyro_input, o.range_margin)
        poly, _ = _gyro_bias(ctx.subset(train))
        wu = _whole_unit_gyro(ctx, train, acc, accel_model).model
        out['polynomial'][test] = still_rate_error(poly.correct(w.gyro[test], tg[test]))
        out['whole_unit'][test] = still_rate_error(
            wu.correct(w.gyro[test], tg[test], aux={'accel': acc[test]}))
    return out, n


def _poly_as_static(poly):
    """Return the bias polynomial in the form ``prepare_transitions`` compensates with."""
    from types import SimpleNamespace
    return SimpleNamespace(offset=poly.coeffs, beta=np.zeros(3), g=np.zeros((3, 3)))


def _pose_figures(ctx, est, poly, acc, turns_fit):
    """Return {candidate: (k,) held-out pose-change errors (deg)} and how they were held out."""
    from ..estimation.gyro_rotations import (direction_error_deg, heldout_rotation_errors,
                                             priors_like)
    from ..estimation.gyro_transitions import prepare_transitions
    from ..estimation.gyro_static import hold_directions
    prep = turns_fit.rotation.prepared
    priors = priors_like(turns_fit.rotation, ctx.options.whole_unit_priors)
    # the static model's error is the rotation fit's own before it (Omega1 = I, its prior)
    out = {'whole_unit_static': turns_fit.rotation.error_before_deg,
           'whole_unit_turns': heldout_rotation_errors(prep, priors)}
    up, sig = hold_directions(ctx.windows, acc)
    noise = np.sqrt(np.median(ctx.windows.gyro_var, axis=0))
    pp = prepare_transitions(ctx.options.transitions, up, sig, _poly_as_static(poly),
                             est.accel, ctx.accel_input, ctx.gyro_input, poly.t0, noise)
    out['polynomial'] = direction_error_deg(pp, np.eye(3))
    k = len(prep.sigma)
    return out, (f'leave-one-out error of {k} pose changes' if k <= HELDOUT_FOLDS else
                 f'held-out error of {k} pose changes in {HELDOUT_FOLDS} folds')


def _still_figures(ctx, est, acc, names, like):
    """Return ({candidate: (m,) held-out | |w| - earth rate | (nan: never held out)}, folds)."""
    from ..estimation.calibrate import _gyro_bias
    from ..estimation.gyro_rotations import priors_like
    from .select import _whole_unit_folds, clamp_to_training, fold_masks
    w, o = ctx.windows, ctx.options
    priors = priors_like(like.rotation, o.whole_unit_priors)
    folds, n = _whole_unit_folds(w)
    out = {k: np.full(len(w), np.nan) for k in names}
    for test, train in fold_masks(folds, n if n >= 2 else 0):
        tg = clamp_to_training(ctx.tg, w, train, ctx.gyro_input, o.range_margin)
        models = {'polynomial': _gyro_bias(ctx.subset(train))[0]}
        static = None
        if 'whole_unit_static' in names:
            fit = _whole_unit_gyro(ctx, train, acc, est.accel)
            models['whole_unit_static'], static = fit.model, fit.static
        models['whole_unit_turns'] = _whole_unit_gyro(ctx, train, acc, est.accel,
                                                      o.transitions, priors, static).model
        for k, m in models.items():
            out[k][test] = still_rate_error(m.correct(w.gyro[test], tg[test],
                                                      aux={'accel': acc[test]}))
    return out, n


def choose(figures, aims, keep_ratio=KEEP_RATIO, margin=GYRO_MARGIN):
    """Return (chosen, kept, why) by the rule of the module docstring.

    figures: {candidate: {figure: value}} in order of complexity; aims: {candidate: the
    figure its extra terms explain (None for the simplest)}.
    """
    names = list(figures)
    best = {f: min(figures[c][f] for c in names if f in figures[c])
            for f in {f for c in names for f in figures[c]}}
    worst = {c: max([figures[c][f] / best[f] for f in figures[c] if best[f] > 0] or [1.0])
             for c in names}
    kept = [c for c in names if worst[c] <= keep_ratio]
    why = f'dropped (> {keep_ratio:g}x the best on a figure): ' + (
        ', '.join(c for c in names if c not in kept) or 'none')
    if not kept:
        kept = [min(names, key=worst.get)]
        why += f'; all were, {kept[0]} is nearest the best'
    chosen = kept[0]
    for c in kept[1:]:
        f = aims[c]
        if f in figures[c] and figures[c][f] < (1 - margin) * figures[chosen].get(f, np.inf):
            chosen = c
    return chosen, kept, why + (f'; of the rest the simplest unless a richer one is '
                                f'{100 * margin:.0f} % better on the figure its terms explain')


def turns_gyro(ctx, est, poly, rep):
    """Return (model, report, notes) choosing with the pose changes, or None (none usable)."""
    from .select import _weighted_rms
    acc = est.accel.correct(ctx.windows.accel, ctx.ta)
    fit = _whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel,
                           ctx.options.transitions)
    if fit.rotation is None or not np.any(fit.rotation.estimated['Omega1']):
        return None
    static_ok = (ctx.n_orientations >= MIN_ORIENTATIONS and not ctx.coverage.get('missing'))
    names = [c for c, _ in POSE_CANDIDATES if c != 'whole_unit_static' or static_ok]
    pose, how = _pose_figures(ctx, est, poly, acc, fit)
    still, n_folds = _still_figures(ctx, est, acc, names, fit)
    held = np.isfinite(still['polynomial'])
    figures = {}
    for c in names:
        figures[c] = {'pose': float(np.sqrt(np.mean(pose[c] ** 2)))}
        if held.any():
            figures[c]['still'] = _weighted_rms(still[c][held], ctx.windows.n[held])
    chosen, kept, why = choose(figures, dict(POSE_CANDIDATES))
    parts = '; '.join(
        f'{c} ' + ', '.join(([f'still {figures[c]["still"]:.2e} rad/s'] if 'still' in figures[c]
                             else []) + [f'pose changes {figures[c]["pose"]:.3g} deg'])
        for c in names)
    text = (f'gyro candidates compared held out (still | |w| - earth rate | RMS, {n_folds} hold '
            f'folds; {how}, RMS): {parts}; {why}: chose '
            f'{chosen}')
    report = {'gyro_offset': rep, 'gyro_choice': {
        'model': chosen, 'candidates': {c: {('heldout_still_error_rad_s' if f == 'still' else
                                             'heldout_pose_change_error_deg'): v
                                            for f, v in figures[c].items()} for c in names},
        'kept': kept, 'folds': n_folds, 'pose_changes_scored': len(pose['whole_unit_turns']),
        'keep_ratio': KEEP_RATIO,
        'margin': GYRO_MARGIN, 'text': text}}
    if chosen == 'polynomial':
        return poly, report, [POLYNOMIAL_NOTE + f'; {text}']
    if chosen == 'whole_unit_static':
        fit = _whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel)
    report['gyro_whole_unit'] = fit.stats
    return fit.model, report, [f'gyroscope: {LABELS[chosen]}: {text}'] + list(fit.notes)


def default_gyro(ctx, est):
    """Return (gyro model, report, notes) for an Estimate without a gyro model."""
    from ..estimation.calibrate import _gyro_bias
    from .select import _hold_folds, _weighted_rms
    poly, rep = _gyro_bias(ctx)
    if (est.accel is not None and est.temperature_filter is None
            and ctx.options.transitions):
        out = turns_gyro(ctx, est, poly, rep)
        if out is not None:
            return out
    usable = (est.accel is not None and est.temperature_filter is None
              and ctx.n_orientations >= MIN_ORIENTATIONS
              and not ctx.coverage.get('missing') and _hold_folds(ctx.windows)[1] >= 2)
    if not usable:
        return poly, {'gyro_offset': rep}, [POLYNOMIAL_NOTE]
    acc = est.accel.correct(ctx.windows.accel, ctx.ta)
    res, n_folds = heldout_gyro(ctx, est.accel, acc)
    score = {k: _weighted_rms(v, ctx.windows.n) for k, v in res.items()}
    report = {'gyro_offset': rep, 'gyro_choice': {
        'heldout_still_error_rad_s': score, 'folds': n_folds, 'margin': GYRO_MARGIN}}
    text = (f'held-out still-gyro error | |w| - earth rate | RMS: bias polynomial '
            f'{score["polynomial"]:.2e}, seed 002 static model {score["whole_unit"]:.2e} '
            f'rad/s ({n_folds} hold folds)')
    if score['whole_unit'] >= (1 - GYRO_MARGIN) * score['polynomial']:
        report['gyro_choice']['model'] = 'polynomial'
        return poly, report, [POLYNOMIAL_NOTE + f'; {text}']
    fit = _whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel,
                           ctx.options.transitions or None)
    report['gyro_choice']['model'] = 'whole_unit_gyro'
    report['gyro_whole_unit'] = fit.stats
    notes = [f'gyroscope: seed 002 static model (thermal bias + g-sensitivity C) chosen over '
             f'the bias polynomial: {text}'] + list(fit.notes)
    return fit.model, report, notes


def _install():
    """Install ``default_gyro`` as ``calibrate.DEFAULT_GYRO[0]`` (via ESTIMATOR_MODULES)."""
    from ..estimation import calibrate
    calibrate.DEFAULT_GYRO[0] = default_gyro


_install()
