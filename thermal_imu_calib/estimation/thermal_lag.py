"""Thermal lag estimation: temperature legs, held-out groups and the lag time constant.

In a chamber cycle the heating and cooling legs disagree at the same temperature reading
(hysteresis) when the error follows the sensor's reading with a delay. A first-order lag
``tau dT_lag/dt = T - T_lag`` of the reading (thermal_input.ThermalFilter) removes it;
``estimate_tau`` finds ``tau`` by a 1-D search of the held-out error: for each candidate the
windows' lagged temperatures are computed, an offset polynomial in them is fitted with one
temperature leg (or hold, or time block) left out, and the summed normalised held-out error
of every axis of accelerometer and gyroscope is the score. A log-spaced grid brackets the
minimum, ``scipy.optimize.minimize_scalar`` refines it.

The window statistics also carry the temperature rate; ``rate_fit`` reports the
equivalent "temperature and its rate" regression (offset = p(T) + c dT/dt, to first order
c = -tau p'(T)) as a cross-check of the lag found.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy.optimize import minimize_scalar

from ..thermal_input import lag_windows
from .offset_fit import time_groups
from .placement_levels import held_out_level_fits

#: candidate time constants of the coarse grid, s (0 = no lag)
TAU_GRID = (0.0, 10.0, 20.0, 40.0, 70.0, 120.0, 200.0, 320.0, 500.0, 800.0, 1300.0, 2000.0)


def legs(windows, column=0, threshold=None):
    """Label each window with its temperature leg (monotonic heating or cooling run).

    A turning point is declared where the temperature has retreated from its running
    extreme by ``threshold`` degC (default: 10 % of the span, at least 0.5 degC), so noise
    and dwells do not split legs. Returns (leg id per window (m,), list of
    {'leg', 'direction', 't_min', 't_max', 'windows'}), legs numbered in time order.
    """
    m = len(windows)
    if m == 0 or windows.n_inputs == 0:
        return np.zeros(m, int), []
    tm = 0.5 * (windows.t0 + windows.t1)
    order = np.argsort(tm, kind='stable')
    temp = windows.temp[order, column]
    span = float(np.ptp(temp))
    thr = max(0.1 * span, 0.5) if threshold is None else float(threshold)
    turns = [0]
    moved = np.flatnonzero(np.abs(temp - temp[0]) > thr)
    if len(moved):
        ext_i = int(moved[0])
        direction = 1 if temp[ext_i] > temp[0] else -1
        for i in range(ext_i + 1, m):
            if direction * (temp[i] - temp[ext_i]) >= 0:
                ext_i = i
            elif direction * (temp[ext_i] - temp[i]) > thr:
                turns.append(ext_i)
                direction, ext_i = -direction, i
    ids_sorted = np.zeros(m, int)
    for j, start in enumerate(turns[1:], 1):
        ids_sorted[start:] = j
    ids = np.empty(m, int)
    ids[order] = ids_sorted
    info = []
    for j in range(len(turns)):
        sel = ids_sorted == j
        tj = temp[sel]
        info.append({'leg': j, 'direction': 'heating' if tj[-1] >= tj[0] else 'cooling',
                     't_min': float(tj.min()), 't_max': float(tj.max()),
                     'windows': int(sel.sum())})
    return ids, info


def cv_groups(windows, column=0, min_groups=3, n_blocks=6):
    """Return (groups (m,), kind) for held-out validation: legs, holds or time blocks.

    Temperature legs when there are at least ``min_groups`` of them (a cycle: the held-out
    leg is a different thermal history), else holds (several poses), else contiguous time
    blocks (one warm-up).
    """
    leg_ids, _ = legs(windows, column)
    if len(np.unique(leg_ids)) >= min_groups:
        return leg_ids, 'temperature legs'
    if len(np.unique(windows.hold)) >= min_groups:
        return windows.hold.copy(), 'holds'
    return time_groups(windows.t0, n_blocks), 'time blocks'


def _vander(x, order):
    return np.stack([x ** j for j in range(order + 1)], axis=-1)


def _weights(windows, signal):
    var = getattr(windows, f'{signal}_var')
    return 1.0 / np.sqrt(np.maximum(var, 1e-30) / np.maximum(windows.n, 1)[:, None])


def heldout_poly_error(x, y, w, groups, order, levels=None):
    """Return the per-axis held-out weighted RMS of an offset polynomial (leave a group out).

    x: (m, 3) input temperature per axis (centred), y: (m, 3) signal, w: (m, 3) weights
    (1 / std of each window mean). The residual is in units of that std. ``levels``: (m,)
    placement ids whose levels are random effects in the fits
    (``placement_levels.held_out_level_fits``), or None.
    """
    ug = np.unique(groups)
    sse = np.zeros(y.shape[1])
    if levels is not None:      # every group's training part fitted at once, axis by axis
        for a in range(y.shape[1]):
            coefs = held_out_level_fits(_vander(x[:, a], order), y[:, a], w[:, a] ** 2,
                                        groups, np.asarray(levels))
            for g, coef in zip(ug, coefs):
                test = groups == g
                r = (y[test, a] - _vander(x[test, a], order) @ coef) * w[test, a]
                sse[a] += float(r @ r)
        return np.sqrt(sse / len(groups))
    for g in ug:
        test = groups == g
        train = ~test
        for a in range(y.shape[1]):
            v = _vander(x[train, a], order) * w[train, a, None]
            coef, *_ = np.linalg.lstsq(v, y[train, a] * w[train, a], rcond=None)
            r = (y[test, a] - _vander(x[test, a], order) @ coef) * w[test, a]
            sse[a] += float(r @ r)
    return np.sqrt(sse / len(groups))


@dataclass
class LagEstimate:
    """Result of ``estimate_tau``: time constant per input and the evidence for it."""

    tau_s: np.ndarray                     # (k,) s, same for every input (one shared lag)
    score: float                          # summed normalised held-out error at tau
    score_no_lag: float                   # the same at tau = 0
    order: int
    groups: str
    curve: dict = field(default_factory=dict)   # tau -> score on the coarse grid

    @property
    def improvement(self):
        """Return the relative held-out error reduction against no lag (0..1)."""
        return 1.0 - self.score / self.score_no_lag if self.score_no_lag > 0 else 0.0

    def report(self):
        """Return a plain dict for the calibration file."""
        return {'tau_s': self.tau_s.tolist(), 'unit': 's', 'order': self.order,
                'cv_groups': self.groups, 'heldout_score': self.score,
                'heldout_score_no_lag': self.score_no_lag,
                'improvement': round(self.improvement, 4),
                'grid': {f'{k:g}': v for k, v in self.curve.items()}}


def estimate_tau(windows, accel_input, gyro_input, groups=None, order=2, grid=TAU_GRID,
                 signals=('accel', 'gyro'), group_kind='', lagged=None, levels=()):
    """Estimate one first-order lag time constant (s) for the temperature inputs.

    Score(tau) = sum over the axes of ``signals`` of the held-out RMS (in units of each
    window's noise) of an order-``order`` offset polynomial in the lagged temperature,
    normalised per axis by its value at tau = 0 so that every axis counts alike.
    ``lagged``: (k,) bool, the inputs the lag applies to (default all); the others keep
    tau 0, e.g. a thermal proxy measured on the sensing element itself (a gyro's
    resonance frequency) does not lag the error it follows. ``levels``: the sensors whose
    fits take each hold as a placement with a random level (``placement_levels``). Returns
    a ``LagEstimate``.
    """
    if windows.n_inputs == 0:
        raise ValueError('a thermal lag needs a temperature input')
    if groups is None:
        groups, group_kind = cv_groups(windows)
    k = windows.n_inputs
    hold = np.asarray(windows.hold)
    mask = np.ones(k, bool) if lagged is None else np.asarray(lagged, bool).reshape(k)
    # a sensor on unlagged inputs only would add a constant to the score: left out
    ys = [(getattr(windows, s), _weights(windows, s), idx, hold if s in levels else None)
          for s, idx in zip(('accel', 'gyro'), (accel_input, gyro_input))
          if s in signals and np.any(mask[list(idx)])]
    if not ys:
        return LagEstimate(np.zeros(k), 1.0, 1.0, order, group_kind, {0.0: 1.0})

    def raw_errors(tau):
        lag = lag_windows(windows.t0, windows.t1, windows.temp, np.where(mask, tau, 0.0))
        out = []
        for y, w, idx, lv in ys:
            x = lag[:, idx]
            x = x - x.mean(0)
            out.append(heldout_poly_error(x, y, w, groups, order, lv))
        return np.concatenate(out)

    base = raw_errors(0.0)
    scale = np.where(base > 0, base, 1.0)

    def score(tau):
        return float(np.mean(raw_errors(tau) / scale))

    curve = {float(t): (1.0 if t == 0 else score(t)) for t in grid}
    taus = np.array(sorted(curve))
    vals = np.array([curve[t] for t in taus])
    i = int(np.argmin(vals))
    best_tau, best = float(taus[i]), float(vals[i])
    if 0 < i < len(taus) - 1:   # refine in log tau inside the bracketing grid cell
        lo, hi = np.log(taus[i - 1] if taus[i - 1] > 0 else taus[i] / 2), np.log(taus[i + 1])
        res = minimize_scalar(lambda lt: score(float(np.exp(lt))), bounds=(lo, hi),
                              method='bounded', options={'xatol': 0.02})
        if res.fun < best:
            best_tau, best = float(np.exp(res.x)), float(res.fun)
    return LagEstimate(np.where(mask, round(best_tau, 1), 0.0), best, 1.0, order, group_kind,
                       curve)


def rate_fit(windows, axis_temps, signal, order=2, groups=None):
    """Fit offset = p(T) + c dT/dt per axis; return held-out errors with and without c.

    A cross-check of the lag: to first order c = -tau p'(T). Returns a dict with the
    per-axis held-out RMS (noise units) of p(T) alone and with the rate term, and c.
    """
    if groups is None:
        groups, _ = cv_groups(windows)
    y = getattr(windows, signal)
    w = _weights(windows, signal)
    x = axis_temps - axis_temps.mean(0)
    rate = windows.temp_rate[:, 0] if windows.n_inputs else np.zeros(len(windows))
    no_rate = heldout_poly_error(x, y, w, groups, order)
    sse = np.zeros(3)
    coefs = np.zeros(3)
    for g in np.unique(groups):
        test = groups == g
        for a in range(3):
            v = np.column_stack([_vander(x[:, a], order), rate])
            coef, *_ = np.linalg.lstsq(v[~test] * w[~test, a, None], y[~test, a] * w[~test, a],
                                       rcond=None)
            r = (y[test, a] - v[test] @ coef) * w[test, a]
            sse[a] += float(r @ r)
    for a in range(3):
        v = np.column_stack([_vander(x[:, a], order), rate])
        coefs[a] = np.linalg.lstsq(v * w[:, a, None], y[:, a] * w[:, a], rcond=None)[0][-1]
    return {'heldout_no_rate': no_rate.tolist(), 'heldout_with_rate':
            np.sqrt(sse / len(groups)).tolist(), 'rate_coefficient': coefs.tolist(),
            'unit': f'{"m/s^2" if signal == "accel" else "rad/s"} per degC/s'}


def lagged_axis_temperatures(windows, tau_s, axis_input):
    """Return (m, 3) per-axis model-input temperatures for a lag (None or 0: the reading)."""
    if windows.n_inputs == 0:
        return np.zeros((len(windows), 3))
    if tau_s is None or np.all(np.asarray(tau_s) == 0):
        return windows.temp[:, axis_input]
    return lag_windows(windows.t0, windows.t1, windows.temp, np.asarray(tau_s, float))[
        :, axis_input]


def tau_or_none(est: Optional[LagEstimate], min_improvement=0.05):
    """Return the estimated tau when it clearly helps (held-out gain), else None."""
    if est is None or not np.any(est.tau_s > 0) or est.improvement < min_improvement:
        return None
    return est.tau_s


def filter_restart_spread(cal, windows):
    """Return {sensor: (3,)}: the largest |output at T_lag - output at T| over the windows.

    What the calibration's ``temperature_filter`` changes in its own output over the
    calibration data (the models at the lagged temperature against the same models at
    equilibrium, window means as raw input; m/s^2 and rad/s). A stream that (re)starts
    sets the lag to the reading, so its output may be off by up to this much, forgotten
    with the filter's time constant (``Calibration.restart_std``). None without a filter.
    """
    f = cal.temperature_filter
    if f is None or f.is_identity or len(windows) == 0 or not cal.inputs:
        return None
    lagged = f.window_temperatures(windows)
    at_lag = cal.apply(windows.accel, windows.gyro, lagged)
    at_eq = cal.apply(windows.accel, windows.gyro, windows.temp)
    return {which: np.max(np.abs(getattr(at_lag, which) - getattr(at_eq, which)), axis=0)
            for which in ('accel', 'gyro') if getattr(cal, which) is not None}


def with_restart_spread(cal, windows):
    """Return ``cal`` with its filter's ``restart_spread`` measured on ``windows`` (in place)."""
    spread = filter_restart_spread(cal, windows)
    if spread is not None:
        cal.temperature_filter = dataclasses.replace(cal.temperature_filter,
                                                     restart_spread=spread)
    return cal
