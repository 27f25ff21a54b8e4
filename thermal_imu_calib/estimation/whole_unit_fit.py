"""Seed 002 whole-unit estimator: the accelerometer fit, then the gyroscope fit.

``fit_whole_unit`` runs ``whole_unit_accel.fit_whole_unit_accel`` and
``gyro_fit.fit_gyro`` on the accel-corrected holds; priors can come from a
seed 000 lab calibration (``prior_from_field_model``).
Register: ``--model whole_unit`` (estimator ``whole_unit``).
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

from .observability import DETERMINED_RATIO, FitNotConverged, Priors
from .whole_unit_accel import AccelFit, fit_whole_unit_accel


def prior_from_field_model(pm):
    """Return whole-unit prior means from a seed 000 FieldPolynomialModel (lab k0, b0, S)."""
    k0 = pm.k0 + pm.thermal[:, 0]
    b0 = pm.b0 + pm.thermal[:, 3]
    a1 = np.linalg.inv(pm.s) @ np.diag(1.0 / k0)
    return {'ct0': b0, 'A1': a1, 'ct1': pm.thermal[:, 4], 'ct2': pm.thermal[:, 5],
            'kt1': pm.thermal[:, 1] / k0, 'kt2': pm.thermal[:, 2] / k0}


# ------------------------------------------------------------------------ both triads
@dataclass
class WholeUnitFit:
    """Accelerometer and gyroscope fits of one whole-unit calibration."""

    accel: AccelFit
    gyro: object                 # gyro_fit.GyroFit
    notes: list
    stats: dict


def fit_whole_unit(windows, gravity, axis_temps=None, t0=None, gyro_inputs=None, t0g=None,
                   latitude=None, transitions=None, priors=None, order=2,
                   accel_input=(0, 0, 0), gyro_input=(0, 0, 0), residual='norm',
                   gyro_input_unit='degC', accel_rows=None):
    """Fit both triads from stationary windows (and pose changes); no refusal logic.

    windows: Windows; gravity m/s^2; axis_temps / gyro_inputs: (m, 3) thermal inputs of the
    accel / gyro axes per window (None: temperature-independent); t0 / t0g their references
    (default: middle of the range); latitude (deg) for the earth rate; transitions from
    ``gyro_fit.MotionCollector``; ``accel_rows``: bool mask of the windows the accelerometer
    is fitted on (default all; the gyro always uses every window, its hold directions come
    from the fitted accelerometer). Returns WholeUnitFit (models in ``.accel.model`` and
    ``.gyro.model``).
    """
    from .gyro_fit import fit_gyro
    priors = priors or Priors()
    m = len(windows)
    if axis_temps is not None and t0 is None:
        t0 = np.round((axis_temps.min(0) + axis_temps.max(0)) / 2.0, 2)
    if gyro_inputs is not None and t0g is None:
        t0g = np.round((gyro_inputs.min(0) + gyro_inputs.max(0)) / 2.0, 2)
    t0 = np.zeros(3) if t0 is None else np.asarray(t0, float)
    t0g = np.zeros(3) if t0g is None else np.asarray(t0g, float)
    rows = np.ones(m, bool) if accel_rows is None else np.asarray(accel_rows, bool)
    fit = fit_whole_unit_accel(windows.select(rows),
                               None if axis_temps is None else axis_temps[rows], gravity, t0,
                               priors, order=order if axis_temps is not None else 0,
                               residual=residual)
    am = fit.model
    acc = am.correct(windows.accel, axis_temps if axis_temps is not None
                     else np.broadcast_to(am.t0, (m, 3)))
    gfit = fit_gyro(windows, gyro_inputs, acc, t0g, latitude=latitude,
                    transitions=transitions, accel_model=am, accel_input=accel_input,
                    gyro_input=gyro_input, priors=priors,
                    order=order if gyro_inputs is not None else 0, input_unit=gyro_input_unit)
    n_est, n_fix = am.count()
    g_est, g_fix = gfit.model.count()
    notes = [f'seed 002 whole-unit model: {n_est + g_est} of {n_est + n_fix + g_est + g_fix} '
             'coefficients (the 63 of seed 002 plus the scale temperature terms) estimated '
             'from the data, the rest fixed (see meta.estimated and meta.fixed of each model)'
             ] + fit.notes + gfit.notes
    stats = {'residual_rms': {'value': fit.residual_rms, 'unit': 'm/s^2'},
             'chi2_per_dof': fit.chi2_dof, 'robust_scale': fit.robust_scale,
             'outlier_holds': fit.outlier_holds, 'accel_residual': residual,
             'accel_estimated': n_est, 'accel_fixed': n_fix,
             'gyro_estimated': g_est, 'gyro_fixed': g_fix,
             'observability_ratio_limit': DETERMINED_RATIO,
             'accel_posterior_ratio': fit.determined, 'accel_cv': fit.cv, **gfit.stats}
    return WholeUnitFit(fit, gfit, notes, stats)


def fit_whole_unit_context(ctx, rows=None, transitions=None):
    """Run ``fit_whole_unit`` with the settings of a ``calibrate.Context``.

    ``rows``: bool mask of the windows to fit (default all; e.g. the training holds of a
    held-out comparison); ``transitions``: pose changes (None: static only). The options'
    ``whole_unit_priors`` are copied, never modified; a lab prior (seed 000 field model)
    sets the accelerometer prior means.
    """
    w, o, k = ctx.windows, ctx.options, ctx.k
    rows = np.ones(len(w), bool) if rows is None else np.asarray(rows, bool)
    user = o.whole_unit_priors
    priors = dataclasses.replace(user) if user is not None else Priors()
    if ctx.prior_model is not None:
        priors.accel_mean = prior_from_field_model(ctx.prior_model)
    t0g = ctx.t0 if k and list(ctx.gyro_input) == list(ctx.accel_input) else None
    acc_rows = getattr(ctx, 'accel_rows', None)
    return fit_whole_unit(w.select(rows), o.gravity, ctx.ta[rows] if k else None, ctx.t0,
                          ctx.tg[rows] if k else None, t0g, o.latitude,
                          transitions, priors, o.order if k else 0, ctx.accel_input,
                          ctx.gyro_input, o.whole_unit_residual, ctx.gyro_unit,
                          accel_rows=None if acc_rows is None else acc_rows[rows])


# ------------------------------------------------------------------------ estimator
def _register():
    """Register the ``whole_unit`` estimator (imported by calibrate.ESTIMATOR_MODULES)."""
    from .calibrate import CalibrationRefused, Estimate, register_estimator
    from .options import hold_seconds

    @register_estimator('whole_unit')
    def estimate_whole_unit(ctx):
        """Seed 002 whole-unit model: accel (norm fit) and gyro (static + rotations).

        Settings from CalibrateOptions: ``latitude`` (deg), ``transitions`` (pose changes
        from gyro_fit.MotionCollector), ``whole_unit_priors`` (Priors) and
        ``whole_unit_residual`` ('norm' or 'vector').
        """
        o = ctx.options
        if ctx.n_orientations < 4:
            raise CalibrationRefused(
                f'only {ctx.n_orientations} distinct orientations were held',
                'the whole-unit model needs at least the six faces (+x -x +y -y +z -z up), '
                'plus tilted poses for misalignment, each still for '
                f'{hold_seconds(o.min_hold_s)} s or more')
        try:
            res = fit_whole_unit_context(ctx, transitions=o.transitions)
        except FitNotConverged as e:
            raise CalibrationRefused(e.what, e.advice) from None
        am = res.accel.model
        weak = [f'{a}' for i, a in enumerate('xyz')
                if not (am.estimated_mask('ct0')[i] and am.estimated_mask('A1')[i, i])]
        if weak:
            raise CalibrationRefused(
                f'bias or scale factor of axis {",".join(weak)} is not determined by the '
                f'holds collected ({ctx.coverage["holds"]} holds, faces missing: '
                f'{" ".join(ctx.coverage["missing"]) or "none"})',
                'hold every axis pointing up and pointing down, still, ideally several '
                'times during the warm-up')
        return Estimate(accel=am, gyro=res.gyro.model, notes=res.notes, fit=res.stats,
                        report={'whole_unit': {'accel': res.accel.determined,
                                               'gyro': res.gyro.stats}})

    return estimate_whole_unit


estimate_whole_unit = _register()
