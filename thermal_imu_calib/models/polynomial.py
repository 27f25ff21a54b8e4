"""Offset-only polynomial in temperature, per axis (PX4/ArduPilot-style thermal offsets).

    corrected_i = raw_i - sum_{j=j0..order} c_j,i * (T_i - T0_i)^j

T is the model's thermal input: a temperature in degC or a proxy in its own unit
(``input_unit``, e.g. Hz); T0 and the coefficients are in that unit.

With ``include_constant`` (j0 = 0) the constant bias is removed too (gyro bias from static
segments). Without it (j0 = 1) the model removes only the *drift relative to the reference
temperature T0*: the single-orientation warm-up case, where a constant accelerometer bias
cannot be told apart from the projection of gravity.
"""

import numpy as np

from ..input_units import coefficient_unit, reference_description
from .base import (highest_power, input_unit_of, Param, register, require, SensorModel,
                   with_input_unit)


@register
class OffsetPolynomialModel(SensorModel):
    """Per-axis offset polynomial in (T - T0); units follow the sensor (m/s^2 or rad/s)."""

    kind = 'offset_polynomial'

    def __init__(self, t0, coeffs, sensor='accel', include_constant=True, coeff_std=None,
                 input_unit='degC'):
        self.input_unit = str(input_unit)
        self.t0 = np.asarray(t0, float).reshape(3)
        self.coeffs = np.asarray(coeffs, float)  # (order+1, 3): row j multiplies dT^j
        if self.coeffs.ndim != 2 or self.coeffs.shape[1] != 3:
            raise ValueError(f'coeffs must be (order+1, 3), got {self.coeffs.shape}')
        self.sensor = sensor
        self.include_constant = bool(include_constant)
        if not self.include_constant:
            self.coeffs[0] = 0.0
        self.coeff_std = None if coeff_std is None else np.asarray(coeff_std, float)

    @property
    def order(self):
        """Return the polynomial order."""
        return self.coeffs.shape[0] - 1

    def temperature_degree(self):
        """Return the highest power with a non-zero coefficient on any axis (0: constant)."""
        return highest_power(self.coeffs[1:])

    def offset(self, temps):
        """Return the modelled (n, 3) offset at per-axis thermal inputs (n, 3), ``input_unit``."""
        dt = np.asarray(temps, float) - self.t0
        out = np.zeros_like(dt)
        for c in self.coeffs[::-1]:  # Horner
            out = out * dt + c
        return out

    def correct(self, raw, temps, aux=None):
        """Subtract the modelled offset."""
        return np.asarray(raw, float) - self.offset(temps)

    def forward(self, true, temps, aux=None):
        """Add the modelled offset."""
        return np.asarray(true, float) + self.offset(temps)

    def predict_std(self, temps):
        """Return the 1-sigma offset uncertainty from coefficient stds (correlations ignored)."""
        if self.coeff_std is None:
            return None
        dt = np.asarray(temps, float) - self.t0
        var = np.zeros_like(dt)
        for j, s in enumerate(self.coeff_std):
            var += (s * dt ** j) ** 2
        return np.sqrt(var)

    def params(self):
        """Return T0 and one parameter per power, c0..cN, each per axis."""
        u, iu = self.unit, self.input_unit
        out = {'T0': Param(self.t0, iu, description=reference_description(iu))}
        for j, c in enumerate(self.coeffs):
            std = None if self.coeff_std is None else self.coeff_std[j]
            unit = coefficient_unit(u, iu, j)
            desc = 'constant offset' if j == 0 else f'offset coefficient of (T-T0)^{j}'
            out[f'c{j}'] = Param(c, unit, std, desc)
        return out

    def meta(self):
        """Return order and whether the constant term is modelled."""
        return with_input_unit({'order': self.order, 'include_constant': self.include_constant,
                                'offset_only': not self.include_constant}, self.input_unit)

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters."""
        where = cls.kind
        order = int(meta.get('order', 0))
        t0 = require(params, 'T0', (3,), where)
        coeffs = np.stack([require(params, f'c{j}', (3,), where) for j in range(order + 1)])
        stds = [params[f'c{j}'].std for j in range(order + 1)]
        std = None if any(s is None for s in stds) else np.stack(stds)
        return cls(t0, coeffs, include_constant=bool(meta.get('include_constant', True)),
                   coeff_std=std, input_unit=input_unit_of(params, meta))
