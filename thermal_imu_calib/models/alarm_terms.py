"""Bias and scale factor of any accelerometer (or gyro) model near its reference temperature.

The drift alarms of a registry (``fleet/registry.py``) compare a unit's accelerometer bias
and scale factor at a common temperature between calibrations. The seed 000 field model
has them as parameters (db0, dk0 and their polynomial); the other families (the standard
fit and the seed 002 whole-unit model, the offset, hysteresis and RVM models of one
orientation) have them only implicitly. ``bias_scale_terms`` reads them off any model that
has a forward model, the same way for every family::

    b_i(T) = raw_i(f = 0, T)                                  m/s^2
    k_i(T) = (raw_i(+g e_i, T) - raw_i(-g e_i, T)) / (2 g)    1

at equilibrium (no thermal history), as a quadratic in dT = T - T0 (central differences
at T0 and T0 +- ``STEP``: exact for the polynomial families up to 2nd order). The 1-sigma
of each coefficient comes from moving each fitted parameter by its std, one at a time
(independent, as the registry treats the field model's stds). No ROS import.
"""

import dataclasses

import numpy as np

#: step of the central differences, in the model's input unit (degC)
STEP = 5.0
#: g used to probe the scale factor (m/s^2; any value in the sensor's range)
PROBE_G = 9.80665


def _at(model, t0, dt):
    """Return (bias (3,), scale (3,)) of ``model`` at per-axis inputs t0 + dt, equilibrium."""
    temps = np.tile(np.asarray(t0, float) + dt, (7, 1))
    probe = np.zeros((7, 3))
    for i in range(3):
        probe[1 + 2 * i, i] = PROBE_G
        probe[2 + 2 * i, i] = -PROBE_G
    # a g-sensitive gyro is probed at zero specific force (its bias alone); the
    # accelerometer models ignore ``aux``
    raw = model.forward(probe, temps, aux={'accel': np.zeros_like(probe)})
    bias = raw[0]
    scale = np.array([(raw[1 + 2 * i, i] - raw[2 + 2 * i, i]) / (2 * PROBE_G)
                      for i in range(3)])
    return bias, scale


def coefficients(model, t0):
    """Return (b (3, 3), k (3, 3)): columns the dT^0, dT^1, dT^2 coefficients per axis."""
    (b_m, k_m), (b_0, k_0), (b_p, k_p) = (_at(model, t0, d) for d in (-STEP, 0.0, STEP))

    def quad(lo, mid, hi):
        return np.stack([mid, (hi - lo) / (2 * STEP), (hi - 2 * mid + lo) / (2 * STEP ** 2)], 1)
    return quad(b_m, b_0, b_p), quad(k_m, k_0, k_p)


def reference_of(model):
    """Return the model's per-axis reference input (3,) (T0, X0 or T_ref), or None."""
    params = model.params()
    for name in ('T0', 'X0', 'T_ref', 't_ref'):
        p = params.get(name)
        if p is not None and np.asarray(p.value).shape == (3,):
            return np.asarray(p.value, float)
    return None


def relative_bias(model):
    """Return True when the model's bias is defined only relative to its reference input.

    The offset models of one orientation without their constant (``include_constant``
    False; an RVM with ``offset_only``) remove the drift relative to T0, T_ref: their bias
    at T0 is 0 by construction, not a measured value, so two of them with different T0
    differ by the drift between the two T0 whatever the sensor did.
    """
    return bool(getattr(model, 'offset_only', False)
                or getattr(model, 'include_constant', True) is False)


def bias_scale_terms(model):
    """Return {'T0', 'b', 'b_std', 'k', 'k_std'} of an accelerometer model, or None.

    ``b``/``k`` (3, 3): per axis (rows) the coefficients of dT^0..2 of the bias (m/s^2)
    and the scale factor (1) about ``T0`` (3,). None when the model has no forward model,
    no reference input or no parameter stds. A bias defined only relative to T0
    (``relative_bias``) has its constant NaN (std NaN): it is not a measurement to test.
    """
    t0 = reference_of(model)
    if t0 is None:
        return None
    params = model.params()
    fitted = {n: p for n, p in params.items() if p.std is not None}
    if not fitted:
        return None
    try:
        b, k = coefficients(model, t0)
    except (NotImplementedError, ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(b)) or not np.all(np.isfinite(k)):
        return None
    var_b, var_k = np.zeros_like(b), np.zeros_like(k)
    meta = model.meta()
    for name, p in fitted.items():
        value, std = np.asarray(p.value, float), np.asarray(p.std, float)
        for idx in zip(*np.nonzero(np.isfinite(std) & (std > 0))):
            v = value.copy()
            v[idx] += std[idx]
            moved = dict(params, **{name: dataclasses.replace(p, value=v)})
            try:
                db, dk = coefficients(type(model).from_params(moved, meta), t0)
            except (NotImplementedError, ValueError, np.linalg.LinAlgError):
                return None
            var_b += (db - b) ** 2
            var_k += (dk - k) ** 2
    b_std = np.sqrt(var_b)
    if relative_bias(model):
        b[:, 0] = b_std[:, 0] = np.nan
    return {'T0': t0, 'b': b, 'b_std': b_std, 'k': k, 'k_std': np.sqrt(var_k)}
