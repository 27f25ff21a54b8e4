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
terms are compared only with other such yardsticks; it also stores the terms given S, the
scale factor's curvature on S, and what its holds say about S (``given_s``), so the alarms
can test a unit's calibrations at S pooled over them (``fleet/pooled_s.py``). With a
prior, S is the prior's and a field calibration's own terms serve, as before.

A yardstick that cannot be fitted (faces missing, no convergence, non-finite terms) is
recorded with the reason; the calibration's own terms are then used, as before. No ROS
import.
"""

import numpy as np

from ..models.alarm_terms import bias_scale_terms, coefficients
from ..models.field import FieldPolynomialModel
from .builtin_estimators import estimate_field
from .field_estimator import s_of_terms
from .options import CalibrationRefused

#: the family whose terms the alarms read (``ESTIMATORS`` name and model kind)
YARDSTICK_FAMILY = 'field'
YARDSTICK_KIND = FieldPolynomialModel.kind
#: the family name of a yardstick that estimated S (no prior): its terms are compared only
#: with others of the same kind, not with S = identity ones (registries written before it)
FREE_S_KIND = YARDSTICK_KIND + '+S'
#: the keys of ``bias_scale_terms`` stored (arrays as nested lists)
TERMS = ('T0', 'b', 'b_std', 'k', 'k_std')
#: with S estimated: the terms' stds given S and their gains on S's terms (``given_s``)
GIVEN_S = ('b_std_s', 'k_std_s', 'b_ds', 'k_ds')
#: with S estimated and the fit's curvature on S (``field_estimator.SCondition``): the
#: scale factor's second derivatives on S's terms at T0 (yardsticks written before have none)
K_CURVATURE = 'k_dss'
#: the fit's thermal vector given S, read by ``given_s`` and not stored
GIVEN_S_INPUTS = ('thermal_gain', 'thermal_std_given_s', 'thermal_curvature')
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
        given = given_s(est.accel, s_terms)
        out['s_terms'] = {k: v for k, v in s_terms.items() if k not in GIVEN_S_INPUTS}
        if given is not None:
            out.update({k: np.asarray(v, float).tolist() for k, v in given.items()})
    out['note'] = note
    return out


def given_s(model, s_terms):
    """Return the terms' stds given S and their gains on S's terms, or None.

    {'b_std_s', 'k_std_s' (3, 3): as ``b_std``/``k_std`` at a known S; 'b_ds', 'k_ds'
    (3, 3, 3): d b / d (s10, s20, s21) and d k / d ..}, from the fit's thermal vector given S
    (``field_estimator.SCondition``; the terms are linear in it, so the gains are exact);
    with the fit's curvature on S also ``K_CURVATURE`` (3 axes, 3, 3): d^2 k(T0) / d (s_m,
    s_n). None when the fit has no condition or it is not finite.
    """
    try:
        gain = np.asarray(s_terms['thermal_gain'], float).reshape(3, 6, 3)
        std = np.asarray(s_terms['thermal_std_given_s'], float).reshape(3, 6)
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(gain)) and np.all(np.isfinite(std))):
        return None
    m = model
    cond = bias_scale_terms(FieldPolynomialModel(m.t0, m.thermal, m.k0, m.b0, m.s, std,
                                                 m.input_unit))
    if cond is None:
        return None
    b, k = coefficients(m, m.t0)
    b_ds, k_ds = np.zeros((3, 3, 3)), np.zeros((3, 3, 3))
    q = np.asarray(s_terms['value'], float)
    for i in range(3):
        step = np.eye(3)[i]
        moved = FieldPolynomialModel(m.t0, m.thermal + gain[:, :, i], m.k0, m.b0,
                                     s_of_terms(q + step), input_unit=m.input_unit)
        bi, ki = coefficients(moved, m.t0)
        b_ds[:, :, i], k_ds[:, :, i] = bi - b, ki - k
    out = {'b_std_s': cond['b_std'], 'k_std_s': cond['k_std'], 'b_ds': b_ds, 'k_ds': k_ds}
    curv = _k_curvature(m, s_terms.get('thermal_curvature'), k)
    if curv is not None:
        out[K_CURVATURE] = curv
    return out


def _k_curvature(m, curvature, k):
    """Return (3 axes, 3, 3) d^2 k(T0) / d (s_m, s_n) from the fit's thermal curvature, or None.

    The terms are linear in the thermal vector, so each pair's curvature moves them as a
    thermal step would. Only the scale factor at T0: its curvature is k itself times
    (s^2) / 2 (``field_estimator.SCondition.curvature``), that of its temperature coefficients and
    of the bias (read from opposite faces, where it cancels) is smaller by their size.
    """
    try:
        c = np.asarray(curvature, float).reshape(3, 6, 3, 3)
    except (TypeError, ValueError):
        return None
    if not np.all(np.isfinite(c)):
        return None
    out = np.zeros((3, 3, 3))
    for i in range(3):
        for j in range(3):
            moved = FieldPolynomialModel(m.t0, m.thermal + c[:, :, i, j], m.k0, m.b0, m.s,
                                         input_unit=m.input_unit)
            out[:, i, j] = coefficients(moved, m.t0)[1][:, 0] - k[:, 0]
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
    out.update(_given_s_of(y))
    return out


def _given_s_of(y):
    """Return the stored terms given S with S's fit ({} when the yardstick has none).

    {'b_std_s', 'k_std_s' (3, 3), 'b_ds', 'k_ds' (3, 3, 3), 's' (3,) fitted terms,
    's_info' (3, 3), 's_eta' (3,)}: see ``given_s`` and ``field_estimator.SCondition``.
    """
    st = y.get('s_terms') or {}
    try:
        out = {k: np.asarray(y[k], float) for k in GIVEN_S}
        out.update(s=np.asarray(st['value'], float), s_info=np.asarray(st['information'], float),
                   s_eta=np.asarray(st['information_vector'], float))
    except (KeyError, TypeError, ValueError):
        return {}
    shapes = {'b_std_s': (3, 3), 'k_std_s': (3, 3), 'b_ds': (3, 3, 3), 'k_ds': (3, 3, 3),
              's': (3,), 's_info': (3, 3), 's_eta': (3,)}
    if any(out[k].shape != v or not np.all(np.isfinite(out[k])) for k, v in shapes.items()):
        return {}
    try:            # optional: yardsticks written before it have none
        curv = np.asarray(y[K_CURVATURE], float)
        if curv.shape == (3, 3, 3) and np.all(np.isfinite(curv)):
            out[K_CURVATURE] = curv
    except (KeyError, TypeError, ValueError):
        pass
    return out
