"""``--model auto`` on several orientations: field, lagged field and RVM compared held out.

Several orientations: the seed 000 field model is fitted once for the hold tilts; with
those tilts fixed, its thermal polynomial (by linear least squares), the same in a lagged
temperature (when the gyro-bias lag search finds one) and the bias/scale RVM are refitted
with holds left out (at most one per face) and scored by the held-out raw-output residual.
The field model stays unless the lagged one is 10 % and the RVM 50 % better.
"""

import time

import numpy as np

from ..estimation.calibrate import input_margins, ORDER_SPAN
from ..estimation.field_estimator import fit_field_model
from ..estimation.rvm_fit import fit_rvm_bias_scale
from ..estimation.thermal_lag import estimate_tau, lagged_axis_temperatures, tau_or_none
from .heldout import (_filter_ok, _hold_folds, _lagged_inputs, _rms, clamp_to_training,
                      Selection)

MULTI_CANDIDATES = ('field', 'field-lag', 'rvm')
#: several orientations: the lagged field model must beat the field model by this much
MULTI_MARGIN = 0.10
#: ... and the RVM the better of them by this much (a richer model that only matches the
#: parametric one is not worth it)
MULTI_RVM_MARGIN = 0.5
#: the gyro-bias lag search must improve by this much before a lag is tried
MULTI_LAG_IMPROVEMENT = 0.20


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


def resolved_order(ctx, ta):
    """Return the highest polynomial order (<= the option) the inputs' span resolves.

    ``ta`` (m, 3) per-axis model inputs; the span needed per order is ``ORDER_SPAN``.
    """
    span = float(np.max(np.ptp(ta, axis=0))) if ctx.k else 0.0
    return max(o for o in range(ctx.options.order + 1) if o == 0 or span >= ORDER_SPAN[o])


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
    order = resolved_order(ctx, ta)
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
                           groups=w.hold, group_kind='holds', lagged=_lagged_inputs(ctx),
                           levels=ctx.options.level_sensors())
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
