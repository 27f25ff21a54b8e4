"""Offset-vs-temperature polynomial fits with the order chosen by held-out validation.

Used for the gyroscope bias (constant included) and for the single-orientation warm-up
(accelerometer drift relative to the reference temperature, constant not observable).
"""

import numpy as np

from ..models.polynomial import OffsetPolynomialModel


def _vander(dt, order):
    return np.stack([dt ** j for j in range(order + 1)], axis=1)


def _polyfit_coef(dt, y, w, order):
    """Coefficients of the weighted LS polynomial (what ``weighted_polyfit`` returns first)."""
    a = _vander(dt, order) * w[:, None]
    return np.linalg.lstsq(a, y * w, rcond=None)[0], a


def weighted_polyfit(dt, y, w, order):
    """Return (coeffs (order+1,), std (order+1,)) of a weighted LS polynomial in dt."""
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


def cv_order(dt, y, w, groups, orders):
    """Pick the order with the lowest held-out weighted squared error (leave one group out).

    Returns (order, {order: cv_rms}). Groups are e.g. holds or contiguous time blocks.
    """
    scores = {}
    ug = np.unique(groups)
    for order in orders:
        err, wsum = 0.0, 0.0
        for g in ug:
            test = groups == g
            train = ~test
            if np.sum(train) <= order + 1 or np.ptp(dt[train]) <= 0:
                err = np.inf
                break
            coef, _ = _polyfit_coef(dt[train], y[train], w[train], order)  # no std needed
            r = y[test] - _vander(dt[test], order) @ coef
            err += float(np.sum((r * w[test]) ** 2))
            wsum += float(np.sum(w[test] ** 2))
        scores[order] = float(np.sqrt(err / wsum)) if wsum else np.inf
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
                     orders=(0, 1, 2, 3), groups=None):
    """Fit an OffsetPolynomialModel per axis with a CV-chosen order.

    windows: Windows; axis_temps: (m, 3) degC; signal: 'accel' or 'gyro' field of windows.
    Without a constant (single-orientation accel) the constant is still fitted (it holds the
    unobservable gravity projection) but not stored. Returns (model, report dict).
    """
    y_all = getattr(windows, signal)
    var = getattr(windows, f'{signal}_var')
    w_all = 1.0 / np.sqrt(np.maximum(var, 1e-30) / windows.n[:, None])
    if groups is None:
        groups = time_groups(windows.t0)
    t0 = np.asarray(t0, float)
    chosen, cv = [], []
    for i in range(3):
        dt = axis_temps[:, i] - t0[i]
        span = float(np.ptp(dt)) if len(dt) else 0.0
        allowed = [o for o in orders if o == 0 or span > 0.5 * o]
        o, sc = cv_order(dt, y_all[:, i], w_all[:, i], groups, allowed)
        chosen.append(o)
        cv.append(sc)
    order = max(chosen)
    coeffs = np.zeros((order + 1, 3))
    std = np.zeros((order + 1, 3))
    for i in range(3):
        dt = axis_temps[:, i] - t0[i]
        c, s = weighted_polyfit(dt, y_all[:, i], w_all[:, i], chosen[i])
        coeffs[:chosen[i] + 1, i] = c
        std[:chosen[i] + 1, i] = s
    model = OffsetPolynomialModel(t0, coeffs, sensor=sensor, include_constant=include_constant,
                                  coeff_std=std)
    if not include_constant:
        model.coeff_std[0] = 0.0
    report = {'order_per_axis': chosen, 'cv_rms_per_order': [
        {str(k): v for k, v in sc.items()} for sc in cv]}
    return model, report
