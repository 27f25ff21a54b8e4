"""Offset-vs-temperature polynomial fits with the order chosen by held-out validation.

Used for the gyroscope bias (constant included) and for the single-orientation warm-up
(accelerometer drift relative to the reference temperature, constant not observable).
"""

import numpy as np

from ..models.polynomial import OffsetPolynomialModel
from .placement_levels import held_out_level_fits, random_level_fit


def _vander(dt, order):
    return np.stack([dt ** j for j in range(order + 1)], axis=1)


def _polyfit_coef(dt, y, w, order):
    """Coefficients of the weighted LS polynomial (what ``weighted_polyfit`` returns first)."""
    a = _vander(dt, order) * w[:, None]
    return np.linalg.lstsq(a, y * w, rcond=None)[0], a


def weighted_polyfit(dt, y, w, order, levels=None):
    """Return (coeffs (order+1,), std (order+1,)) of a weighted LS polynomial in dt.

    ``w``: 1 / std of each value; ``levels``: (m,) placement ids whose levels are random
    effects (``placement_levels.random_level_fit``), or None. The residual variance is in
    units of that std and never below 1 (the values' own noise).
    """
    if levels is not None:
        fit = random_level_fit(_vander(dt, order), y, w ** 2, levels)
        return fit.coef, fit.std(max(fit.sigma2, 1.0))
    coef, a = _polyfit_coef(dt, y, w, order)
    r = (y - _vander(dt, order) @ coef) * w
    dof = max(len(y) - order - 1, 1)
    s2 = max(float(r @ r) / dof, 1.0)
    try:
        cov = np.linalg.pinv(a.T @ a) * s2
        std = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        std = np.full(order + 1, np.nan)
    return coef, std


def _held_out_fits(dt, y, w, gi, ng, order):
    """Return (ng, order + 1) coefficients fitted without each group (``gi``: group index).

    Normal equations of the weighted Vandermonde design, column-scaled, batched over the
    groups (one solve per group); a training set whose scaled system is ill-conditioned
    (cond > 1e10) is solved by ``lstsq`` like the plain loop.
    """
    v = _vander(dt, order) * w[:, None]                          # (m, p)
    p = order + 1
    train = np.ones((ng, len(dt)))
    train[gi, np.arange(len(dt))] = 0.0
    nrm = (train @ (v[:, :, None] * v[:, None, :]).reshape(len(dt), p * p)).reshape(ng, p, p)
    rhs = train @ (v * (y * w)[:, None])                          # (ng, p)
    sc = np.sqrt(np.maximum(np.einsum('gii->gi', nrm), 1e-300))
    scaled = nrm / (sc[:, :, None] * sc[:, None, :])
    coef = np.empty((ng, p))
    ok = np.linalg.cond(scaled) < 1e10
    if np.any(ok):
        coef[ok] = np.linalg.solve(scaled[ok], (rhs[ok] / sc[ok])[..., None])[..., 0] / sc[ok]
    for g in np.flatnonzero(~ok):
        sel = gi != g
        coef[g] = _polyfit_coef(dt[sel], y[sel], w[sel], order)[0]
    return coef


def _others_extreme(values, fn):
    """Return per group the extreme (``fn``: np.max or np.min) over the other groups."""
    out = np.empty(len(values))
    for g in range(len(values)):
        rest = np.delete(values, g)
        out[g] = fn(rest) if len(rest) else np.nan
    return out


def cv_order(dt, y, w, groups, orders, levels=None):
    """Pick the order with the lowest held-out weighted squared error (leave one group out).

    Returns (order, {order: cv_rms}). Groups are e.g. holds or contiguous time blocks.
    An order scores inf when a training set has too few points or no temperature span.
    All groups of an order are fitted at once (``_held_out_fits``); with ``levels``
    ((m,) placement ids) each training part is fitted with a random level per placement
    (``placement_levels.held_out_level_fits``).
    """
    scores = {}
    dt, y, w = (np.asarray(a, float) for a in (dt, y, w))
    ug, gi = np.unique(groups, return_inverse=True)
    gi = gi.ravel()
    ng = len(ug)
    count = np.bincount(gi, minlength=ng)
    lo = np.full(ng, np.inf)
    hi = np.full(ng, -np.inf)
    np.minimum.at(lo, gi, dt)
    np.maximum.at(hi, gi, dt)
    n_train = len(dt) - count
    span = _others_extreme(hi, np.max) - _others_extreme(lo, np.min)
    for order in orders:
        if ng == 0 or np.any(n_train <= order + 1) or not np.all(span > 0):
            scores[order] = np.inf
            continue
        coef = (_held_out_fits(dt, y, w, gi, ng, order) if levels is None else
                held_out_level_fits(_vander(dt, order), y, w ** 2, gi, np.asarray(levels)))
        r = (y - np.einsum('ip,ip->i', _vander(dt, order), coef[gi])) * w
        wsum = float(np.sum(w ** 2))
        scores[order] = float(np.sqrt(float(np.sum(r * r)) / wsum)) if wsum else np.inf
    finite = {k: v for k, v in scores.items() if np.isfinite(v)}
    if not finite:
        return min(orders), scores
    best = min(finite.values())
    # the lowest order within 2 % of the best held-out error (parsimony)
    order = min(k for k, v in finite.items() if v <= best * 1.02)
    return order, scores


def time_groups(t, n_groups=6):
    """Split windows into contiguous time blocks for cross-validation."""
    t = np.asarray(t, float)
    if len(t) == 0:
        return np.zeros(0, int)
    edges = np.quantile(t, np.linspace(0, 1, n_groups + 1)[1:-1])
    return np.searchsorted(edges, t, side='right')


def fit_offset_model(windows, axis_temps, t0, signal, sensor, include_constant,
                     orders=(0, 1, 2, 3), groups=None, levels=False):
    """Fit an OffsetPolynomialModel per axis with a CV-chosen order.

    windows: Windows; axis_temps: (m, 3) degC; signal: 'accel' or 'gyro' field of windows.
    Without a constant (single-orientation accel) the constant is still fitted (it holds the
    unobservable gravity projection) but not stored. ``levels``: each hold of ``windows``
    is a placement whose level is a random effect (``CalibrateOptions.placement_levels``).
    Returns (model, report dict).
    """
    y_all = getattr(windows, signal)
    var = getattr(windows, f'{signal}_var')
    w_all = 1.0 / np.sqrt(np.maximum(var, 1e-30) / windows.n[:, None])
    if groups is None:
        groups = time_groups(windows.t0)
    t0 = np.asarray(t0, float)
    lv = np.asarray(windows.hold) if levels else None
    chosen, cv = [], []
    for i in range(3):
        dt = axis_temps[:, i] - t0[i]
        span = float(np.ptp(dt)) if len(dt) else 0.0
        allowed = [o for o in orders if o == 0 or span > 0.5 * o]
        o, sc = cv_order(dt, y_all[:, i], w_all[:, i], groups, allowed, lv)
        chosen.append(o)
        cv.append(sc)
    order = max(chosen)
    coeffs = np.zeros((order + 1, 3))
    std = np.zeros((order + 1, 3))
    for i in range(3):
        dt = axis_temps[:, i] - t0[i]
        c, s = weighted_polyfit(dt, y_all[:, i], w_all[:, i], chosen[i], lv)
        coeffs[:chosen[i] + 1, i] = c
        std[:chosen[i] + 1, i] = s
    model = OffsetPolynomialModel(t0, coeffs, sensor=sensor, include_constant=include_constant,
                                  coeff_std=std)
    if not include_constant:
        model.coeff_std[0] = 0.0
    report = {'order_per_axis': chosen, 'cv_rms_per_order': [
        {str(k): v for k, v in sc.items()} for sc in cv]}
    return model, report
