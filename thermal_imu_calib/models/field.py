"""Seed 000: field thermal model of a triaxial accelerometer (Yang, Wu, Lian, Liu).

Measurement model, eqs. (3)-(5) and (8) of the paper, per axis i = x, y, z:

    raw = diag(k(T)) S f + b(T)
    k_i(T_i) = k0_i + dk0_i + k1_i dT_i + k2_i dT_i^2
    b_i(T_i) = b0_i + db0_i + b1_i dT_i + b2_i dT_i^2,      dT_i = T_i - T0_i

f is the specific force in the accelerometer reference frame p (m/s^2), S the
lower-triangular non-orthogonality matrix and k0, b0 the prior (lab) scale factor and
bias at T0; dk0, db0 are the drift of those lab values found in the field. Without a
prior, k0 = 1, b0 = 0, S = I and dk0/db0 carry the whole scale-factor and bias error.
Correction inverts the model: f = S^-1 ((raw - b(T)) / k(T)).
"""

import numpy as np

from ..input_units import coefficient_unit, reference_description
from .base import (highest_power, input_unit_of, Param, register, require, SensorModel,
                   with_input_unit)

#: thermal vector layout per axis, paper eq. (9)
THERMAL_NAMES = ('dk0', 'k1', 'k2', 'db0', 'b1', 'b2')
THERMAL_UNITS = ('1', '1/degC', '1/degC^2', 'm/s^2', 'm/s^2/degC', 'm/s^2/degC^2')
THERMAL_DESC = ('scale-factor change at T0 relative to the prior',
                'scale-factor temperature coefficient, 1st order',
                'scale-factor temperature coefficient, 2nd order',
                'bias change at T0 relative to the prior',
                'bias temperature coefficient, 1st order',
                'bias temperature coefficient, 2nd order')


def thermal_units(input_unit='degC'):
    """Return the units of THERMAL_NAMES for a thermal input in ``input_unit``."""
    return tuple(coefficient_unit(u, input_unit, j) for u in ('1', 'm/s^2') for j in range(3))


@register
class FieldPolynomialModel(SensorModel):
    """Per-axis 2nd-order scale factor and bias in dT with prior k0, b0, S (seed 000)."""

    kind = 'field_polynomial'
    sensor = 'accel'

    def __init__(self, t0, thermal, k0=None, b0=None, s=None, thermal_std=None,
                 input_unit='degC'):
        self.input_unit = str(input_unit)
        self.t0 = np.asarray(t0, float).reshape(3)
        #: (3, 6) rows x, y, z; columns THERMAL_NAMES
        self.thermal = np.asarray(thermal, float).reshape(3, 6)
        self.k0 = np.ones(3) if k0 is None else np.asarray(k0, float).reshape(3)
        self.b0 = np.zeros(3) if b0 is None else np.asarray(b0, float).reshape(3)
        self.s = np.eye(3) if s is None else np.asarray(s, float).reshape(3, 3)
        if np.any(np.abs(np.triu(self.s, 1)) > 0):
            raise ValueError('S must be lower-triangular (seed 000 non-orthogonality)')
        if np.any(np.abs(np.diag(self.s)) < 0.5):
            raise ValueError('S has a near-zero diagonal; it must be close to identity')
        self.thermal_std = None if thermal_std is None else np.asarray(thermal_std,
                                                                       float).reshape(3, 6)
        self._s_inv = np.linalg.inv(self.s)

    def temperature_degree(self):
        """Return 2, 1 or 0: the highest power of dT with a non-zero scale or bias term."""
        th = self.thermal
        return max(highest_power(th[:, [1, 2]].T), highest_power(th[:, [4, 5]].T))

    def scale_bias(self, temps):
        """Return (k, b), each (n, 3), at per-axis thermal inputs (n, 3) in ``input_unit``."""
        dt = np.asarray(temps, float) - self.t0
        th = self.thermal
        k = self.k0 + th[:, 0] + th[:, 1] * dt + th[:, 2] * dt * dt
        b = self.b0 + th[:, 3] + th[:, 4] * dt + th[:, 5] * dt * dt
        return k, b

    def correct(self, raw, temps, aux=None):
        """Return the specific force (n, 3) m/s^2 in the reference frame."""
        k, b = self.scale_bias(temps)
        return ((np.asarray(raw, float) - b) / k) @ self._s_inv.T

    def forward(self, true, temps, aux=None):
        """Return the raw output (n, 3) for a true specific force (n, 3)."""
        k, b = self.scale_bias(temps)
        return k * (np.asarray(true, float) @ self.s.T) + b

    def predict_std(self, temps):
        """Return the 1-sigma bias-equivalent uncertainty at 1 g (correlations ignored), m/s^2."""
        if self.thermal_std is None:
            return None
        dt = np.asarray(temps, float) - self.t0
        sd = self.thermal_std
        g = 9.80665
        var = ((sd[:, 0] * g) ** 2 + (sd[:, 1] * dt * g) ** 2 + (sd[:, 2] * dt * dt * g) ** 2
               + sd[:, 3] ** 2 + (sd[:, 4] * dt) ** 2 + (sd[:, 5] * dt * dt) ** 2)
        return np.sqrt(var)

    def params(self):
        """Return prior and thermal parameters with units and stds."""
        out = {'T0': Param(self.t0, self.input_unit,
                           description=reference_description(self.input_unit)),
               'k0': Param(self.k0, '1', description='prior (lab) scale factor at T0'),
               'b0': Param(self.b0, 'm/s^2', description='prior (lab) bias at T0'),
               'S': Param(self.s, '1', description='prior non-orthogonality, lower-triangular')}
        units = thermal_units(self.input_unit)
        for j, (name, unit, desc) in enumerate(zip(THERMAL_NAMES, units, THERMAL_DESC)):
            std = None if self.thermal_std is None else self.thermal_std[:, j]
            out[name] = Param(self.thermal[:, j], unit, std, desc)
        return out

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters."""
        w = cls.kind
        th = np.stack([require(params, n, (3,), w) for n in THERMAL_NAMES], axis=1)
        stds = [params[n].std for n in THERMAL_NAMES]
        std = None if any(s is None for s in stds) else np.stack(stds, axis=1)
        return cls(require(params, 'T0', (3,), w), th, require(params, 'k0', (3,), w),
                   require(params, 'b0', (3,), w), require(params, 'S', (3, 3), w), std,
                   input_unit=input_unit_of(params, meta))

    def meta(self):
        """Return the polynomial order (2 as in the paper)."""
        return with_input_unit({'order': 2, 'paper': 'seed 000, eqs. (3)-(5), (8)'},
                               self.input_unit)
