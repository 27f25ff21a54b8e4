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

Without a prior (a lab S) the field model takes the non-orthogonality S = identity, and
its cross-axis terms then move the scale factors and biases with each log's poses: with a
consumer datasheet's cross-axis sensitivity the stable units' changes had z std up to 10
(``bench/alarm_truth_z.py``, docs/fleet.md). So without a prior the yardstick estimates S
with the terms (``field_estimator.fit_field_model(free_s=True)``: unit diagonal, a zero-
mean +-2 % prior per term), for the field model too, and is family ``FREE_S_KIND``: its
terms are compared only with other such yardsticks. With a prior, S is the prior's and
a field calibration's own terms serve, as before.

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
#: the family name of a yardstick that estimated S (no prior): its terms are compared only
#: with others of the same kind, not with S = identity ones (registries written before it)
FREE_S_KIND = YARDSTICK_KIND + '+S'
#: the keys of ``bias_scale_terms`` stored (arrays as nested lists)
TERMS = ('T0', 'b', 'b_std', 'k', 'k_std')
#: why the yardstick estimates S when no prior gives it
FREE_S_WHY = ('without a prior the non-orthogonality S is estimated with them: with S = '
              'identity its cross-axis terms move the scale factors and biases with the '
              'poses of each log (simulated stable units with a datasheet\'s cross-axis '
              'sensitivity: change z std up to 10, bench/alarm_truth_z.py)')


def needed(name, n_orientations, accel, lab_s=False):
    """Return True when a calibration by estimator ``name`` gets a yardstick.

    Several orientations and an accelerometer model; and either not the field model
    itself, or no lab S (``lab_s``: a prior gives the non-orthogonality; without one the
    field model takes S = identity and its terms are not honest, ``FREE_S_WHY``).
    """
    if accel is None or n_orientations <= 1:
        return False
    own = name == YARDSTICK_FAMILY or getattr(accel, 'kind', None) == YARDSTICK_KIND
    return not (own and lab_s)


def yardstick(ctx):
    """Return ``fit.alarm_yardstick``: the field model's terms on ``ctx``'s holds.

    {'family', 'kind', 'T0' (3,) degC, 'b' (3, 3) m/s^2 .. about T0, 'b_std', 'k' (3, 3)
    1, 'k_std', 's_terms' (without a prior: S's below-diagonal terms and stds), 'note'} as
    lists; or {'family', 'error', 'note'} when the field model cannot be fitted or has no
    terms. Without a prior S is estimated with the terms (``FREE_S_WHY``).
    """
    free_s = ctx.prior_model is None
    note = ('the drift alarms of a registry read these terms (the field model fitted to '
            'the same holds), not the compensating model\'s, so that calibrations of '
            'different families stay comparable; they do not compensate anything'
            + ('; ' + FREE_S_WHY if free_s else ''))
    try:
        with np.errstate(all='ignore'):
            est = estimate_field(ctx, free_s=free_s)
            terms = bias_scale_terms(est.accel) if est.accel is not None else None
    except (CalibrationRefused, ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        return {'family': YARDSTICK_FAMILY, 'error': _reason(e), 'note': note}
    if terms is None or not all(np.all(np.isfinite(terms[k])) for k in TERMS):
        why = next((f' ({n})' for n in est.notes if n.startswith('field model: ')), '')
        return {'family': YARDSTICK_FAMILY, 'error': 'the field model has no finite bias and '
                f'scale terms with stds on these holds{why}', 'note': note}
    s_terms = est.fit.get('s_terms')
    if free_s and (s_terms is None or not np.all(np.isfinite(s_terms['std']))
                   or min(s_terms['std']) <= 0):
        return {'family': YARDSTICK_FAMILY, 'error': 'the non-orthogonality S has no finite, '
                'positive stds on these holds', 'note': note}
    out = {'family': YARDSTICK_FAMILY, 'kind': FREE_S_KIND if free_s else YARDSTICK_KIND}
    out.update({k: np.asarray(terms[k], float).tolist() for k in TERMS})
    if s_terms is not None:
        out['s_terms'] = s_terms
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
