"""``--model auto``: choose the thermal model by held-out validation on the collected data.

One orientation: only an offset per axis as a function of temperature is observable (the
bias and scale of an axis separate only between its up and down poses). Every candidate
below is such an offset model; they differ in the shape of the dependence, which needs the
temperature to move. When the degC inputs span less than ``SINGLE_MIN_SPAN`` over the
windows (a soak, a robot on its mount at a steady temperature) auto ends at ``offset``
(order by cross-validation) without comparing shapes: a held-out gain of a richer model over
such a span is a drift in time that happens to correlate with temperature (BMI270 soaks:
0.4 and 0.03 degC, the accelerometer drifting 16 mg in 80 s while the temperature is flat).

One orientation across a temperature span (warm-up, chamber cycle): the lag search
(thermal_lag.estimate_tau, same polynomial order with and without the lag) decides whether
the models see a first-order lagged temperature. The candidates are the offset polynomial
(order per axis by CV, 0..3) with and without that lag and the RVM (seed 003) with the
chosen filter. Every candidate is
refitted with one temperature leg (chamber cycle), hold, or contiguous time block (single
warm-up) left out, and scored on it: the held-out drift is the corrected output minus its
mean over the training part (the constant is not observable in one pose), inputs clamped
to the training range, RMS over windows and axes, divided by the raw signal's held-out
drift, averaged over accelerometer and gyroscope. Among the candidates with the chosen
filter the simplest within 5 % of the best wins (order: offset, lag, rvm, rvm-lag).

Several orientations: the seed 000 field model is fitted once for the hold tilts; with
those tilts fixed, its thermal polynomial (by linear least squares), the same in a lagged
temperature (when the gyro-bias lag search finds one) and the bias/scale RVM are refitted
with holds left out (at most one per face) and scored by the held-out raw-output residual.
The field model stays unless the lagged one is 10 % and the RVM 50 % better.

Whole-unit (seed 002): when the field model was chosen, the field calibration (field model
+ gyro bias polynomial) and the whole-unit one are refitted with the same hold folds and
scored on the held-out holds by the gravity-norm residual |a| - g (the one accelerometer
score both admit without the held-out tilts) and by the still gyro's |w| (the earth rate
at most; a pose-dependent bias such as g-sensitivity makes it larger). This runs only with
``WHOLE_UNIT_MIN_TILTED`` holds off the six faces (misalignment is what the field model
lacks without a lab prior) and ``WHOLE_UNIT_MIN_FOLDS`` folds. The whole-unit model is
chosen when it is ``WHOLE_UNIT_MARGIN`` better on |a| - g and no more than
``WHOLE_UNIT_GYRO_SLACK`` worse on |w|. It then also fits the gyro's scale and
misalignment from the pose changes.

``auto_policy`` is installed as ``calibrate.AUTO_POLICY[0]``; its decision and the table of
held-out errors go to ``ctx.thermal_selection`` so that the estimators registered here
reuse the time constant and RVM kernels instead of searching again.

Cohesive: one algorithm, held-out validation of candidate families, with the estimator
registrations that share its fit helpers.
"""

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Dict, Optional

import numpy as np

from ..input_units import is_temperature
from ..thermal_input import ThermalFilter
from ..calibration import Calibration
from ..estimation.calibrate import (AUTO_POLICY, CalibrateOptions, CalibrationRefused,
                                    check_faces_up_and_down, Estimate, estimate_field,
                                    input_margins, input_units, make_context, ORDER_SPAN,
                                    register_estimator, valid_range)
from ..estimation.field_estimator import fit_field_model
from ..estimation.offset_fit import fit_offset_model
from ..collection.segments import face_of
from ..estimation.rvm_fit import fit_rvm_bias_scale, fit_rvm_offset
from ..estimation.thermal_lag import cv_groups, estimate_tau, lagged_axis_temperatures, tau_or_none
from .time_folds import select_history, turns_both_ways

#: candidates in order of complexity (parsimony prefers the earlier one on a near tie)
SINGLE_CANDIDATES = ('offset', 'lag', 'rvm', 'rvm-lag')
MULTI_CANDIDATES = ('field', 'field-lag', 'rvm')
#: a more complex single-orientation candidate must be this much better (relative)
SINGLE_MARGIN = 0.05
#: one orientation: degC span (over the windows) below which auto ends at ``offset``
#: (the field model's span for a first-order term, ``calibrate.ORDER_SPAN[1]``)
SINGLE_MIN_SPAN = ORDER_SPAN[1]
#: the lag is used when it cuts the held-out error of the lag search by this much
LAG_MIN_IMPROVEMENT = 0.10
#: several orientations: the lagged field model must beat the field model by this much
MULTI_MARGIN = 0.10
#: ... and the RVM the better of them by this much (a richer model that only matches the
#: parametric one is not worth it)
MULTI_RVM_MARGIN = 0.5
#: the gyro-bias lag search must improve by this much before a lag is tried
MULTI_LAG_IMPROVEMENT = 0.20
#: at most this many hold folds in the several-orientation comparison (fewer when a face
#: was held fewer times)
MULTI_FOLDS = 5
#: several orientations with tilted holds: the whole-unit model must beat the field model's
#: held-out gravity-norm residual by this much (relative) to be chosen
WHOLE_UNIT_MARGIN = 0.25
#: ... while its still-gyro residual is at most this much worse
WHOLE_UNIT_GYRO_SLACK = 0.05
#: holds off the six faces needed before the whole-unit model is tried (misalignment)
WHOLE_UNIT_MIN_TILTED = 3
#: hold folds needed (every face held this often): with two folds a fit sees one hold
#: per face and the held-out score is dominated by extrapolation (simulated demo: field
#: 16 mg vs whole_unit 1.1 mg held out, but on the next cold start 117 vs 453 ug)
WHOLE_UNIT_MIN_FOLDS = 3
#: a candidate whose held-out residual is more than this many times the best one's is
#: never kept, whatever the margins above
KEEP_RATIO = 1.5
#: Estimate carries a temperature filter into the Calibration (calibrate.py support)
FILTER_SUPPORTED = 'temperature_filter' in {f.name for f in dataclasses.fields(Estimate)}


@dataclass
class Selection:
    """The outcome of the automatic choice, kept on the Context for the estimators."""

    model: str
    reason: str
    tau_s: Optional[np.ndarray] = None
    table: Dict[str, dict] = field(default_factory=dict)
    lag: Optional[dict] = None
    groups: str = ''
    kernels: Dict[str, list] = field(default_factory=dict)
    seconds: float = 0.0

    def report(self):
        """Return a plain dict for the calibration file's fit section."""
        return {'model': self.model, 'reason': self.reason, 'cv_groups': self.groups,
                'heldout': self.table, 'lag': self.lag, 'seconds': round(self.seconds, 2)}


def _weighted_mean(x, n):
    return np.average(x, axis=0, weights=n)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float('nan')


def calibration_from(ctx, est):
    """Return the Calibration an Estimate makes (models, filter, inputs, range, noise)."""
    o, w = ctx.options, ctx.windows
    return Calibration(
        accel=est.accel, gyro=est.gyro, inputs=list(o.inputs), valid_range=valid_range(w, o),
        out_of_range=o.out_of_range, accel_input=ctx.accel_input, gyro_input=ctx.gyro_input,
        frame_id=o.frame_id, gravity=o.gravity, gravity_source=o.gravity_source,
        accel_noise_std=np.sqrt(np.median(w.accel_var, axis=0)),
        gyro_noise_std=np.sqrt(np.median(w.gyro_var, axis=0)), notes=list(est.notes),
        fit=dict(est.fit), temperature_filter=getattr(est, 'temperature_filter', None))


# ---------------------------------------------------------------------- single orientation
def fit_single(ctx, family, tau, windows=None, groups=None, kernels=None, rvm_settings=None,
               signals=('accel', 'gyro')):
    """Fit accel and gyro offset models of ``family`` ('poly'/'rvm') on lagged inputs.

    Returns (accel model, gyro model, report); a sensor not in ``signals`` gets None.
    ``windows`` defaults to the context's; ``groups`` are its CV groups (legs, holds,
    time blocks).
    """
    w = ctx.windows if windows is None else windows
    if groups is None:
        groups, _ = cv_groups(w)
    kernels = kernels or {}
    out, rep = {}, {}
    for sig, idx in (('accel', ctx.accel_input), ('gyro', ctx.gyro_input)):
        if sig not in signals:
            out[sig], rep[sig] = None, None
            continue
        temps = lagged_axis_temperatures(w, tau, idx)
        single_accel = sig == 'accel'    # one pose: the constant is gravity, not bias
        ref = ctx.t0 if single_accel else ctx.gyro_t0
        if family == 'poly':
            out[sig], rep[sig] = fit_offset_model(w, temps, ref, sig, sig,
                                                  include_constant=not single_accel,
                                                  groups=groups)
        else:
            out[sig], rep[sig] = fit_rvm_offset(w, temps, sig, sig, groups,
                                                offset_only=single_accel, t_ref=ref,
                                                settings=rvm_settings,
                                                kernels=kernels.get(sig))
    return out['accel'], out['gyro'], rep


def clamp_to_training(temps, windows, train, axis_input, margin):
    """Clamp model inputs to the training readings' range +- margin (each input's unit).

    What ``Calibration.apply`` does with the default ``clamp`` policy and the valid range
    of a calibration made from the training windows. ``margin``: scalar or (k,) per input.
    """
    if windows.n_inputs == 0:
        return temps
    margin = np.broadcast_to(np.asarray(margin, float), (windows.n_inputs,))[axis_input]
    lo = windows.temp[train].min(0)[axis_input] - margin
    hi = windows.temp[train].max(0)[axis_input] + margin
    return np.clip(temps, lo, hi)


def heldout_single(ctx, family, tau, groups, kernels=None, rvm_settings=None,
                   signals=('accel', 'gyro')):
    """Return the per-axis held-out drift RMS {'accel': (3,), 'gyro': (3,)} of a candidate.

    Each group is left out in turn; the drift of a held-out window is its corrected
    output minus the n-weighted mean corrected output of the training windows. Inputs
    are clamped to the training range as a calibration from the training part would.
    """
    w = ctx.windows
    ta = lagged_axis_temperatures(w, tau, ctx.accel_input)
    tg = lagged_axis_temperatures(w, tau, ctx.gyro_input)
    margin = input_margins(w, ctx.options) if ctx.k else ctx.options.range_margin
    sse = {s: np.zeros(3) for s in signals}
    for g in np.unique(groups):
        test = groups == g
        train = ~test
        wt = w.select(train)
        if family == 'raw':
            models = {'accel': None, 'gyro': None}
        else:
            acc, gyr, _ = fit_single(ctx, family, tau, wt, groups[train], kernels,
                                     rvm_settings, signals)
            models = {'accel': acc, 'gyro': gyr}
        for sig, temps, idx in (('accel', ta, ctx.accel_input), ('gyro', tg, ctx.gyro_input)):
            if sig not in signals:
                continue
            y = getattr(w, sig)
            m = models[sig]
            c = y if m is None else m.correct(y, clamp_to_training(temps, w, train, idx,
                                                                   margin))
            ref = _weighted_mean(c[train], w.n[train])
            sse[sig] += np.sum((c[test] - ref) ** 2, axis=0)
    return {k: np.sqrt(v / len(w)) for k, v in sse.items()}


def select_single(ctx, rvm_settings=None, candidates=SINGLE_CANDIDATES,
                  signals=('accel', 'gyro')):
    """Compare the single-orientation candidates; returns a ``Selection``.

    ``signals`` limits the score to the accelerometer or the gyroscope (e.g. a gyro-only
    comparison across soaks in different orientations).
    """
    t_start = time.perf_counter()
    w = ctx.windows
    groups, kind = cv_groups(w)
    if len(np.unique(groups)) < 2:
        return Selection('offset', 'too few windows for held-out validation: offset '
                         'polynomial', groups=kind)
    lag = estimate_tau(w, ctx.accel_input, ctx.gyro_input, groups, group_kind=kind,
                       signals=signals, lagged=_lagged_inputs(ctx))
    tau = tau_or_none(lag, LAG_MIN_IMPROVEMENT)
    lag_note = (f'lag search: tau {np.max(lag.tau_s):.0f} s cuts the held-out error of a '
                f'quadratic by {100 * lag.improvement:.0f} % (used above '
                f'{100 * LAG_MIN_IMPROVEMENT:.0f} %)')
    if tau is not None and not _filter_ok(ctx):
        lag_note += ' (not used: this calibrate.py cannot store a temperature filter)'
        tau = None
    kernels = {}
    if 'rvm' in candidates or 'rvm-lag' in candidates:
        # the RVM (the costly candidate) only with the filter the lag search chose
        for name, tt in (('rvm', None), ('rvm-lag', tau)):
            if name not in candidates or (name == 'rvm-lag') != (tau is not None):
                continue
            acc, gyr, _ = fit_single(ctx, 'rvm', tt, groups=groups, rvm_settings=rvm_settings,
                                     signals=signals)
            kernels[name] = {s: m.kernel_list for s, m in (('accel', acc), ('gyro', gyr))
                             if m is not None}
    raw = heldout_single(ctx, 'raw', None, groups, signals=signals)
    table = {'raw': {s: _rms(v) for s, v in raw.items()}}
    spec = {'offset': ('poly', None), 'lag': ('poly', tau), 'rvm': ('rvm', None),
            'rvm-lag': ('rvm', tau)}
    scores = {}
    for name in candidates:
        family, tt = spec[name]
        if (name.endswith('lag') and tt is None) or (family == 'rvm' and name not in kernels):
            continue
        err = heldout_single(ctx, family, tt, groups, kernels.get(name), rvm_settings, signals)
        table[name] = {s: _rms(v) for s, v in err.items()}
        ratios = [table[name][s] / table['raw'][s] for s in signals if table['raw'][s] > 0]
        scores[name] = float(np.mean(ratios))
        table[name]['score'] = scores[name]
    # the filter comes from the lag search (same polynomial order with and without the
    # lag, so the comparison is not confounded by the order); the family by held-out error
    pool = [n for n in candidates if n in scores and n.endswith('lag') == (tau is not None)]
    best = min(scores[n] for n in pool)
    chosen = next(n for n in pool if scores[n] <= best * (1 + SINGLE_MARGIN))
    units = {'accel': 'm/s^2', 'gyro': 'rad/s'}
    parts = ', '.join(n + ' ' + ' / '.join(f'{table[n][s]:.3g} {units[s]}' for s in signals)
                      for n in ['raw'] + list(scores))
    reason = (f'one orientation; held-out drift (leave one of {len(np.unique(groups))} '
              f'{kind} out, {" / ".join(signals)} RMS): {parts}; {lag_note}; chose {chosen} '
              f'(score {scores[chosen]:.3f} of raw)')
    return Selection(chosen, reason, tau if chosen.endswith('lag') else None, table,
                     lag.report(), kind, kernels, time.perf_counter() - t_start)


def select_single_history(ctx):
    """Return the Selection of the one-orientation history path (``time_folds``).

    The model is 'hysteresis' (``history_select``), which refits the chosen specs.
    """
    res = select_history(ctx)
    sel = Selection('hysteresis', res['reason'], None, res['table'], None, res['kind'],
                    seconds=res['seconds'])
    sel.history = res
    return sel


# ---------------------------------------------------------------------- several orientations
def _hold_folds(windows, n_folds=MULTI_FOLDS):
    """Return (fold per window, number of folds): the k-th hold of each face goes to fold k.

    A fold then leaves out at most one hold per face, so every axis keeps an up and a down
    pose in training (needed to separate bias from scale factor). When a face was held only
    once that is impossible: fewer than 2 folds are returned (no comparison is made; the
    folds are then a plain round robin of the holds, for the RVM's own kernel search).
    """
    ids, means = windows.hold_means()
    faces = [face_of(m) for m in means]
    names = sorted(set(faces))
    counts = [faces.count(f) for f in names if f != 'tilted']
    n = min([n_folds] + counts) if counts else 0
    seen, fold_of = {}, {}
    for i, (h, f) in enumerate(zip(ids, faces)):
        k = seen.get(f, 0)
        seen[f] = k + 1
        # shifted per face, so a fold mixes repetitions (temperatures) instead of being one
        # time block of a warm-up; else a plain round robin
        fold_of[int(h)] = (k + names.index(f)) % n if n >= 2 else i % n_folds
    return np.array([fold_of[int(h)] for h in windows.hold]), n


def _field_fit(ctx, windows, ta, refine=None):
    o = ctx.options
    pm = ctx.prior_model
    k0 = b0 = s = None
    if pm is not None:
        k0, b0, s = pm.k0 + pm.thermal[:, 0], pm.b0 + pm.thermal[:, 3], pm.s
    return fit_field_model(windows, ta, o.gravity, ctx.t0, k0, b0, s, order=o.order,
                           refine=o.refine if refine is None else refine)


def _up_per_window(windows, fit):
    up = np.zeros((len(windows), 3))
    for h, u in zip(fit.hold_ids, fit.tilts):
        up[windows.hold == h] = u
    return up


def _prior(ctx):
    pm = ctx.prior_model
    if pm is None:
        return np.ones(3), np.zeros(3), np.eye(3)
    return pm.k0, pm.b0, pm.s


def fit_rvm_multi(ctx, windows=None, tau=None, kernels=None, rvm_settings=None, up=None):
    """Fit the bias/scale RVM on the field model's hold tilts; returns (model, report).

    ``up`` (per window) skips the field fit that provides the tilts.
    """
    w = ctx.windows if windows is None else windows
    ta = lagged_axis_temperatures(w, tau, ctx.accel_input)
    if up is None:
        up = _up_per_window(w, _field_fit(ctx, w, ta))
    k0, b0, s = _prior(ctx)
    return fit_rvm_bias_scale(w, ta, up, _hold_folds(w)[0], ctx.options.gravity, k0, b0, s,
                              rvm_settings, kernels)


def _field_design(dt, sf, order):
    """Return the per-axis regressors of the field model's thermal terms (seed 000 eq. 8)."""
    powers = np.stack([dt ** j for j in range(order + 1)], 1)
    return np.concatenate([powers * sf[:, None], powers], 1)


def heldout_multi(ctx, up, tau, kernels=None, rvm_settings=None):
    """Return held-out raw-output residuals {'field': (m, 3), 'rvm': ...} at known tilts.

    The tilts of the holds (``up`` per window, from one field fit on all holds) are kept;
    the thermal part is refitted on the training holds: the field model's polynomial by
    linear least squares, the RVM with fixed kernels. The residual is the raw output minus
    the output each model predicts for the held-out hold's specific force.
    """
    w = ctx.windows
    g = ctx.options.gravity
    ta = lagged_axis_temperatures(w, tau, ctx.accel_input)
    k0, b0, s = _prior(ctx)
    sf = g * up @ s.T
    y = w.accel - b0 - k0 * sf
    span = float(np.max(np.ptp(ta, axis=0))) if ctx.k else 0.0
    order = max(o for o in range(ctx.options.order + 1) if o == 0 or span >= ORDER_SPAN[o])
    folds, _ = _hold_folds(w)
    out = {'field': np.zeros_like(y), 'rvm': np.zeros_like(y) if kernels else None}
    for f in np.unique(folds):
        test = folds == f
        train = ~test
        # evaluated as a calibration from the training holds would be: clamped to its range
        tc = clamp_to_training(ta, w, train, ctx.accel_input,
                               input_margins(w, ctx.options) if ctx.k else 0.0)
        for a in range(3):
            v = _field_design(ta[:, a] - ctx.t0[a], sf[:, a], order)
            vt = _field_design(tc[:, a] - ctx.t0[a], sf[:, a], order)
            coef, *_ = np.linalg.lstsq(v[train], y[train, a], rcond=None)
            out['field'][test, a] = y[test, a] - vt[test] @ coef
        if kernels:
            model, _ = fit_rvm_multi(ctx, w.select(train), tau, kernels, rvm_settings,
                                     up[train])
            out['rvm'][test] = w.accel[test] - model.forward(g * up[test], tc[test])
    return out


def select_multi(ctx, rvm_settings=None):
    """Compare field, lagged field and bias/scale RVM by held-out holds; ``Selection``."""
    t_start = time.perf_counter()
    g = ctx.options.gravity
    w = ctx.windows
    if ctx.k == 0:
        return Selection('field', f'{ctx.n_orientations} orientations, no temperature input: '
                         'seed 000 field model (temperature-independent terms)', groups='holds')
    _, n_folds = _hold_folds(w)
    if n_folds < 2:
        return Selection('field', f'{ctx.n_orientations} orientations; a face was held only '
                         'once, so no held-out split keeps every axis up and down in '
                         'training: seed 000 field model', groups='holds')
    # tilts from the two-step iteration (the joint refinement changes them by far less than
    # the thermal models differ, and costs most of the time)
    up = _up_per_window(w, _field_fit(ctx, w, ctx.ta, refine=False))
    lag, tau, kernels = None, None, {}
    lag_note = 'no temperature input'
    if ctx.k:
        lag = estimate_tau(w, ctx.accel_input, ctx.gyro_input, signals=('gyro',),
                           groups=w.hold, group_kind='holds', lagged=_lagged_inputs(ctx))
        tau = tau_or_none(lag, MULTI_LAG_IMPROVEMENT) if _filter_ok(ctx) else None
        lag_note = (f'gyro-bias lag search: tau {np.max(lag.tau_s):.0f} s, '
                    f'{100 * lag.improvement:.0f} % better held out')
        model, _ = fit_rvm_multi(ctx, rvm_settings=rvm_settings, up=up)
        kernels['rvm'] = model.kernel_list
    res = heldout_multi(ctx, up, None, kernels.get('rvm'), rvm_settings)
    scores = {'field': _rms(res['field'])}
    if res['rvm'] is not None:
        scores['rvm'] = _rms(res['rvm'])
    if tau is not None:
        scores['field-lag'] = _rms(heldout_multi(ctx, up, tau)['field'])
    table = {n: {'residual_ug': v / g * 1e6} for n, v in scores.items()}
    chosen = 'field'
    if 'field-lag' in scores and scores['field-lag'] < scores['field'] * (1 - MULTI_MARGIN):
        chosen = 'field-lag'
    if 'rvm' in scores and scores['rvm'] < scores[chosen] * (1 - MULTI_RVM_MARGIN):
        chosen = 'rvm'
    parts = ', '.join(f'{n} {v / g * 1e6:.1f} ug' for n, v in scores.items())
    reason = (f'{ctx.n_orientations} orientations; held-out raw-output residual RMS at the '
              f'holds\' tilts ({n_folds} folds, at most one hold per face out): {parts}; '
              f'{lag_note}; chose {chosen}')
    return Selection(chosen, reason, tau if chosen == 'field-lag' else None, table,
                     None if lag is None else lag.report(), 'holds', kernels,
                     time.perf_counter() - t_start)


def _weighted_rms(x, n):
    return float(np.sqrt(np.sum(n * x * x) / np.sum(n)))


def _whole_unit_folds(windows):
    """Return (fold per window, number of folds) for the whole-unit check.

    ``_hold_folds`` when every face was held at least twice; else (a face held once)
    each hold that can leave without taking a face's last hold away (a repeated face, or a
    tilted pose) is a fold of its own (at most ``MULTI_FOLDS``, round robin), and the other
    holds (fold -1) always train. A short hand-held session (six faces once, a few repeats
    and tilts) is then still compared held out.
    """
    folds, n = _hold_folds(windows)
    if n >= 2:
        # every face twice or more: the face folds (fewer than WHOLE_UNIT_MIN_FOLDS of them
        # skip the check, see there)
        return folds, n
    ids, means = windows.hold_means()
    faces = [face_of(m) for m in means]
    seen, fold_of, k = {}, {}, 0
    for h, f in zip(ids, faces):
        seen[f] = seen.get(f, 0) + 1
        if f == 'tilted' or seen[f] > 1:
            fold_of[int(h)] = k % MULTI_FOLDS
            k += 1
        else:
            fold_of[int(h)] = -1
    return np.array([fold_of[int(h)] for h in windows.hold]), min(k, MULTI_FOLDS)


def fold_masks(folds, n):
    """Yield (test, train) bool masks of folds 0..n-1 of ``folds`` (empty ones skipped)."""
    for f in range(n):
        test = folds == f
        if test.any():
            yield test, ~test


def heldout_whole_unit(ctx):
    """Held-out static residuals of the field and whole-unit calibrations; (dict, folds).

    Both are refitted on the training holds of each fold (``_hold_folds``) and applied to
    the held-out windows, inputs clamped to the training range. Returns per window
    ``{'accel': {'field': |a| - g, 'whole_unit': ...}, 'gyro': {...: |w_corrected|}}``:
    the gyro of a still IMU should read the earth rate (<= 7.3e-5 rad/s) in every pose,
    so a pose-dependent bias (g-sensitivity) shows as a larger held-out |w|. The field
    calibration's gyro is the default bias polynomial (``calibrate._gyro_bias``).
    """
    from ..estimation.calibrate import _gyro_bias
    from ..estimation.whole_unit_fit import fit_whole_unit_context
    w, o = ctx.windows, ctx.options
    folds, n = _whole_unit_folds(w)
    out = {s: {'field': np.full(len(w), np.nan), 'whole_unit': np.full(len(w), np.nan)}
           for s in ('accel', 'gyro')}
    for test, train in fold_masks(folds, n):
        ta = clamp_to_training(ctx.ta, w, train, ctx.accel_input, o.range_margin)
        tg = clamp_to_training(ctx.tg, w, train, ctx.gyro_input, o.range_margin)
        sub = ctx.subset(train)
        fm = _field_fit(ctx, sub.windows, sub.ta, refine=False).model
        gm, _ = _gyro_bias(sub)
        wu = fit_whole_unit_context(ctx, train)
        for name, am, gmod in (('field', fm, gm),
                               ('whole_unit', wu.accel.model, wu.gyro.model)):
            a = am.correct(w.accel[test], ta[test])
            out['accel'][name][test] = np.linalg.norm(a, axis=1) - o.gravity
            g = gmod.correct(w.gyro[test], tg[test], aux={'accel': a})
            out['gyro'][name][test] = np.linalg.norm(g, axis=1)
    return out, n


def select_whole_unit(ctx, sel):
    """Return ``sel`` or a whole-unit Selection when it wins held out (see the docstring).

    Whatever the margins, a candidate whose held-out |a| - g is more than ``KEEP_RATIO``
    times the other's is never kept. Without a temperature input the margin is 0.
    """
    if sel.model != 'field' or sel.groups != 'holds':
        return sel
    ids, means = ctx.windows.hold_means()
    tilted = sum(face_of(m) == 'tilted' for m in means)
    if ctx.k and tilted < WHOLE_UNIT_MIN_TILTED:
        return sel          # misalignment unobservable: whole_unit is not a candidate
    folds, n_folds = _whole_unit_folds(ctx.windows)
    if n_folds < 2 or (folds.min() >= 0 and n_folds < WHOLE_UNIT_MIN_FOLDS):
        sel.reason += (f'; whole-unit check skipped: {n_folds} hold folds (the held-out score '
                       'would be dominated by extrapolation)')
        return sel
    t_start = time.perf_counter()
    res, n_folds = heldout_whole_unit(ctx)
    g = ctx.options.gravity
    held = np.isfinite(res['accel']['field'])
    n = ctx.windows.n[held]
    acc = {k: _weighted_rms(v[held], n) / g * 1e6 for k, v in res['accel'].items()}
    gyr = {k: _weighted_rms(v[held], n) for k, v in res['gyro'].items()}
    for k in acc:
        sel.table[f'{k} |a|-g'] = {'residual_ug': acc[k]}
        sel.table[f'{k} |w| still'] = {'residual_rad_s': gyr[k]}
    sel.seconds += time.perf_counter() - t_start
    kept = [k for k in acc if acc[k] <= KEEP_RATIO * min(acc.values())]
    # no temperature input: both models are constant, whole_unit only adds the
    # misalignment the tilted holds observe, so it needs no margin
    margin = WHOLE_UNIT_MARGIN if ctx.k else 0.0
    if len(kept) == 1:
        wins = kept[0] == 'whole_unit'
        why = (f'{"field" if wins else "whole_unit"} is more than {KEEP_RATIO:g}x worse held '
               'out on |a|-g')
    else:
        wins = (tilted >= WHOLE_UNIT_MIN_TILTED
                and acc['whole_unit'] < (1 - margin) * acc['field']
                and gyr['whole_unit'] <= (1 + WHOLE_UNIT_GYRO_SLACK) * gyr['field'])
        better = (f'{100 * margin:.0f} % better' if margin else
                  'better (no margin: without a temperature input both are constant)')
        why = (f'whole_unit {better} on |a|-g with the gyro no worse and >= '
               f'{WHOLE_UNIT_MIN_TILTED} tilted holds' if wins else
               f'whole_unit not {better} on |a|-g with the gyro no worse, or fewer than '
               f'{WHOLE_UNIT_MIN_TILTED} tilted holds')
    text = (f'; candidates compared held out: field, whole_unit ({tilted} of {len(ids)} '
            f'holds off the six faces, {n_folds} folds): |a|-g RMS field {acc["field"]:.1f} '
            f'ug, whole_unit {acc["whole_unit"]:.1f} ug; still-gyro |w| RMS field '
            f'{gyr["field"]:.2e}, whole_unit {gyr["whole_unit"]:.2e} rad/s; {why}: ')
    if wins:
        sel.model = 'whole_unit'
        sel.reason += text + 'chose whole_unit (seed 002)'
    else:
        sel.reason += text + 'field'
    return sel


# ---------------------------------------------------------------------- policy, estimators
def auto_policy(ctx):
    """Choose the model for ``--model auto`` by held-out validation; returns (name, reason)."""
    if ctx.n_orientations == 1:
        if ctx.k == 0:
            return 'offset', 'one orientation and no temperature input'
        span = _degc_span(ctx)
        if span is not None and span < SINGLE_MIN_SPAN:
            return 'offset', (
                f'one orientation: only an offset per axis vs temperature is observable; the '
                f'temperature spans {span:.2f} degC (< {SINGLE_MIN_SPAN:g}), too little to tell '
                'a temperature dependence from a drift in time, so no richer shape (lag, rvm) '
                'is compared: offset polynomial, order by cross-validation')
        sel = select_single_history(ctx) if turns_both_ways(ctx) else select_single(ctx)
    else:
        try:
            check_faces_up_and_down(ctx)
        except CalibrationRefused:
            return 'field', (f'{ctx.n_orientations} orientations but faces missing: the '
                             'field estimator explains what to collect')
        sel = select_whole_unit(ctx, select_multi(ctx))
    ctx.thermal_selection = sel
    return sel.model, sel.reason


def _degc_span(ctx):
    """Return the largest span (degC) of the degC inputs over the windows (None: none)."""
    degc = [i for i, t in enumerate(_lagged_inputs(ctx)) if t]
    if not degc or len(ctx.windows) == 0:
        return None
    return float(np.max(np.ptp(ctx.windows.temp[:, degc], axis=0)))


def _lagged_inputs(ctx):
    """Return the inputs a thermal lag applies to: the degC ones (a proxy has none)."""
    return [is_temperature(u) for u in input_units(ctx.options, ctx.k)]


def _selection(ctx, name):
    sel = getattr(ctx, 'thermal_selection', None)
    return sel if sel is not None and sel.model == name else None


def _filter_ok(ctx):
    return FILTER_SUPPORTED or getattr(ctx, 'filter_ok', False)


def _require_filter(ctx, name):
    if not _filter_ok(ctx):
        raise CalibrationRefused(f'the {name} model needs a temperature filter in the '
                                 'calibration, which this calibrate.py cannot store',
                                 'use --model offset, rvm or field')


def _lag_for(ctx, name, sel):
    if sel is not None and sel.tau_s is not None:
        return sel.tau_s, sel.lag
    if ctx.k == 0:
        raise CalibrationRefused(f'the {name} model needs a temperature input',
                                 'record the IMU temperature topic')
    if ctx.n_orientations == 1:
        est = estimate_tau(ctx.windows, ctx.accel_input, ctx.gyro_input,
                           lagged=_lagged_inputs(ctx))
    else:
        est = estimate_tau(ctx.windows, ctx.accel_input, ctx.gyro_input, signals=('gyro',),
                           groups=ctx.windows.hold, group_kind='holds',
                           lagged=_lagged_inputs(ctx))
    return est.tau_s, est.report()


def _estimate(ctx, name, family, lagged):
    if ctx.k == 0:
        raise CalibrationRefused(f'the {name} model needs a temperature input',
                                 'record the IMU temperature topic')
    sel = _selection(ctx, name)
    tau, lag_rep = None, None
    if lagged:
        _require_filter(ctx, name)
        tau, lag_rep = _lag_for(ctx, name, sel)
    notes = []
    fit_stats = {}
    report = {}
    if ctx.n_orientations == 1:
        kernels = sel.kernels.get(name) if sel is not None else None
        acc, gyr, rep = fit_single(ctx, family, tau, kernels=kernels)
        report.update({'accel_offset': rep['accel'], 'gyro_offset': rep['gyro']})
        fit_stats['pose'] = 'single orientation (offset-only)'
        notes.append('one orientation: the accelerometer model removes the drift relative '
                     'to its output at the reference temperature; valid for this mounting '
                     'pose only')
    else:
        check_faces_up_and_down(ctx)
        if family == 'field':
            lag_ctx = dataclasses.replace(
                ctx, ta=lagged_axis_temperatures(ctx.windows, tau, ctx.accel_input),
                tg=lagged_axis_temperatures(ctx.windows, tau, ctx.gyro_input))
            est = estimate_field(lag_ctx)
            acc, notes, fit_stats = est.accel, list(est.notes), dict(est.fit)
        else:
            kernels = sel.kernels.get(name) if sel is not None else None
            acc, rep = fit_rvm_multi(ctx, tau=tau, kernels=kernels)
            report['accel_rvm'] = rep
            fit_stats['pose'] = 'several orientations (bias and scale by pose, seed 003)'
        tg = lagged_axis_temperatures(ctx.windows, tau, ctx.gyro_input)
        groups, _ = cv_groups(ctx.windows)
        if family == 'rvm':
            gyr, report['gyro_offset'] = fit_rvm_offset(ctx.windows, tg, 'gyro', 'gyro',
                                                        groups, t_ref=ctx.gyro_t0)
        else:
            gyr, report['gyro_offset'] = fit_offset_model(ctx.windows, tg, ctx.gyro_t0, 'gyro',
                                                          'gyro', include_constant=True,
                                                          groups=groups)
        notes.append('gyroscope: bias vs temperature from stationary windows; earth rotation '
                     'is not removed (up to 7.3e-5 rad/s)')
    if sel is not None:
        fit_stats['selection'] = sel.report()
    if lagged:
        fit_stats['thermal_lag'] = lag_rep
        notes.append(f'the models take the temperature through a first-order lag of '
                     f'{float(np.max(tau)):.0f} s (temperature.filter): stream data through '
                     'Calibration.stream()')
    est = Estimate(accel=acc, gyro=gyr, notes=notes, fit=fit_stats, report=report)
    # carried as a field once calibrate.Estimate has one, else as an attribute that
    # calibrate_thermal (below) reads
    est.temperature_filter = ThermalFilter(tau) if lagged else None
    return est


@register_estimator('lag')
def estimate_lag(ctx):
    """Estimate polynomial (or field) models in a lagged temperature, tau from the data."""
    return _estimate(ctx, 'lag', 'poly' if ctx.n_orientations == 1 else 'field', True)


@register_estimator('field-lag')
def estimate_field_lag(ctx):
    """Estimate the seed 000 field model in a lagged temperature (several orientations)."""
    if ctx.n_orientations == 1:
        raise CalibrationRefused('the field model needs several orientations',
                                 'use --model lag for one orientation')
    return _estimate(ctx, 'field-lag', 'field', True)


@register_estimator('rvm')
def estimate_rvm(ctx):
    """Estimate RVM models (seed 003): offsets in one pose, bias and scale in several."""
    return _estimate(ctx, 'rvm', 'rvm', False)


@register_estimator('rvm-lag')
def estimate_rvm_lag(ctx):
    """Estimate RVM models in a lagged temperature, tau from the data."""
    return _estimate(ctx, 'rvm-lag', 'rvm', True)


def calibrate_thermal(windows, options=None):
    """Run the ``--model`` choice and estimator on windows; returns (Calibration, Estimate).

    The same decisions as ``calibrate_windows`` (auto policy, registered estimators, gyro
    default) with the temperature filter honoured even where calibrate.py cannot store it
    yet; the Calibration has no fit statistics beyond the estimator's.
    """
    from ..estimation.calibrate import _gyro_bias, ESTIMATORS, model_choices
    o = options or CalibrateOptions()
    if o.model not in model_choices():
        raise CalibrationRefused(f'unknown model {o.model!r}', f'use one of {model_choices()}')
    ctx = make_context(windows, o)
    ctx.filter_ok = True
    name, why = (o.model, 'requested') if o.model != 'auto' else AUTO_POLICY[0](ctx)
    est = ESTIMATORS[name](ctx)
    if est.gyro is None:
        est.gyro, _ = _gyro_bias(ctx)
    est.fit.setdefault('model_choice', {'model': name, 'reason': why})
    sel = getattr(ctx, 'thermal_selection', None)
    if sel is not None:
        est.fit.setdefault('selection', sel.report())
    return calibration_from(ctx, est), est


AUTO_POLICY[0] = auto_policy
