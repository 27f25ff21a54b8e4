"""One family's bias and scale terms for the drift alarms, whatever model compensates.

A registry's drift alarms (``fleet/alarms.py``) compare a unit's accelerometer bias and
scale factor at a common temperature between calibrations, in units of the fits' stds.
Those stds are honest for the seed 000 field model (on simulated fleets the stable units'
changes have z std 0.93 / 0.92) and not for the standard fit, whose scale factor has no
temperature terms (std 3-4; ``bench/fleet_family_switch.py``, docs/fleet.md). When
``auto`` (or ``--model``) gives a unit's calibrations different families, the changes
between them could not be tested. So every calibration of several orientations whose
accelerometer model is not the field model also gets the field model fitted to the same
holds, and its terms (``models.alarm_terms.bias_scale_terms``) are stored as
``fit.alarm_yardstick``: the alarms read them. The compensating model is not touched.

A yardstick that cannot be fitted (faces missing, no convergence, non-finite terms) is
recorded with the reason; the calibration's own terms are then used, as before. No ROS
import.
"""

import numpy as np

from ..models.alarm_terms import bias_scale_terms
from ..models.field import FieldPolynomialModel
from .builtin_estimators import estimate_field
from .options import CalibrationRefused

#: the family whose terms the alarms read (``ESTIMATORS`` name and model kind)
YARDSTICK_FAMILY = 'field'
YARDSTICK_KIND = FieldPolynomialModel.kind
#: the keys of ``bias_scale_terms`` stored (arrays as nested lists)
TERMS = ('T0', 'b', 'b_std', 'k', 'k_std')


def needed(name, n_orientations, accel):
    """Return True when a calibration by estimator ``name`` gets a yardstick.

    Several orientations, an accelerometer model, and not the field model itself.
    """
    return (accel is not None and n_orientations > 1 and name != YARDSTICK_FAMILY
            and getattr(accel, 'kind', None) != YARDSTICK_KIND)


def yardstick(ctx):
    """Return ``fit.alarm_yardstick``: the field model's terms on ``ctx``'s holds.

    {'family', 'kind', 'T0' (3,) degC, 'b' (3, 3) m/s^2 .. about T0, 'b_std', 'k' (3, 3)
    1, 'k_std', 'note'} as lists; or {'family', 'error', 'note'} when the field model
    cannot be fitted or has no terms.
    """
    note = ('the drift alarms of a registry read these terms (the field model fitted to '
            'the same holds), not the compensating model\'s, so that calibrations of '
            'different families stay comparable; they do not compensate anything')
    try:
        with np.errstate(all='ignore'):
            est = estimate_field(ctx)
            terms = bias_scale_terms(est.accel) if est.accel is not None else None
    except (CalibrationRefused, ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        return {'family': YARDSTICK_FAMILY, 'error': _reason(e), 'note': note}
    if terms is None or not all(np.all(np.isfinite(terms[k])) for k in TERMS):
        return {'family': YARDSTICK_FAMILY, 'error': 'the field model has no finite bias and '
                'scale terms with stds on these holds', 'note': note}
    out = {'family': YARDSTICK_FAMILY, 'kind': YARDSTICK_KIND}
    out.update({k: np.asarray(terms[k], float).tolist() for k in TERMS})
    out['note'] = note
    return out


def _reason(e):
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    return f'the field model cannot be fitted to these holds ({text[:300]})'


def terms_of(fit):
    """Return the stored yardstick as ``bias_scale_terms`` arrays, or None (none, failed)."""
    y = (fit or {}).get('alarm_yardstick')
    if not isinstance(y, dict) or 'error' in y:
        return None
    try:
        out = {k: np.asarray(y[k], float) for k in TERMS}
    except (KeyError, TypeError, ValueError):
        return None
    shapes = {'T0': (3,), 'b': (3, 3), 'b_std': (3, 3), 'k': (3, 3), 'k_std': (3, 3)}
    if any(out[k].shape != s for k, s in shapes.items()):
        return None
    out['kind'] = str(y.get('kind', YARDSTICK_KIND))
    return out
