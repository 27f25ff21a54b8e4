"""Offset polynomial in temperature plus terms of the thermal history (hysteresis), per axis.

    corrected_i = raw_i - sum_{j=j0..order} c_j,i (B_i - T0_i)^j - sum_k d_k,i h_k,i

B is the model's base input: the reading T, or T through a first-order lag (``base``).
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

from ..input_units import coefficient_unit, reference_description
from ..thermal_input import parse_history_key
from .base import input_unit_of, Param, register, require, SensorModel, with_input_unit

TERM_KINDS = ('diff', 'rate')


@register
class HysteresisOffsetModel(SensorModel):
    """Per-axis offset polynomial in (B - T0) plus history terms; units follow the sensor."""

    kind = 'hysteresis_offset'

    def __init__(self, t0, coeffs, terms=(), term_coeffs=None, base='', sensor='accel',
                 include_constant=True, coeff_std=None, term_std=None, input_unit='degC',
                 term_spread=None):
        self.input_unit = str(input_unit)
        self.t0 = np.asarray(t0, float).reshape(3)
        self.coeffs = np.asarray(coeffs, float)
        if self.coeffs.ndim != 2 or self.coeffs.shape[1] != 3:
            raise ValueError(f'coeffs must be (order+1, 3), got {self.coeffs.shape}')
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
        self.sensor = sensor
        self.include_constant = bool(include_constant)
        if not self.include_constant:
            self.coeffs[0] = 0.0
        self.coeff_std = None if coeff_std is None else np.asarray(coeff_std, float)
        self.term_std = None if term_std is None else np.asarray(term_std, float).reshape(nt, 3)
        #: RMS of each history term over the calibration data (its unit): what an unknown
        #: history (a stream just (re)started) may hold
        self.term_spread = (None if term_spread is None
                            else np.asarray(term_spread, float).reshape(nt, 3))

    @property
    def order(self):
        """Return the polynomial order."""
        return self.coeffs.shape[0] - 1

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
        dt = base - self.t0
        out = np.zeros_like(dt)
        for c in self.coeffs[::-1]:
            out = out * dt + c
        return out + np.einsum('kna,ka->na', h, self.term_coeffs)

    def correct(self, raw, temps, aux=None):
        """Subtract the modelled offset."""
        return np.asarray(raw, float) - self.offset(temps, aux)

    def forward(self, true, temps, aux=None):
        """Add the modelled offset."""
        return np.asarray(true, float) + self.offset(temps, aux)

    def predict_std(self, temps, aux=None):
        """Return the 1-sigma offset uncertainty from coefficient stds (correlations ignored)."""
        if self.coeff_std is None:
            return None
        base, h = self.features(temps, aux)
        dt = base - self.t0
        var = np.zeros_like(dt)
        for j, s in enumerate(self.coeff_std):
            var += (s * dt ** j) ** 2
        if self.term_std is not None:
            var += np.einsum('kna,ka->na', h ** 2, self.term_std ** 2)
        age = ((aux or {}).get('history') or {}).get('_age_s')
        if self.term_spread is not None and age is not None:
            # a (re)started stream does not know the history before it: each term may be
            # off by its spread, forgotten as the lag cascade's memory passes
            for k, (_, key) in enumerate(self.terms):
                mem = np.exp(-np.asarray(age, float) / sum(parse_history_key(key)))
                var += (mem[:, None] * self.term_coeffs[k] * self.term_spread[k]) ** 2
        return np.sqrt(var)

    def params(self):
        """Return T0, c0..cN per axis and d0..dK (one per history term) per axis."""
        u, iu = self.unit, self.input_unit
        out = {'T0': Param(self.t0, iu, description=reference_description(iu))}
        for j, c in enumerate(self.coeffs):
            std = None if self.coeff_std is None else self.coeff_std[j]
            desc = 'constant offset' if j == 0 else f'offset coefficient of (B-T0)^{j}'
            out[f'c{j}'] = Param(c, coefficient_unit(u, iu, j), std, desc)
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
                                   {'term_spread': self.term_spread.tolist()})},
                               self.input_unit)

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters."""
        where = cls.kind
        order = int(meta.get('order', 0))
        t0 = require(params, 'T0', (3,), where)
        coeffs = np.stack([require(params, f'c{j}', (3,), where) for j in range(order + 1)])
        stds = [params[f'c{j}'].std for j in range(order + 1)]
        terms = [(str(t.get('kind')), str(t.get('history'))) for t in meta.get('terms') or []]
        d = [require(params, f'd{k}', (3,), where) for k in range(len(terms))]
        dstd = [params[f'd{k}'].std for k in range(len(terms))]
        base = str(meta.get('base', 'T'))
        return cls(t0, coeffs, terms, np.array(d).reshape(len(terms), 3),
                   '' if base == 'T' else base,
                   include_constant=bool(meta.get('include_constant', True)),
                   coeff_std=None if any(s is None for s in stds) else np.stack(stds),
                   term_std=(None if not terms or any(s is None for s in dstd)
                             else np.stack(dstd)),
                   input_unit=input_unit_of(params, meta),
                   term_spread=meta.get('term_spread') if terms else None)
