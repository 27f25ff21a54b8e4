"""PX4 thermal compensation parameters (``TC_A*``/``TC_G*``) as a QGroundControl .params file.

PX4 (``src/modules/temperature_compensation/TemperatureCompensation.cpp``,
``calc_thermal_offsets_3D``; parameters in ``temp_comp_params_accel.c``/``_gyro.c``)
computes per axis i::

    dT = clamp(T, TMIN, TMAX) - TREF
    offset_i = X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3

and *subtracts* it from the sensor-frame output before its own static calibration
(``CAL_ACCn_*``/``CAL_GYROn_*``: offset, per-axis scale, board rotation). An
``offset_polynomial`` calibration of order <= 3 on one degC input is written exactly. Any
other model (scale-factor temperature terms, non-orthogonality, an RVM) is refitted as the
cubic offset that best matches it on the calibration's windows (or a grid over its valid
range and the six faces); what is lost is reported.

The .params file is QGroundControl's: ``# Vehicle-Id Component-Id Name Value Type`` with
tab-separated columns, type 6 = MAV_PARAM_TYPE_INT32, 9 = MAV_PARAM_TYPE_REAL32.
"""

import numpy as np

from ..calibration import Calibration, spanning_range, TemperatureInput
from ..models.polynomial import OffsetPolynomialModel
from .common import (ageing_note, check_out, cubic_offset, exact_loss, Exported, ExportRefused,
                     history_note, lag_note, num, offset_refit, parse_params, single_input,
                     summarize_loss)

INT32, REAL32 = 6, 9
PREFIX = {'accel': 'TC_A', 'gyro': 'TC_G'}


def _design(tref):
    return lambda t: np.stack([(t - tref) ** j for j in range(4)], 1)


def sensor_params(cal, which, smp, instance=0, device_id=0):
    """Return (rows [(name, value, type)], notes, loss) for 'accel' or 'gyro'."""
    i = single_input(cal, which, 'PX4')
    lo, hi = (float(v) for v in cal.own_range(which)[i])
    notes = [n for n in [check_out(cal, which, 'PX4')] if n]
    ex = cubic_offset(cal, which)
    if ex is not None:
        tref, x = ex
        loss = exact_loss(which)
    else:
        model = cal.accel if which == 'accel' else cal.gyro
        tref = round(0.5 * (lo + hi), 2)
        x, lin, resid = offset_refit(cal, which, smp, _design(tref), 'PX4')
        what = f'cubic offset refit of {model.kind} on {smp.what}'
        notes.append(f'{which}: {model.kind} is not a cubic offset; refitted (TREF {tref:g} '
                     'degC, the middle of the valid range as PX4 does)')
        if not np.allclose(lin, np.eye(3), atol=1e-12):
            notes.append(f'{which}: the scale factor and non-orthogonality at T0 are not '
                         'thermal; PX4\'s own static calibration (CAL_ACCn/CAL_GYROn) must '
                         'hold them')
        loss = summarize_loss(which, resid, what)
    p = f'{PREFIX[which]}{instance}'
    rows = [(f'{p}_ID', int(device_id), INT32), (f'{p}_TREF', tref, REAL32),
            (f'{p}_TMIN', lo, REAL32), (f'{p}_TMAX', hi, REAL32)]
    for j in range(4):
        for a in range(3):
            rows.append((f'{p}_X{j}_{a}', float(x[j, a]), REAL32))
    return rows, notes, loss


def export(cal, smp, instance=0, accel_id=0, gyro_id=0, header=''):
    """Return ``Exported`` with one .params file (TC_A_ENABLE, TC_G_ENABLE and the rows)."""
    if not 0 <= instance <= 3:
        raise ExportRefused(f'PX4 has thermal compensation instances 0..3, not {instance}')
    rows, loss = [], {}
    notes = lag_note(cal, 'PX4') + history_note(cal, 'PX4') + ageing_note(cal, 'PX4')
    for which, dev in (('accel', accel_id), ('gyro', gyro_id)):
        if getattr(cal, which) is None:
            continue
        r, n, lo = sensor_params(cal, which, smp, instance, dev)
        rows += [(f'{PREFIX[which]}_ENABLE', 1, INT32)] + r
        notes += n
        loss[which] = lo
        if not dev:
            notes.append(f'{PREFIX[which]}{instance}_ID is 0: set it to the device id of the '
                         f'{which} (CAL_{"ACC" if which == "accel" else "GYRO"}0_ID) or PX4 '
                         'will not apply it')
    lines = ['# Onboard parameters for Vehicle 1', '#']
    lines += [f'# {t}' for t in header.splitlines()]
    lines += ['#', '# Vehicle-Id Component-Id Name Value Type']
    for name, value, typ in rows:
        v = str(int(value)) if typ == INT32 else num(value, 10)
        lines.append(f'1\t1\t{name}\t{v}\t{typ}')
    return Exported({'': '\n'.join(lines) + '\n'}, notes, loss)


def parse(text):
    """Return {name: float} of a QGroundControl .params file (comments skipped)."""
    return parse_params(text, lambda line: line.split('\t') if '\t' in line else line.split(),
                        2, 3, '"vehicle component name value type"')


def read(text, source='PX4 parameters'):
    """Return the Calibration a PX4 .params file holds (offset_polynomial, order 3)."""
    p = parse(text)
    models, ranges = {}, {}
    for which, pre in PREFIX.items():
        if int(p.get(f'{pre}_ENABLE', 0)) != 1:
            continue
        inst = [i for i in range(4) if f'{pre}{i}_TREF' in p]
        if not inst:
            raise ValueError(f'{source}: {pre}_ENABLE is 1 but no {pre}n_TREF is set')
        q = f'{pre}{inst[0]}'
        x = np.array([[p.get(f'{q}_X{j}_{a}', 0.0) for a in range(3)] for j in range(4)])
        models[which] = OffsetPolynomialModel(np.full(3, p[f'{q}_TREF']), x, sensor=which)
        ranges[which] = np.array([[p[f'{q}_TMIN'], p[f'{q}_TMAX']]])
    if not models:
        raise ValueError(f'{source}: neither TC_A_ENABLE nor TC_G_ENABLE is 1; no thermal '
                         'compensation to import')
    # a sensor with a narrower TMIN..TMAX keeps it as its own range (Calibration.own_range)
    valid, own = spanning_range(ranges)
    return Calibration(accel=models.get('accel'), gyro=models.get('gyro'),
                       inputs=[TemperatureInput('t0', 'imu/temperature')],
                       valid_range=valid, sensor_range=own,
                       fit={'imported': {'format': 'px4', 'source': source}},
                       notes=[f'imported from PX4 thermal compensation parameters ({source})'])
