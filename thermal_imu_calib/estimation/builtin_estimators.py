"""The estimators the core always has: offset (one orientation) and field (seed 000).

``estimate_offset``: the drift of each axis relative to the reference temperature, all one
pose allows. ``estimate_field``: the seed 000 field model, after ``check_faces_up_and_down``
refuses unless every axis was held up and down. ``DEFAULT_GYRO[0]`` gives the gyro model of
an Estimate without one (the bias polynomial ``_gyro_bias``; ``selection/gyro_select``
replaces it).
"""

import numpy as np

from ..input_units import DEGC
from .context import Estimate, register_estimator
from .field_estimator import (fit_field_model, per_axis_vertical_range, S_TERM_NAMES, S_TERMS,
                              SWEEP_TOL)
from .observability import ORDER_SPAN
from .offset_fit import fit_offset_model, time_groups
from .options import CalibrationRefused, hold_seconds, input_units
from .summary import _face_text

#: warn when an axis was never vertical within this many degC of the collected range's ends
EXTRAPOLATION_WARN_DEGC = 2.0


def _default_gyro(ctx, est):
    """Return (bias polynomial, report, notes); replaced by ``gyro_select.default_gyro``."""
    model, rep = _gyro_bias(ctx)
    return model, {'gyro_offset': rep}, ['gyroscope: bias polynomial from stationary windows; '
                                         'earth rotation is not removed (up to 7.3e-5 rad/s)']


#: the gyro model of an Estimate without one: ``fn(ctx, estimate) -> (model, report, notes)``
DEFAULT_GYRO = [_default_gyro]


def no_thermal(ctx):
    """Return the sensors the model choice gave no thermal terms (its placement floor)."""
    return getattr(getattr(ctx, 'thermal_selection', None), 'no_thermal', ())


def _gyro_bias(ctx):
    """Fit the default gyro bias polynomial; groups = holds when there are enough."""
    w = ctx.windows
    groups = w.hold if len(np.unique(w.hold)) >= 3 else time_groups(w.t0)
    orders = (0, 1, 2, 3) if ctx.k and 'gyro' not in no_thermal(ctx) else (0,)
    return fit_offset_model(w, ctx.tg, ctx.gyro_t0 if ctx.k else np.zeros(3), 'gyro', 'gyro',
                            include_constant=True, orders=orders, groups=groups,
                            levels=ctx.options.levels('gyro'))


@register_estimator('offset')
def estimate_offset(ctx):
    """Single orientation: per-axis drift relative to T0 (offset-only)."""
    if ctx.k == 0:
        return Estimate(notes=[
            'accelerometer not calibrated: a single orientation without temperature cannot '
            'separate bias or scale factor from gravity; hold the six faces (+x -x +y -y +z '
            '-z up)'])
    model, rep = fit_offset_model(ctx.windows, ctx.ta, ctx.t0, 'accel', 'accel',
                                  include_constant=False,
                                  orders=(0,) if 'accel' in no_thermal(ctx) else (0, 1, 2, 3),
                                  levels=ctx.options.levels('accel'))
    return Estimate(accel=model, report={'accel_offset': rep},
                    fit={'pose': 'single orientation (offset-only)'},
                    notes=['offset-only model for a single orientation: removes the drift of '
                           'each axis relative to its output at the reference temperature T0; '
                           'bias and scale factor are not separable from gravity in one pose '
                           'and are not estimated. Valid for this mounting pose only.'])


def check_faces_up_and_down(ctx):
    """Refuse unless every axis was held pointing up and pointing down (within 45 deg).

    Seed 000 sect. 3: bias and scale of an axis separate only between its up and down
    poses; the tilt is unknown, so a horizontal axis alone does not pin its bias.
    """
    w, o, cov = ctx.windows, ctx.options, ctx.coverage
    _, means = w.hold_means()
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    c45 = np.cos(np.radians(45.0))
    weak = [a for i, a in enumerate('xyz')
            if not (np.any(u[:, i] > c45) and np.any(u[:, i] < -c45))]
    if weak:
        missing = cov['missing']
        raise CalibrationRefused(
            f'scale factor and bias of axis {",".join(weak)} are not observable: faces held '
            f'{_face_text(cov)}; missing {" ".join(missing) or "none"}',
            f'hold each missing face ({" ".join(missing)}) still for at least '
            f'{hold_seconds(o.min_hold_s)} s, ideally repeated during the warm-up so each face is '
            'seen at several temperatures')


@register_estimator('field')
def estimate_field(ctx, free_s=False):
    """Seed 000 field model: two-step iteration plus joint refinement.

    ``free_s``: without a prior, also estimate the non-orthogonality S (its three
    below-diagonal terms, ``field_estimator.fit_field_model``); the alarm yardstick's use.
    """
    ctx = ctx.accel_view()
    w, o, k, ta = ctx.windows, ctx.options, ctx.k, ctx.ta
    check_faces_up_and_down(ctx)
    notes = []
    u = input_units(o, k)[ctx.accel_input[0]] if k else DEGC   # span rules: in this unit
    order = o.order if k else 0
    span = float(np.max(np.ptp(ta, axis=0))) if k else 0.0
    while order > 0 and span < ORDER_SPAN[order]:
        notes.append(f'temperature span {span:.2f} {u} is below {ORDER_SPAN[order]} {u}: '
                     f'polynomial order reduced from {order} to {order - 1}; collect during a '
                     'warm-up for temperature coefficients')
        order -= 1
    if k == 0:
        notes.append('no temperature input: temperature-independent scale factor and bias '
                     'only (dk0, db0)')
    k0 = b0 = s = None
    pm = ctx.prior_model
    free_s = bool(free_s and pm is None and o.refine)
    if pm is not None:
        k0 = pm.k0 + pm.thermal[:, 0]
        b0 = pm.b0 + pm.thermal[:, 3]
        s = pm.s
    elif free_s:
        notes.append('no prior calibration: k0 = 1, b0 = 0; dk0 and db0 hold the full '
                     'scale-factor and bias errors at T0; the non-orthogonality S is '
                     'estimated with them (unit diagonal, a +-2 % prior)')
    else:
        notes.append('no prior calibration: k0 = 1, b0 = 0, S = identity; dk0 and db0 hold '
                     'the full scale-factor and bias errors at T0, non-orthogonality is not '
                     'estimated')
    fit = fit_field_model(w, ta, o.gravity, ctx.t0, k0, b0, s, order=order, refine=o.refine,
                          free_s=free_s)
    vert = per_axis_vertical_range(w, ta, fit.tilts, fit.hold_ids)
    axis_span = np.nan_to_num(vert[:, 1] - vert[:, 0])
    for i, a in enumerate('xyz'):
        if order >= 1 and axis_span[i] < ORDER_SPAN[1]:
            notes.append(f'axis {a} was near vertical over only {axis_span[i]:.2f} {u}: its '
                         'scale temperature coefficients are poorly determined (see their std)')
        if k:
            lo, hi = ta[:, i].min(), ta[:, i].max()
            gap_lo, gap_hi = vert[i, 0] - lo, hi - vert[i, 1]
            if max(gap_lo, gap_hi) > EXTRAPOLATION_WARN_DEGC:
                notes.append(
                    f'axis {a} was held vertical only between {vert[i, 0]:.1f} and '
                    f'{vert[i, 1]:.1f} {u} of the {lo:.1f}-{hi:.1f} {u} collected: its '
                    'temperature terms are extrapolated outside that; next time hold every '
                    'face once early in the warm-up (a quick first pass of ~1 min per face)')
    if fit.refine_note:
        notes.append(f'field model: {fit.refine_note}')
    if not fit.converged:
        notes.append(f'field model: the two-step estimation did not settle in {fit.iterations} '
                     f'iterations (the fitted window means still moved by more than '
                     f'{SWEEP_TOL:g} of their noise)'
                     + ('; the joint refinement started from there' if fit.refined else ''))
    stats = {'iterations': fit.iterations, 'converged': bool(fit.converged),
             'joint_refinement': bool(fit.refined), 'order': order,
             'residual_rms': {'value': fit.residual_rms, 'unit': 'm/s^2'},
             'chi2_per_dof': fit.chi2_dof,
             'axis_vertical_temperature_range': {'value': vert.tolist(), 'unit': u}}
    if fit.s_std is not None:
        stats['s_terms'] = {'value': fit.model.s[S_TERMS].tolist(), 'std': fit.s_std.tolist(),
                            'unit': '1', 'terms': list(S_TERM_NAMES)}
        cond = fit.s_condition
        if cond is not None:      # the thermal vector given S (``SCondition``)
            stats['s_terms'].update({'information': cond.info.tolist(),
                                     'information_vector': cond.eta.tolist(),
                                     'thermal_gain': cond.gain.tolist(),
                                     'thermal_std_given_s': cond.std.tolist()})
            if cond.curvature is not None:
                stats['s_terms']['thermal_curvature'] = cond.curvature.tolist()
    return Estimate(accel=fit.model, notes=notes, fit=stats)
