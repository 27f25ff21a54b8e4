"""``--model auto``: choose the thermal model by held-out validation on the collected data.

``auto_policy`` (installed as ``calibrate.AUTO_POLICY[0]``) decides:

* one orientation without a temperature input, or with degC inputs spanning less than
  ``SINGLE_MIN_SPAN`` over the windows (a soak, a robot on its mount at a steady
  temperature): ``offset`` (order by cross-validation) without comparing shapes; a held-out
  gain of a richer model over such a span is a drift in time that happens to correlate with
  temperature (BMI270 soaks: 0.4 and 0.03 degC, the accelerometer drifting 16 mg in 80 s
  while the temperature is flat);
* one orientation across a temperature span: offset, lag and RVM compared held out
  (``single_select``; the history models when the temperature turns both ways);
* several orientations: field, lagged field and RVM (``multi_select``), then the whole-unit
  model against field when there are tilted holds (``whole_unit_select``).

The folds, clamping and scores they share are in ``heldout``. The decision and the table
of held-out errors go to ``ctx.thermal_selection`` so that the estimators registered here
(``lag``, ``field-lag``, ``rvm``, ``rvm-lag``) reuse the time constant and RVM kernels
instead of searching again. ``calibrate_thermal`` runs the choice and the estimator alone.
The names of the comparison modules stay importable from here.
"""

import dataclasses

import numpy as np

from ..calibration import Calibration
from ..estimation.calibrate import (AUTO_POLICY, CalibrateOptions, CalibrationRefused,
                                    check_faces_up_and_down, Estimate, estimate_field,
                                    make_context, ORDER_SPAN, register_estimator, valid_range)
from ..estimation.offset_fit import fit_offset_model
from ..estimation.rvm_fit import fit_rvm_offset
from ..estimation.thermal_lag import (cv_groups, estimate_tau, lagged_axis_temperatures,
                                      with_restart_spread)
from ..thermal_input import ThermalFilter
from .heldout import (_filter_ok, _hold_folds, _lagged_inputs,  # noqa: F401  (re-exported)
                      _weighted_rms, _whole_unit_folds, clamp_to_training, FILTER_SUPPORTED,
                      fold_masks, MULTI_FOLDS, Selection)
from .multi_select import (_field_fit, fit_rvm_multi, heldout_multi,  # noqa: F401
                           MULTI_CANDIDATES, MULTI_LAG_IMPROVEMENT, MULTI_MARGIN,
                           MULTI_RVM_MARGIN, select_multi)
from .single_select import (fit_single, heldout_single,  # noqa: F401  (re-exported)
                            LAG_MIN_IMPROVEMENT, select_single, select_single_history,
                            SINGLE_CANDIDATES, SINGLE_MARGIN)
from .one_way_select import select_one_way
from .time_folds import turns_both_ways
from .whole_unit_select import (heldout_whole_unit, KEEP_RATIO,  # noqa: F401  (re-exported)
                                select_whole_unit, WHOLE_UNIT_GYRO_SLACK, WHOLE_UNIT_MARGIN,
                                WHOLE_UNIT_MIN_FOLDS, WHOLE_UNIT_MIN_TILTED)

#: one orientation: degC span (over the windows) below which auto ends at ``offset``
#: (the field model's span for a first-order term, ``calibrate.ORDER_SPAN[1]``)
SINGLE_MIN_SPAN = ORDER_SPAN[1]


def calibration_from(ctx, est):
    """Return the Calibration an Estimate makes (models, filter, inputs, range, noise).

    The filter's ``restart_spread`` is measured on the context's windows.
    """
    o, w = ctx.options, ctx.windows
    return with_restart_spread(Calibration(
        accel=est.accel, gyro=est.gyro, inputs=list(o.inputs), valid_range=valid_range(w, o),
        out_of_range=o.out_of_range, accel_input=ctx.accel_input, gyro_input=ctx.gyro_input,
        frame_id=o.frame_id, gravity=o.gravity, gravity_source=o.gravity_source,
        accel_noise_std=np.sqrt(np.median(w.accel_var, axis=0)),
        gyro_noise_std=np.sqrt(np.median(w.gyro_var, axis=0)), notes=list(est.notes),
        fit=dict(est.fit), temperature_filter=getattr(est, 'temperature_filter', None)), w)


def auto_policy(ctx):
    """Choose the model for ``--model auto`` by held-out validation; returns (name, reason)."""
    if ctx.n_orientations == 1:
        if ctx.k == 0:
            return 'offset', 'one orientation and no temperature input'
        span = _degc_span(ctx)
        if span is not None and span < SINGLE_MIN_SPAN:
            return 'offset', (
                f'one orientation: only an offset per axis vs temperature is observable; the '
                f'temperature spans {span:.2f} degC (< {SINGLE_MIN_SPAN:g}), too little to tell '
                'a temperature dependence from a drift in time, so no richer shape (lag, rvm) '
                'is compared: offset polynomial, order by cross-validation')
        if turns_both_ways(ctx):
            sel = select_single_history(ctx)
        else:
            sel = select_single(ctx)
            res, note = select_one_way(ctx, sel, fit_single)
            sel.reason += f'; {note}'
            sel = sel if res is None else select_single_history(ctx, res)
    else:
        try:
            check_faces_up_and_down(ctx)
        except CalibrationRefused:
            return 'field', (f'{ctx.n_orientations} orientations but faces missing: the '
                             'field estimator explains what to collect')
        sel = select_whole_unit(ctx, select_multi(ctx))
    ctx.thermal_selection = sel
    return sel.model, sel.reason


def _degc_span(ctx):
    """Return the largest span (degC) of the degC inputs over the windows (None: none)."""
    degc = [i for i, t in enumerate(_lagged_inputs(ctx)) if t]
    if not degc or len(ctx.windows) == 0:
        return None
    return float(np.max(np.ptp(ctx.windows.temp[:, degc], axis=0)))


def _selection(ctx, name):
    sel = getattr(ctx, 'thermal_selection', None)
    return sel if sel is not None and sel.model == name else None


def _require_filter(ctx, name):
    if not _filter_ok(ctx):
        raise CalibrationRefused(f'the {name} model needs a temperature filter in the '
                                 'calibration, which this calibrate.py cannot store',
                                 'use --model offset, rvm or field')


def _lag_for(ctx, name, sel):
    if sel is not None and sel.tau_s is not None:
        return sel.tau_s, sel.lag
    if ctx.k == 0:
        raise CalibrationRefused(f'the {name} model needs a temperature input',
                                 'record the IMU temperature topic')
    if ctx.n_orientations == 1:
        est = estimate_tau(ctx.windows, ctx.accel_input, ctx.gyro_input,
                           lagged=_lagged_inputs(ctx), levels=ctx.options.level_sensors())
    else:
        est = estimate_tau(ctx.windows, ctx.accel_input, ctx.gyro_input, signals=('gyro',),
                           groups=ctx.windows.hold, group_kind='holds',
                           lagged=_lagged_inputs(ctx), levels=ctx.options.level_sensors())
    return est.tau_s, est.report()


def _estimate(ctx, name, family, lagged):
    if ctx.k == 0:
        raise CalibrationRefused(f'the {name} model needs a temperature input',
                                 'record the IMU temperature topic')
    sel = _selection(ctx, name)
    tau, lag_rep = None, None
    if lagged:
        _require_filter(ctx, name)
        tau, lag_rep = _lag_for(ctx, name, sel)
    notes = []
    fit_stats = {}
    report = {}
    if ctx.n_orientations == 1:
        kernels = sel.kernels.get(name) if sel is not None else None
        acc, gyr, rep = fit_single(ctx, family, tau, kernels=kernels,
                                   no_thermal=sel.no_thermal if sel is not None else ())
        report.update({'accel_offset': rep['accel'], 'gyro_offset': rep['gyro']})
        fit_stats['pose'] = 'single orientation (offset-only)'
        notes.append('one orientation: the accelerometer model removes the drift relative '
                     'to its output at the reference temperature; valid for this mounting '
                     'pose only')
    else:
        check_faces_up_and_down(ctx)
        if family == 'field':
            lag_ctx = dataclasses.replace(
                ctx, ta=lagged_axis_temperatures(ctx.windows, tau, ctx.accel_input),
                tg=lagged_axis_temperatures(ctx.windows, tau, ctx.gyro_input))
            est = estimate_field(lag_ctx)
            acc, notes, fit_stats = est.accel, list(est.notes), dict(est.fit)
        else:
            kernels = sel.kernels.get(name) if sel is not None else None
            acc, rep = fit_rvm_multi(ctx, tau=tau, kernels=kernels)
            report['accel_rvm'] = rep
            fit_stats['pose'] = 'several orientations (bias and scale by pose, seed 003)'
        tg = lagged_axis_temperatures(ctx.windows, tau, ctx.gyro_input)
        groups, _ = cv_groups(ctx.windows)
        if family == 'rvm':
            gyr, report['gyro_offset'] = fit_rvm_offset(ctx.windows, tg, 'gyro', 'gyro',
                                                        groups, t_ref=ctx.gyro_t0)
        else:
            gyr, report['gyro_offset'] = fit_offset_model(ctx.windows, tg, ctx.gyro_t0, 'gyro',
                                                          'gyro', include_constant=True,
                                                          groups=groups,
                                                          levels=ctx.options.levels('gyro'))
        notes.append('gyroscope: bias vs temperature from stationary windows; earth rotation '
                     'is not removed (up to 7.3e-5 rad/s)')
    if sel is not None:
        fit_stats['selection'] = sel.report()
    if lagged:
        fit_stats['thermal_lag'] = lag_rep
        notes.append(f'the models take the temperature through a first-order lag of '
                     f'{float(np.max(tau)):.0f} s (temperature.filter): stream data through '
                     'Calibration.stream()')
    est = Estimate(accel=acc, gyro=gyr, notes=notes, fit=fit_stats, report=report)
    # carried as a field once calibrate.Estimate has one, else as an attribute that
    # calibrate_thermal (below) reads
    est.temperature_filter = ThermalFilter(tau) if lagged else None
    return est


@register_estimator('lag')
def estimate_lag(ctx):
    """Estimate polynomial (or field) models in a lagged temperature, tau from the data."""
    return _estimate(ctx, 'lag', 'poly' if ctx.n_orientations == 1 else 'field', True)


@register_estimator('field-lag')
def estimate_field_lag(ctx):
    """Estimate the seed 000 field model in a lagged temperature (several orientations)."""
    if ctx.n_orientations == 1:
        raise CalibrationRefused('the field model needs several orientations',
                                 'use --model lag for one orientation')
    return _estimate(ctx, 'field-lag', 'field', True)


@register_estimator('rvm')
def estimate_rvm(ctx):
    """Estimate RVM models (seed 003): offsets in one pose, bias and scale in several."""
    return _estimate(ctx, 'rvm', 'rvm', False)


@register_estimator('rvm-lag')
def estimate_rvm_lag(ctx):
    """Estimate RVM models in a lagged temperature, tau from the data."""
    return _estimate(ctx, 'rvm-lag', 'rvm', True)


def calibrate_thermal(windows, options=None):
    """Run the ``--model`` choice and estimator on windows; returns (Calibration, Estimate).

    The same decisions as ``calibrate_windows`` (auto policy, registered estimators, gyro
    default) with the temperature filter honoured even where calibrate.py cannot store it
    yet; the Calibration has no fit statistics beyond the estimator's.
    """
    from ..estimation.calibrate import _gyro_bias, ESTIMATORS, model_choices
    o = options or CalibrateOptions()
    if o.model not in model_choices():
        raise CalibrationRefused(f'unknown model {o.model!r}', f'use one of {model_choices()}')
    ctx = make_context(windows, o)
    ctx.filter_ok = True
    name, why = (o.model, 'requested') if o.model != 'auto' else AUTO_POLICY[0](ctx)
    est = ESTIMATORS[name](ctx)
    if est.gyro is None:
        est.gyro, _ = _gyro_bias(ctx)
    est.fit.setdefault('model_choice', {'model': name, 'reason': why})
    sel = getattr(ctx, 'thermal_selection', None)
    if sel is not None:
        est.fit.setdefault('selection', sel.report())
    return calibration_from(ctx, est), est


AUTO_POLICY[0] = auto_policy
