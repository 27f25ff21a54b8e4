"""Offset models with thermal-history terms: candidate specs, window features and the fit.

A candidate (``Spec``) is an offset polynomial of order 1..3 in a base input (the reading
T, or T through a first-order lag), plus zero or more history terms (``models.hysteresis``):
the lag difference ``T_lag - T``, the temperature rate, or the difference of a two-state
(die-to-case) lag cascade; and a weighting of the windows in the least-squares fit:

* ``time``: every window (a fixed stretch of time) counts alike, as the flight stacks'
  fits do; a warm-up that dwells near its final temperature then dominates the fit;
* ``temperature``: windows are weighted so that every 1/``TEMP_BINS`` of the temperature
  span counts alike (PX4 resamples uniformly in temperature for the same reason).

The candidate grid, the weighting and every time constant are chosen by held-out blocks
of the thermal history (``selection.time_folds``), never by the in-sample residual.
"""

from dataclasses import dataclass
from typing import Tuple

import numpy as np

from ..models.hysteresis import HysteresisOffsetModel
from ..models.polynomial import OffsetPolynomialModel
from ..thermal_input import history_key, history_windows
from .placement_levels import random_level_fits

#: temperature-uniform weighting: the span is cut into this many equal bins
TEMP_BINS = 40
#: time constants (s) of the lag-difference and lagged-input candidates
TAU_GRID = (20.0, 50.0, 100.0, 200.0, 400.0)
#: two-state (die-to-case) cascades (s)
TWO_STATE_GRID = ((20.0, 200.0), (50.0, 500.0))
#: time constant (s) of the smoothed rate term
RATE_TAU = 30.0
#: the flight stacks' reference temperature (ArduPilot TEMP_REF), degC
ARDUPILOT_TREF = 35.0


@dataclass(frozen=True)
class Spec:
    """One candidate: order, base lag (() = the reading), history terms, weighting."""

    order: int
    base: Tuple[float, ...] = ()
    terms: Tuple[Tuple[str, Tuple[float, ...]], ...] = ()
    weighting: str = 'time'
    name: str = ''

    @property
    def n_params(self):
        """Return the number of fitted parameters per axis (plus one per time constant)."""
        return self.order + 1 + len(self.terms) + len(self.base) + sum(
            len(t) for _, t in self.terms)

    def label(self):
        """Return a short readable description, e.g. 'cubic T + diff lag:100, time'."""
        if self.name:
            return self.name
        words = {1: 'linear', 2: 'quadratic', 3: 'cubic'}
        base = f'T_{history_key(self.base)}' if self.base else 'T'
        parts = [f'{words.get(self.order, f"order {self.order}")} {base}']
        parts += [f'{k} {history_key(t)}' for k, t in self.terms]
        return ' + '.join(parts) + f', {self.weighting}-weighted'

    def to_dict(self):
        """Return a JSON-able form (``spec_from_dict`` reads it back equal)."""
        return {'order': self.order, 'base': list(self.base),
                'terms': [[k, list(t)] for k, t in self.terms], 'weighting': self.weighting,
                'name': self.name}


def spec_from_dict(item):
    """Return the ``Spec`` of ``Spec.to_dict``'s form; None when it is not one."""
    try:
        return Spec(int(item['order']), tuple(float(x) for x in item['base']),
                    tuple((str(k), tuple(float(x) for x in t)) for k, t in item['terms']),
                    str(item['weighting']), str(item.get('name', '')))
    except (KeyError, TypeError, ValueError, AttributeError):
        return None


#: the flight stacks' cubic as ArduPilot's offline tool fits it (tempcal_IMU.py: cubic
#: polyfit of every sample against T - 35 degC): time-weighted, no history
ARDUPILOT_SPEC = Spec(3, (), (), 'time', 'ardupilot (cubic in T - 35 degC, time-weighted)')

#: no thermal terms: the constant alone (the gyro's bias; nothing for an offset-only
#: accelerometer). On held-out history its figure is the raw output's (the figures take
#: constants out), so it is chosen when no thermal model is better than leaving the output
#: as it is: the "no harm" candidate, the simplest of all
NO_THERMAL_SPEC = Spec(0, (), (), 'time', 'no thermal terms (constant only)')


def candidate_specs():
    """Return the candidate grid, simplest first (``NO_THERMAL_SPEC``, then the floor).

    ``ARDUPILOT_SPEC`` is the floor the choice never goes below; ``NO_THERMAL_SPEC`` is the
    output left as it is.
    """
    out = [NO_THERMAL_SPEC, ARDUPILOT_SPEC]
    for weighting in ('time', 'temperature'):
        for order in (1, 2, 3):
            hist = [()]
            hist += [(('diff', (tau,)),) for tau in TAU_GRID]
            hist += [(('rate', (RATE_TAU,)),)]
            hist += [(('diff', c),) for c in TWO_STATE_GRID]
            for h in hist:
                out.append(Spec(order, (), h, weighting))
            for tau in TAU_GRID:
                out.append(Spec(order, (tau,), (), weighting))
    return sorted(out, key=lambda s: (s.n_params, s is not ARDUPILOT_SPEC))


class Features:
    """Window-level inputs of every candidate, computed once per window table."""

    def __init__(self, windows, axis_input, levels=False):
        self.windows = windows
        self.axis_input = list(axis_input)
        #: (m,) placement (hold) ids whose levels ``fit_spec`` takes as random
        #: (``placement_levels``), or None: every window independent
        self.levels = np.asarray(windows.hold) if levels else None
        self.temp = windows.temp[:, self.axis_input] if windows.n_inputs else \
            np.zeros((len(windows), 3))
        self._lags = {}

    def lagged(self, taus):
        """Return the (m, 3) per-axis readings through the lag cascade ``taus``."""
        key = tuple(taus)
        if key not in self._lags:
            w = self.windows
            self._lags[key] = history_windows(w.t0, w.t1, w.temp, key)[:, self.axis_input]
        return self._lags[key]

    def design(self, spec, t0):
        """Return (m, 3, p) design matrices: powers of (B - t0), then the history terms."""
        base = self.lagged(spec.base) if spec.base else self.temp
        dt = base - t0
        cols = [dt ** j for j in range(spec.order + 1)]
        for kind, taus in spec.terms:
            d = self.lagged(taus) - self.temp
            cols.append(d if kind == 'diff' else -d / taus[0])
        return np.stack(cols, axis=-1)


def fit_weights(temps, weighting, rows):
    """Return (m,) least-squares weights of ``rows`` (others 0) for a weighting.

    ``temperature``: 1 / (windows in the row's temperature bin), bins of 1/``TEMP_BINS``
    of the span of ``rows``; ``time``: 1.
    """
    w = np.zeros(len(temps))
    t = np.asarray(temps, float)[rows]
    if weighting == 'time' or len(t) == 0 or np.ptp(t) <= 0:
        w[rows] = 1.0
        return w
    b = np.minimum(((t - t.min()) / np.ptp(t) * TEMP_BINS).astype(int), TEMP_BINS - 1)
    cnt = np.bincount(b, minlength=TEMP_BINS)
    w[rows] = 1.0 / cnt[b]
    return w / np.mean(w[rows])


def fit_spec(feats, spec, y, rows, t0, design=None):
    """Fit a spec per axis on ``rows``; returns (coef (p, 3), std (p, 3)).

    Weighted least squares (``fit_weights`` on each axis' reading); the std is from the
    weighted residual scatter (coefficient covariance s^2 (A^T W A)^-1). With
    ``feats.levels`` each placement's level is a random effect
    (``placement_levels.random_level_fits``, REML per axis). ``design``: the spec's
    ``feats.design(spec, t0)`` when the caller already has it (it does not depend on rows).
    """
    a = feats.design(spec, t0) if design is None else design
    p = a.shape[-1]
    coef = np.zeros((p, 3))
    std = np.zeros((p, 3))
    ws = [fit_weights(feats.temp[:, i], spec.weighting, rows)[rows] for i in range(3)]
    if feats.levels is not None:        # the three axes' REML fits at once
        fits = random_level_fits(a[rows].transpose(1, 0, 2), y[rows].T, np.stack(ws),
                                 feats.levels[rows])
        for i, (fit, w) in enumerate(zip(fits, ws)):
            coef[:, i] = fit.coef
            std[:, i] = fit.std(fit.sigma2 / max(float(np.mean(w)), 1e-300))
        return coef, std
    for i, w in enumerate(ws):
        sw = np.sqrt(w)
        ai = a[rows, i] * sw[:, None]
        yi = y[rows, i] * sw
        c, *_ = np.linalg.lstsq(ai, yi, rcond=None)
        r = yi - ai @ c
        dof = max(len(yi) - p, 1)
        s2 = float(r @ r) / dof / max(float(np.mean(w)), 1e-300)
        cov = np.linalg.pinv(ai.T @ ai) * s2
        coef[:, i], std[:, i] = c, np.sqrt(np.maximum(np.diag(cov), 0.0))
    return coef, std


def predict(feats, spec, coef, t0, design=None):
    """Return the (m, 3) modelled offset (constant included) of a fitted spec.

    ``design``: ``feats.design(spec, t0)`` when the caller already has it.
    """
    a = feats.design(spec, t0) if design is None else design
    return np.einsum('map,pa->ma', a, coef)


def restart_spread(feats, spec, coef, t0):
    """Return (3,) the largest |offset with its history - offset at equilibrium| (sensor unit).

    Over the calibration windows: what the thermal history (history terms and a lagged base
    input) added to the modelled offset. A stream that (re)starts does not know that
    history and starts at equilibrium, so its offset may be off by up to this much.
    """
    p = spec.order + 1
    full = predict(feats, spec, coef, t0)
    flat = Spec(spec.order, (), (), spec.weighting)
    eq = predict(feats, flat, coef[:p], t0)
    return np.max(np.abs(full - eq), axis=0) if len(full) else np.zeros(3)


def build_model(spec, coef, std, t0, sensor, include_constant, feats=None):
    """Return the model of a fitted spec: HysteresisOffsetModel, or OffsetPolynomialModel.

    A spec without history terms or lagged input is a plain offset polynomial.

    With ``feats`` (the calibration windows' Features) the model keeps each history term's
    RMS over them and the largest offset the history added (``restart_spread``), which its
    ``predict_std`` uses after a stream (re)start.
    """
    p = spec.order + 1
    if not spec.terms and not spec.base:
        # no thermal history: the plain offset polynomial (same file, exports and apply)
        return OffsetPolynomialModel(t0, coef[:p], sensor, include_constant, std[:p])
    terms = [(k, history_key(t)) for k, t in spec.terms]
    spread = restart = None
    if feats is not None and terms:
        h = feats.design(spec, t0)[..., p:]
        spread = np.sqrt(np.mean(h ** 2, axis=0)).T
    if feats is not None and (terms or spec.base):
        restart = restart_spread(feats, spec, coef, t0)
    return HysteresisOffsetModel(t0, coef[:p], terms, coef[p:], history_key(spec.base)
                                 if spec.base else '', sensor=sensor,
                                 include_constant=include_constant, coeff_std=std[:p],
                                 term_std=std[p:], term_spread=spread,
                                 restart_spread=restart)
