"""Plausibility: refuse a calibration no real IMU has, or one that breaks in its valid range.

The schema (``schema.py``) says a file is well formed; these checks say its numbers can be
used: parameters within what any IMU has (a corrupt or mis-united file), no thermal terms
without a thermal input, and an output that stays finite and sane everywhere in the valid
range (a coefficient such as k2 = 1e300 erases the output at the range edges only).
"""

import numpy as np

from ..input_units import is_temperature, TEMPERATURE_BOUNDS
from .base import out_unit


def check_thermal_without_inputs(cal):
    """Refuse a model that changes with temperature in a calibration with no thermal input.

    With ``temperature.inputs: []`` every model is evaluated at its reference value
    (``axis_temperatures``), so thermal terms would silently do nothing: the output would
    be the same at 22 and 34 degC. Probed per model at T0 and T0 +- 10 (input units).
    """
    if cal.inputs:
        return
    for name in ('accel', 'gyro'):
        model = getattr(cal, name)
        if model is None:
            continue
        t0 = np.broadcast_to(np.asarray(getattr(model, 't0', np.zeros(3)), float), (3,))
        raw = np.vstack([np.eye(3), -np.eye(3)]) * (cal.gravity if name == 'accel' else 1.0)
        temps = [np.tile(t0 + dt, (6, 1)) for dt in (0.0, -10.0, 10.0)]
        with np.errstate(all='ignore'):
            aux = {'accel': raw}
            out = [np.asarray(model.correct(raw, t, aux=aux), float) for t in temps]
        scale = np.max(np.abs(out[0])) or 1.0
        if any(not np.allclose(o, out[0], rtol=0, atol=1e-12 * scale) for o in out[1:]):
            raise ValueError(f'the {name} model has thermal terms but there is no temperature '
                             'input: it would run at its reference temperature whatever the '
                             'real one; add the input(s) it was fitted on (inputs, '
                             'valid_range) or refit without thermal terms')


def check_output(cal):
    """Refuse a model whose output is unusable anywhere in its valid input range.

    Each axis sees +-g (accel) and +-1 rad/s (gyro) at 17 points spanning the valid range
    of every input; the corrected output must be finite with a scale factor 0.25..4 and a
    bias below 100 m/s^2 / 10 rad/s (a corrupt coefficient such as k2 = 1e300 erases the
    output at the range edges while the mid-range looks fine).
    """
    if cal.inputs:
        f = np.linspace(0.0, 1.0, 17)[:, None]
        lo, hi = cal.valid_range[:, 0], cal.valid_range[:, 1]
        grid = lo + f * (hi - lo)
    else:
        grid = np.zeros((1, 0))
    m = grid.shape[0]
    eye = np.vstack([np.eye(3), -np.eye(3)])               # +x +y +z -x -y -z
    temps = np.repeat(grid, 6, axis=0)
    accel = np.tile(eye * cal.gravity, (m, 1))
    gyro = np.tile(eye * 1.0, (m, 1))
    with np.errstate(all='ignore'):
        res = cal.apply(accel, gyro, temps)
        for name, out, amp, bias_lim, std in (
                ('accel', res.accel, cal.gravity, 100.0, res.accel_std),
                ('gyro', res.gyro, 1.0, 10.0, res.gyro_std)):
            if getattr(cal, name) is None:
                continue
            out = np.asarray(out, float).reshape(m, 6, 3)
            if not np.all(np.isfinite(out)):
                raise ValueError(f'the {name} model gives NaN/Inf inside the valid range')
            if std is not None and not np.all(np.isfinite(std)):
                raise ValueError(f'the {name} model\'s uncertainty is NaN/Inf inside the '
                                 'valid range')
            scale = (out[:, :3] - out[:, 3:]) / (2 * amp)      # (m, axis, component)
            diag = np.abs(np.einsum('mii->mi', scale))
            bias = np.abs(out[:, :3] + out[:, 3:]) / 2
            if np.any(diag < 0.25) or np.any(diag > 4.0) or np.any(bias > bias_lim):
                j = int(np.argmax(np.any((diag < 0.25) | (diag > 4.0), 1)
                                  | np.any(bias > bias_lim, (1, 2))))
                at = grid[j].round(3).tolist() if cal.inputs else 'any input'
                raise ValueError(
                    f'the {name} model is implausible inside the valid range: at input '
                    f'{at} its scale factor is {diag[j].tolist()} (expected 0.25..4) and its '
                    f'bias up to {float(bias[j].max()):.3g} {out_unit(name)}; a coefficient '
                    'is corrupt (e.g. a huge k2): recalibrate or restore the file')


def check_bounds(name, model):
    """Refuse parameters no real IMU has (a corrupt or mis-united file)."""
    p = {k: v.value for k, v in model.params().items()}
    if 'k0' in p:
        k = p['k0'] + p.get('dk0', 0)
        if np.any(np.abs(k - 1) > 0.5):
            raise ValueError(f'{name}.parameters.k0: scale factor {k.tolist()} is not within '
                             '0.5..1.5; '
                             'the file is corrupt or not in SI units')
    lim = 50.0 if model.sensor == 'accel' else 5.0
    for key in ('b0', 'db0', 'c0'):
        if key in p and np.any(np.abs(p[key]) > lim):
            raise ValueError(f'{name}.parameters.{key} = {p[key].tolist()} exceeds {lim} '
                             f'{model.unit}; '
                             'the file is corrupt or not in SI units')
    unit = model.input_unit
    if is_temperature(unit) and 'T0' in p and np.any((p['T0'] < TEMPERATURE_BOUNDS[0])
                                                     | (p['T0'] > TEMPERATURE_BOUNDS[1])):
        raise ValueError(f'{name}.parameters.T0 = {p["T0"].tolist()} degC is implausible (outside '
                         f'{TEMPERATURE_BOUNDS[0]}..{TEMPERATURE_BOUNDS[1]} degC; Kelvin or '
                         'Fahrenheit by mistake?)')
