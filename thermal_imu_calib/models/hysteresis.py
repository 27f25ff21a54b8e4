"""Offset polynomial in temperature plus terms of the thermal history (hysteresis), per axis.

    corrected_i = raw_i - sum_{j=j0..order} c_j,i (B_i - T0_i)^j - sum_k d_k,i h_k,i

B is the model's base input: the reading T, or T through a first-order lag (``base``); the
polynomial part is an ``OffsetPolynomialModel`` in B (``poly``).
The history terms ``h_k`` are built from lag cascades of the reading (``thermal_input``
``history_key``: ``lag:TAU`` one state, ``lag:TAU1:TAU2`` a die-to-case two-state lag):

* ``diff``: the lag difference ``T_lag - T`` (degC); to first order ``-tau dT/dt``;
* ``rate``: the smoothed temperature rate ``(T - T_lag) / tau`` (degC/s).

The lagged readings come from ``CalibrationStream`` (``aux['history']``, per axis); without
them (``Calibration.apply`` alone) the lags equal the reading: thermal equilibrium, every
history term zero. Without ``include_constant`` only the drift relative to T0 is removed
(one orientation: the constant holds gravity).
"""

import numpy as np

from ..thermal_input import parse_history_key
from .base import Param, register, require, SensorModel, with_input_unit
from .polynomial import OffsetPolynomialModel

TERM_KINDS = ('diff', 'rate')


@register
class HysteresisOffsetModel(SensorModel):
    """Per-axis offset polynomial in (B - T0) plus history terms; units follow the sensor."""

    kind = 'hysteresis_offset'

    def __init__(self, t0, coeffs, terms=(), term_coeffs=None, base='', sensor='accel',
                 include_constant=True, coeff_std=None, term_std=None, input_unit='degC',
                 term_spread=None, restart_spread=None):
        #: the polynomial part (in the base input), an ``OffsetPolynomialModel``
        self.poly = OffsetPolynomialModel(t0, coeffs, sensor, include_constant, coeff_std,
                                          input_unit)
        self.terms = [(str(k), str(h)) for k, h in terms]
        for kind, key in self.terms:
            if kind not in TERM_KINDS:
                raise ValueError(f'history term kind {kind!r} is not one of {TERM_KINDS}')
            parse_history_key(key)
        self.base = str(base or '')
        if self.base:
            parse_history_key(self.base)
        nt = len(self.terms)
        self.term_coeffs = (np.zeros((nt, 3)) if term_coeffs is None
                            else np.asarray(term_coeffs, float).reshape(nt, 3))
        self.term_std = None if term_std is None else np.asarray(term_std, float).reshape(nt, 3)
        #: RMS of each history term over the calibration data (its unit): what an unknown
        #: history (a stream just (re)started) may hold
        self.term_spread = (None if term_spread is None
                            else np.asarray(term_spread, float).reshape(nt, 3))
        #: (3,) the largest offset the thermal history added over the calibration data
        #: (sensor unit): how far a stream that (re)starts at equilibrium may be off
        self.restart_spread = (None if restart_spread is None
                               else np.asarray(restart_spread, float).reshape(3))

    # the polynomial part's settings, shared with it (the Calibration and the file set them)
    sensor = property(lambda self: self.poly.sensor,
                      lambda self, v: setattr(self.poly, 'sensor', v))
    input_unit = property(lambda self: self.poly.input_unit,
                          lambda self, v: setattr(self.poly, 'input_unit', v))
    t0 = property(lambda self: self.poly.t0)
    coeffs = property(lambda self: self.poly.coeffs)
    coeff_std = property(lambda self: self.poly.coeff_std)
    include_constant = property(lambda self: self.poly.include_constant)

    @property
    def order(self):
        """Return the polynomial order."""
        return self.poly.order

    def temperature_degree(self):
        """Return the degree of the polynomial in the base input (history terms aside)."""
        return self.poly.temperature_degree()

    @property
    def history_keys(self):
        """Return the lag cascades this model needs from the stream (may be empty)."""
        keys = [h for _, h in self.terms] + ([self.base] if self.base else [])
        return list(dict.fromkeys(keys))

    def features(self, temps, aux=None):
        """Return (base input (n, 3), history terms (nt, n, 3)) at per-axis readings."""
        temps = np.asarray(temps, float)
        hist = (aux or {}).get('history') or {}
        base = np.asarray(hist.get(self.base, temps), float) if self.base else temps
        out = np.zeros((len(self.terms),) + temps.shape)
        for k, (kind, key) in enumerate(self.terms):
            d = np.asarray(hist.get(key, temps), float) - temps
            out[k] = d if kind == 'diff' else -d / parse_history_key(key)[0]
        return base, out

    def offset(self, temps, aux=None):
        """Return the modelled (n, 3) offset in the sensor unit (history terms included)."""
        base, h = self.features(temps, aux)
        return self.poly.offset(base) + np.einsum('kna,ka->na', h, self.term_coeffs)

    def correct(self, raw, temps, aux=None):
        """Subtract the modelled offset."""
        return np.asarray(raw, float) - self.offset(temps, aux)

    def forward(self, true, temps, aux=None):
        """Add the modelled offset."""
        return np.asarray(true, float) + self.offset(temps, aux)

    def predict_std(self, temps, aux=None):
        """Return the 1-sigma offset uncertainty from coefficient stds (correlations ignored)."""
        base, h = self.features(temps, aux)
        std = self.poly.predict_std(base)
        if std is None:
            return None
        var = std ** 2
        if self.term_std is not None:
            var += np.einsum('kna,ka->na', h ** 2, self.term_std ** 2)
        age = ((aux or {}).get('history') or {}).get('_age_s')
        if age is not None and self.restart_spread is not None:
            # a (re)started stream does not know the history before it and starts at
            # equilibrium: its offset may be off by what the history added during the
            # calibration, forgotten as the longest lag cascade's memory passes
            mem = np.exp(-np.asarray(age, float) / self.memory_s)
            var += (mem[:, None] * self.restart_spread) ** 2
        elif self.term_spread is not None and age is not None:
            # files without restart_spread: each term may be off by its RMS spread
            for k, (_, key) in enumerate(self.terms):
                mem = np.exp(-np.asarray(age, float) / sum(parse_history_key(key)))
                var += (mem[:, None] * self.term_coeffs[k] * self.term_spread[k]) ** 2
        return np.sqrt(var)

    @property
    def memory_s(self):
        """Return the longest memory (s) of the lag cascades: the sum of their constants."""
        return max((sum(parse_history_key(k)) for k in self.history_keys), default=1.0)

    def params(self):
        """Return T0, c0..cN (powers of B - T0) and d0..dK (one per history term), per axis."""
        u, iu = self.unit, self.input_unit
        out = self.poly.params()
        for k, (kind, key) in enumerate(self.terms):
            std = None if self.term_std is None else self.term_std[k]
            unit = f'{u}/{iu}' if kind == 'diff' else f'{u}/({iu}/s)'
            desc = (f'coefficient of the lag difference T_{key} - T' if kind == 'diff' else
                    f'coefficient of the temperature rate (T - T_{key}) / tau')
            out[f'd{k}'] = Param(self.term_coeffs[k], unit, std, desc)
        return out

    def meta(self):
        """Return order, constant flag, base input and history terms."""
        return with_input_unit({'order': self.order, 'include_constant': self.include_constant,
                                'offset_only': not self.include_constant,
                                'base': self.base or 'T',
                                'terms': [{'kind': k, 'history': h} for k, h in self.terms],
                                **({} if self.term_spread is None else
                                   {'term_spread': self.term_spread.tolist()}),
                                **({} if self.restart_spread is None else
                                   {'restart_spread': self.restart_spread.tolist()})},
                               self.input_unit)

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters (the polynomial part read as an offset polynomial)."""
        where = cls.kind
        poly = OffsetPolynomialModel.from_params(params, meta)
        terms = [(str(t.get('kind')), str(t.get('history'))) for t in meta.get('terms') or []]
        d = [require(params, f'd{k}', (3,), where) for k in range(len(terms))]
        dstd = [params[f'd{k}'].std for k in range(len(terms))]
        base = str(meta.get('base', 'T'))
        return cls(poly.t0, poly.coeffs, terms, np.array(d).reshape(len(terms), 3),
                   '' if base == 'T' else base, include_constant=poly.include_constant,
                   coeff_std=poly.coeff_std,
                   term_std=(None if not terms or any(s is None for s in dstd)
                             else np.stack(dstd)),
                   input_unit=poly.input_unit,
                   term_spread=meta.get('term_spread') if terms else None,
                   restart_spread=meta.get('restart_spread'))
