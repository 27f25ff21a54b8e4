"""imucal (Ferraris) calibration JSON.

imucal (``imucal/ferraris_calibration_info.py``, ``FerrarisCalibrationInfo``) applies::

    acc = R_a^-1 K_a^-1 (acc_raw - b_a)
    gyr = R_g^-1 K_g^-1 (gyr_raw - K_ga acc - b_g)        (acc: the calibrated accel)

and stores K_a, R_a, b_a, K_g, R_g, K_ga, b_g with ``acc_unit``, ``gyr_unit``,
``from_acc_unit``, ``from_gyr_unit``, ``comment`` and ``cal_type`` "Ferraris" in JSON
(``CalibrationInfo.to_json``). K is diagonal and R has a unit diagonal (imucal's own
results have unit rows; the formula is the same). We export SI in and out (m/s^2,
rad/s). imucal has no temperature: the model is evaluated at T0 (or ``--temperature``)
and the loss over the valid range is reported.
"""

import json

import numpy as np

from ..calibration import Calibration
from ..models.whole_unit import WholeUnitAccelModel, WholeUnitGyroModel
from .common import affine_map, ageing_note, Exported, rounded, summarize_loss
from .imu_tk import DIGITS, STATIC_T0

SI = {'acc': 'm/s^2', 'gyr': 'rad/s'}


def _split(m):
    """Return (K diagonal, R with a unit diagonal) with M = R^-1 K^-1.

    imucal's own fits give R unit rows; its formula takes any R. A unit diagonal (as
    imu_tk's T) survives rounding exactly, so export -> import -> export is identical.
    """
    kr = np.linalg.inv(m)
    k = np.diag(kr).copy()
    return np.diag(k), kr / k[:, None]


def export(cal, smp, temperature=None):
    """Return ``Exported`` with one JSON file."""
    if cal.accel is None or cal.gyro is None:
        raise ValueError('imucal holds an accelerometer and a gyro calibration together; this '
                         'calibration lacks one of them')
    notes, loss, mats = ageing_note(cal, 'imucal'), {}, {}
    for which in ('accel', 'gyro'):
        model = getattr(cal, which)
        t = np.full(3, temperature) if temperature is not None else model.t0
        m, b, c, dropped = affine_map(model, t, which)
        mats[which] = (m, b, c)
        if dropped:
            notes.append(f'{which}: {dropped}')
    ma, ba, _ = mats['accel']
    mg, bg, cg = mats['gyro']
    ka, ra = _split(ma)
    kg, rg = _split(mg)
    kga = -np.linalg.solve(mg, cg)
    acc = (smp.accel_raw - ba) @ ma.T
    gyr = (smp.gyro_raw - acc @ kga.T - bg) @ mg.T
    for which, theirs, ours in (('accel', acc, smp.accel_ours), ('gyro', gyr, smp.gyro_ours)):
        model = getattr(cal, which)
        t = temperature if temperature is not None else float(np.mean(model.t0))
        at = f'at {t:.2f} degC' if cal.inputs else '(no temperature)'
        loss[which] = summarize_loss(which, theirs - ours, f'static {at} vs ours on {smp.what}')
    d = {'acc_unit': SI['acc'], 'gyr_unit': SI['gyr'], 'from_acc_unit': SI['acc'],
         'from_gyr_unit': SI['gyr'], 'comment': 'thermal_imu_calib export',
         **{k: rounded(v, DIGITS).tolist() for k, v in (
             ('K_a', ka), ('R_a', ra), ('b_a', ba), ('K_g', kg), ('R_g', rg), ('K_ga', kga),
             ('b_g', bg))},
         'cal_type': 'Ferraris'}
    return Exported({'': json.dumps(d, indent=4) + '\n'}, notes, loss)


def parse(text, source='imucal JSON'):
    """Return the imucal dict with numpy arrays; raises ValueError naming what is missing."""
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f'{source}: not JSON ({e.msg}, line {e.lineno})') from None
    if not isinstance(d, dict) or d.get('cal_type') != 'Ferraris':
        raise ValueError(f'{source}: not an imucal Ferraris calibration (cal_type '
                         f'{d.get("cal_type") if isinstance(d, dict) else None!r})')
    out = dict(d)
    for key, shape in (('K_a', (3, 3)), ('R_a', (3, 3)), ('b_a', (3,)), ('K_g', (3, 3)),
                       ('R_g', (3, 3)), ('K_ga', (3, 3)), ('b_g', (3,))):
        if key not in d:
            raise ValueError(f'{source}: missing {key}')
        out[key] = np.asarray(d[key], float).reshape(shape)
    return out


def read(text, source='imucal JSON'):
    """Return the Calibration an imucal JSON holds (seed 002 whole-unit, no temperature).

    Refuses a calibration whose raw units are not SI (imucal's own examples map raw counts,
    ``a.u.``, to m/s^2 and deg/s): sensor_msgs/Imu is already in m/s^2 and rad/s.
    """
    d = parse(text, source)
    for key, want in (('from_acc_unit', SI['acc']), ('from_gyr_unit', SI['gyr']),
                      ('acc_unit', SI['acc'])):
        if str(d.get(key)) != want:
            raise ValueError(f'{source}: {key} is {d.get(key)!r}; this package reads '
                             f'sensor_msgs/Imu in m/s^2 and rad/s, so the calibration must map '
                             f'{want} to {want} (re-run imucal on data in SI units)')
    gscale = {'rad/s': 1.0, 'deg/s': np.pi / 180.0}.get(str(d.get('gyr_unit')))
    if gscale is None:
        raise ValueError(f'{source}: gyr_unit {d.get("gyr_unit")!r} is not rad/s or deg/s')
    ma = np.linalg.inv(d['R_a']) @ np.linalg.inv(d['K_a'])
    mg = gscale * np.linalg.inv(d['R_g']) @ np.linalg.inv(d['K_g'])
    accel = WholeUnitAccelModel(np.full(3, STATIC_T0), d['b_a'].reshape(1, 3), m1=ma,
                                convention='imported from imucal (Ferraris)')
    gyro = WholeUnitGyroModel(np.full(3, STATIC_T0), d['b_g'].reshape(1, 3), m1=mg,
                              coupling=-mg @ d['K_ga'],
                              convention='imported from imucal (Ferraris)')
    return Calibration(accel=accel, gyro=gyro,
                       fit={'imported': {'format': 'imucal', 'source': source}},
                       notes=[f'imported from imucal ({source}); no temperature terms'])
