"""Gyroscope calibration without a turntable: the static fit, then the rotations.

``fit_gyro`` runs ``gyro_static.fit_gyro_static`` (bias and g-sensitivity from
the holds) and, when pose changes were collected (``collection.motion``),
``gyro_rotations.fit_gyro_rotations`` (scale, misalignment, nonlinearity).
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..models.whole_unit import WholeUnitGyroModel
from .observability import CONVENTION, Priors

from .gyro_rotations import fit_gyro_rotations, RotationFit
from .gyro_transitions import prepare_transitions
from .gyro_static import fit_gyro_static, hold_directions, StaticGyroFit


# ------------------------------------------------------------------------ both
@dataclass
class GyroFit:
    """The whole-unit gyro model plus what was learnt on the way."""

    model: WholeUnitGyroModel
    static: StaticGyroFit
    rotation: Optional[RotationFit]
    notes: list
    stats: dict


def fit_gyro(windows, axis_inputs, acc, t0, latitude=None, transitions=None, accel_model=None,
             accel_input=(0, 0, 0), gyro_input=(0, 0, 0), priors=None, order=2,
             input_unit='degC', robust=True, first_static=None):
    """Fit the seed 002 gyro model: static bias/g-sensitivity, then rotations, then static again.

    windows, axis_inputs (m, 3) or None, acc (m, 3) corrected accel per window (m/s^2),
    t0 (3,) input reference; transitions from MotionCollector (None: no rotation part).
    ``first_static``: the first static fit (Omega1 = I) when the caller already has it for
    the same windows, inputs, priors and order (the static candidate of a fold), else None.
    """
    priors = priors or Priors()
    st = first_static or fit_gyro_static(windows, axis_inputs, acc, t0, latitude, None,
                                         priors, order, robust=robust)
    rot = None
    omega1, omega2, omega3 = np.eye(3), np.zeros(3), np.zeros(3)
    notes = list(st.notes)
    if transitions and accel_model is not None:
        up, sig = hold_directions(windows, acc)
        noise = np.sqrt(np.median(windows.gyro_var, axis=0))
        prep = prepare_transitions(transitions, up, sig, st, accel_model, accel_input,
                                   gyro_input, np.asarray(t0, float), noise)
        rot = fit_gyro_rotations(prep, priors, robust=robust)
        omega1, omega2, omega3 = rot.omega1, rot.omega2, rot.omega3
        notes += rot.notes
        if np.any(rot.estimated['Omega1']):
            st = fit_gyro_static(windows, axis_inputs, acc, t0, latitude, omega1, priors,
                                 order, robust=robust)
    else:
        rot = fit_gyro_rotations(prepare_transitions([], {}, {}, st, None, (), (), t0),
                                 priors)
        notes += rot.notes
    # raw-domain bias in cw0 (Omega0 = 0 by convention), C = -Omega1 G
    offset = st.offset.copy()
    offset[0] = st.beta
    c = -omega1 @ st.g
    std = dict(st.std)
    std['cw0'] = std.pop('beta')
    std['Omega0'] = np.zeros(3)
    std['C'] = std.pop('G')
    std.update(rot.std)
    est = dict(st.estimated)
    est['cw0'] = est.pop('beta')
    est['Omega0'] = np.zeros(3, bool)
    est['C'] = est.pop('G')
    est.update(rot.estimated)
    fixed = dict(st.fixed)
    fixed.pop('cw0', None)
    if 'beta' in fixed:
        fixed['cw0'] = fixed.pop('beta')
    if 'G' in fixed:
        fixed['C'] = fixed.pop('G')
    fixed['Omega0'] = (CONVENTION + ': Omega0 = 0, the bias is carried by cw0 (raw domain; '
                       'exactly redundant)')
    fixed.update(rot.fixed)
    model = WholeUnitGyroModel(t0, offset, None, np.zeros(3), omega1, omega2, omega3, c,
                               std=std, estimated=est, fixed=fixed, input_unit=input_unit,
                               convention='Omega1 full 3x3: gyro axes relative to the '
                                          'accelerometer frame')
    stats = {'gyro_static_residual_rms': {'value': st.residual_rms, 'unit': 'rad/s'},
             'gyro_outlier_holds': st.outlier_holds,
             'gyro_posterior_ratio': {**st.ratios, **(rot.ratios if rot else {})},
             'earth_rate_horizontal_fraction': st.horizontal_fraction,
             'rotations_used': rot.used if rot else 0}
    if rot is not None and rot.used:
        stats['rotation_direction_error_deg'] = {
            'before_rms': float(np.sqrt(np.mean(rot.error_before_deg ** 2))),
            'after_rms': float(np.sqrt(np.mean(rot.error_after_deg ** 2))),
            'note': 'angle between the gravity direction after a pose change and the one '
                    'before carried through the integrated gyro (prior vs fitted Omega1)'}
    return GyroFit(model, st, rot, notes, stats)
