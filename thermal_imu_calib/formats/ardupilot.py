"""ArduPilot IMU temperature calibration (``INS_TCALn_*``) as a .parm file (``NAME,VALUE``).

ArduPilot (``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``,
``TCal::polynomial_eval`` and ``TCal::correct_sensor``) corrects per axis::

    T  = clamp(T, TMIN, TMAX);  Tc = clamp(CALTEMP, TMIN, TMAX)
    P(t) = (c1 + (c2 + c3 t) t) t * 1e-6,   t = T - 35 degC  (TEMP_REFERENCE)
    v -= P(T - 35) - P(Tc - 35)

with c_k = ``INS_TCALn_ACC{k}_{X,Y,Z}`` / ``GYR{k}`` (stored x1e6, no constant term) and
CALTEMP = ``INS_ACCn_CALTEMP`` / ``INS_GYRn_CALTEMP``, the temperature the static offsets
(``INS_ACCOFFS``, the boot-time gyro offsets) were taken at. So only the drift relative to
CALTEMP is thermal; the constant and the scale factors are ArduPilot's own static
calibration. An ``offset_polynomial`` of order <= 3 on one degC input is written exactly
(re-expanded about 35 degC, CALTEMP = its T0); other models are refitted as the closest
cubic and the loss is reported.
"""

import numpy as np
from numpy.polynomial import Polynomial

from ..calibration import Calibration, spanning_range, TemperatureInput
from ..models.polynomial import OffsetPolynomialModel
from .common import (ageing_note, check_out, cubic_offset, exact_loss, Exported, ExportRefused,
                     history_note, lag_note, num, offset_refit, parse_params, single_input,
                     summarize_loss)

TEMP_REFERENCE = 35.0
SCALE = 1e6
STEM = {'accel': 'ACC', 'gyro': 'GYR'}
CALTEMP = {'accel': 'INS_ACC{n}_CALTEMP', 'gyro': 'INS_GYR{n}_CALTEMP'}


def reexpand(coeffs, from_ref, to_ref):
    """Return coefficients (rows per power, 3 axes) of the same polynomials about ``to_ref``."""
    coeffs = np.asarray(coeffs, float)
    out = np.zeros_like(coeffs)
    shift = Polynomial([to_ref - from_ref, 1.0])   # x_from = x_to + (to_ref - from_ref)
    for a in range(coeffs.shape[1]):
        c = Polynomial(coeffs[:, a])(shift).coef
        out[:len(c), a] = c[:coeffs.shape[0]]
    return out


def _snap(c, span):
    """Zero the coefficients whose term stays below 1e-12 (SI) over +-span (rounding noise)."""
    c = np.array(c, float)
    terms = np.abs(c) * span ** np.arange(c.shape[0])[:, None]
    c[terms < 1e-12] = 0.0
    return c


def sensor_params(cal, which, smp, imu=1):
    """Return (rows [(name, value)], TMIN, TMAX, notes, loss) for 'accel' or 'gyro'."""
    i = single_input(cal, which, 'ArduPilot')
    lo, hi = (float(v) for v in cal.own_range(which)[i])
    model = cal.accel if which == 'accel' else cal.gyro
    notes = [n for n in [check_out(cal, which, 'ArduPilot')] if n]
    ex = cubic_offset(cal, which)
    if ex is not None:
        tcal = ex[0]
        c = reexpand(ex[1], tcal, TEMP_REFERENCE)
        loss = exact_loss(which)
        if not lo <= tcal <= hi:
            notes.append(f'{which}: T0 {tcal:g} degC is outside TMIN..TMAX, where ArduPilot '
                         'clamps CALTEMP: exact up to a constant, which its own offsets hold')
        if model.include_constant and np.any(model.coeffs[0]):
            notes.append(f'{which}: the constant offset c0 at T0 is not thermal; ArduPilot\'s '
                         'own offsets (taken at CALTEMP) hold it')
    else:
        tcal = float(np.clip(np.mean(model.t0), lo, hi))
        sc = tcal - TEMP_REFERENCE

        def design(t):
            s = t - TEMP_REFERENCE
            return np.stack([np.ones_like(s)] + [s ** j - sc ** j for j in (1, 2, 3)], 1)
        c, lin, resid = offset_refit(cal, which, smp, design, 'ArduPilot')
        c[0] = 0.0
        notes.append(f'{which}: {model.kind} is not a cubic offset; refitted relative to '
                     f'CALTEMP {tcal:g} degC')
        if not np.allclose(lin, np.eye(3), atol=1e-12):
            notes.append(f'{which}: the scale factor and non-orthogonality at T0 are not '
                         'thermal; ArduPilot\'s own accelerometer calibration must hold them')
        loss = summarize_loss(which, resid, f'cubic refit of {model.kind} on {smp.what}')
    c = _snap(c, max(abs(lo - TEMP_REFERENCE), abs(hi - TEMP_REFERENCE), 1.0))
    rows = [(f'INS_TCAL{imu}_{STEM[which]}{k}_{"XYZ"[a]}', c[k, a] * SCALE)
            for k in (1, 2, 3) for a in range(3)]
    rows.append((CALTEMP[which].format(n=imu), tcal))
    return rows, lo, hi, notes, loss


def export(cal, smp, imu=1, header=''):
    """Return ``Exported`` with one .parm file."""
    if not 1 <= imu <= 3:
        raise ExportRefused(f'ArduPilot has INS_TCAL1..3, not {imu}')
    rows, loss, ranges = [], {}, {}
    notes = (lag_note(cal, 'ArduPilot') + history_note(cal, 'ArduPilot')
             + ageing_note(cal, 'ArduPilot'))
    for which in ('accel', 'gyro'):
        if getattr(cal, which) is None:
            continue
        r, lo, hi, n, ls = sensor_params(cal, which, smp, imu)
        rows += r
        notes += n
        loss[which] = ls
        ranges[which] = np.array([[lo, hi]])
    inputs = {single_input(cal, w, 'ArduPilot') for w in ranges}
    if len(inputs) > 1:
        raise ExportRefused('ArduPilot has one TMIN/TMAX per IMU; the accel and gyro of this '
                            'calibration use inputs with different valid ranges')
    valid, own = spanning_range(ranges)
    lo, hi = (float(v) for v in valid[0])
    for which, ((a, z),) in own.items():    # a sensor's own, narrower range
        notes.append(f'{which}: this calibration holds it at its own range {a:.2f}..'
                     f'{z:.2f} degC; ArduPilot has one TMIN..TMAX per IMU ({lo:.2f}..'
                     f'{hi:.2f}) and continues its polynomial up to '
                     f'{max(a - lo, hi - z):.2f} degC beyond')
    if hi - lo < 10.0:
        notes.append(f'the valid range {lo:.1f}..{hi:.1f} degC is narrower than the 10 degC '
                     'ArduPilot\'s own learning requires; it applies the file anyway')
    head = [(f'INS_TCAL{imu}_ENABLE', 1), (f'INS_TCAL{imu}_TMIN', lo),
            (f'INS_TCAL{imu}_TMAX', hi)]
    lines = [f'# {t}' for t in header.splitlines()]
    for name, value in head + rows:
        lines.append(f'{name},{int(value) if name.endswith("ENABLE") else num(value, 10)}')
    return Exported({'': '\n'.join(lines) + '\n'}, notes, loss)


def parse(text):
    """Return {name: float} of a .parm file (``NAME,VALUE`` or ``NAME VALUE`` lines)."""
    return parse_params(text, lambda line: line.replace(',', ' ').split(), 0, 1, 'NAME,VALUE')


def read(text, source='ArduPilot parameters'):
    """Return the Calibration an ArduPilot .parm file holds (drift relative to CALTEMP)."""
    p = parse(text)
    imus = [n for n in (1, 2, 3) if int(p.get(f'INS_TCAL{n}_ENABLE', 0)) == 1]
    if not imus:
        raise ValueError(f'{source}: no INS_TCALn_ENABLE is 1; no temperature calibration '
                         'to import')
    n = imus[0]
    lo, hi = p[f'INS_TCAL{n}_TMIN'], p[f'INS_TCAL{n}_TMAX']
    models = {}
    for which, stem in STEM.items():
        c = np.zeros((4, 3))
        for k in (1, 2, 3):
            for a in range(3):
                c[k, a] = p.get(f'INS_TCAL{n}_{stem}{k}_{"XYZ"[a]}', 0.0) / SCALE
        tcal = p.get(CALTEMP[which].format(n=n))
        if tcal is None or tcal < -100:
            raise ValueError(f'{source}: {CALTEMP[which].format(n=n)} is not set; the '
                             'correction is relative to it (calibrate the '
                             f'{"accelerometers" if which == "accel" else "gyros"} first)')
        tc = float(np.clip(tcal, lo, hi))
        about = reexpand(c, TEMP_REFERENCE, tc)
        about[0] = 0.0
        models[which] = OffsetPolynomialModel(np.full(3, tc), about, sensor=which,
                                              include_constant=False)
    return Calibration(accel=models['accel'], gyro=models['gyro'],
                       inputs=[TemperatureInput('t0', 'imu/temperature')],
                       valid_range=np.array([[lo, hi]]),
                       fit={'imported': {'format': 'ardupilot', 'source': source}},
                       notes=[f'imported from ArduPilot INS_TCAL{n} ({source})'])
