"""imu_tk calibration files: one text file per triad, for X' = T K (X - B).

imu_tk (``include/imu_tk/calibration.h``, ``CalibratedTriad_::unbiasNormalize``,
``save``/``load``) writes the misalignment matrix T (3x3), a blank line, the scale matrix
K (3x3, diagonal), a blank line and the bias B (3x1), space separated, and applies
``X' = T*K*(X - B)``. Its test program names them ``<name>_acc.calib`` and
``<name>_gyro.calib``; we do the same.

imu_tk has no temperature: our model is evaluated at one temperature (its T0, or
``--temperature``) and what that loses over the valid range is reported. T keeps a unit
diagonal (as imu_tk's), K the per-axis scale. imu_tk has no gyro g-sensitivity: a
``whole_unit`` gyro's C is dropped and its size reported.
"""

import numpy as np

from ..calibration import Calibration
from ..models.whole_unit import WholeUnitAccelModel, WholeUnitGyroModel
from .common import (affine_map, ageing_note, Exported, ExportRefused, num, rounded,
                     summarize_loss)

#: significant digits written (round trips stay identical; 1e-12 is far below 1 ug)
DIGITS = 12
SUFFIX = {'accel': '_acc.calib', 'gyro': '_gyro.calib'}
#: reference temperature given to imported static calibrations, degC (no temperature there)
STATIC_T0 = 25.0


def triad_text(m, b):
    """Return the imu_tk text of M = T K and bias B (T with a unit diagonal)."""
    k = np.diag(np.diag(m))
    t = m @ np.diag(1.0 / np.diag(m))
    t, k, b = rounded(t, DIGITS), rounded(k, DIGITS), rounded(b, DIGITS)

    def mat(x):
        return '\n'.join(' '.join(num(v, DIGITS) for v in row) for row in x)
    return f'{mat(t)}\n\n{mat(k)}\n\n' + '\n'.join(num(v, DIGITS) for v in b) + '\n'


def parse_triad(text, source='imu_tk file'):
    """Return (T, K, B) of an imu_tk triad file (21 numbers)."""
    try:
        v = np.array([float(x) for x in text.split()])
    except ValueError:
        raise ValueError(f'{source}: not an imu_tk calibration (numbers only)') from None
    if v.size != 21:
        raise ValueError(f'{source}: an imu_tk calibration has 21 numbers (T 3x3, K 3x3, '
                         f'B 3x1), this file has {v.size}')
    return v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:]


def export(cal, smp, temperature=None):
    """Return ``Exported``: {'_acc.calib': text, '_gyro.calib': text} for the models present."""
    files, notes, loss = {}, ageing_note(cal, 'imu_tk'), {}
    for which in ('accel', 'gyro'):
        model = getattr(cal, which)
        if model is None:
            continue
        t = np.full(3, temperature) if temperature is not None else model.t0
        m, b, c, dropped = affine_map(model, t, which)
        if np.linalg.cond(m) > 1e6 or np.any(np.abs(np.diag(m)) < 1e-6):
            raise ExportRefused(f'the {which} matrix has a near-zero diagonal; it cannot be '
                                'split into imu_tk\'s unit-diagonal T and diagonal K')
        files[SUFFIX[which]] = triad_text(m, b)
        if dropped:
            notes.append(f'{which}: {dropped}')
        if np.any(c):
            notes.append(f'gyro: imu_tk has no g-sensitivity; C (up to '
                         f'{np.abs(c).max() * cal.gravity * 180 / np.pi * 3600:.3g} deg/h at '
                         '1 g) is dropped')
        raw = smp.accel_raw if which == 'accel' else smp.gyro_raw
        ours = smp.accel_ours if which == 'accel' else smp.gyro_ours
        theirs = (raw - b) @ m.T
        at = f'at {np.mean(t):.2f} degC' if cal.inputs else '(no temperature)'
        loss[which] = summarize_loss(which, theirs - ours, f'static {at} vs ours on {smp.what}')
    return Exported(files, notes, loss)


def read(texts, source='imu_tk files'):
    """Return the Calibration of imu_tk triads ({'accel': text, 'gyro': text}, either optional).

    Each becomes a seed 002 whole-unit model without temperature terms (A1 = T K, ct0 = B),
    which is exactly imu_tk's correction; the reference temperature is ``STATIC_T0``.
    """
    models = {}
    for which, text in texts.items():
        t, k, b = parse_triad(text, f'{source} ({which})')
        cls = WholeUnitAccelModel if which == 'accel' else WholeUnitGyroModel
        models[which] = cls(np.full(3, STATIC_T0), b.reshape(1, 3), m1=t @ k,
                            convention='imported from imu_tk: X\' = T K (X - B)')
    if not models:
        raise ValueError(f'{source}: no triad file given')
    return Calibration(accel=models.get('accel'), gyro=models.get('gyro'),
                       fit={'imported': {'format': 'imu_tk', 'source': source}},
                       notes=[f'imported from imu_tk ({source}); no temperature terms'])
