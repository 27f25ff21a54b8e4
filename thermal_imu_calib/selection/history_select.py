"""``--model hysteresis`` and the one-orientation ``auto`` path across a temperature span.

The candidates of ``estimation.hysteresis`` (order, lag-difference / rate / two-state
terms, lagged input, time or temperature weighting; the ArduPilot-style cubic always among
them) are compared on held-out blocks of the thermal history (``time_folds``); the chosen
spec of each sensor is refitted on every window. ``fit.model_choice`` and
``fit.selection.heldout`` list every candidate's held-out figure.
"""

import numpy as np

from ..estimation.calibrate import CalibrationRefused, Estimate, register_estimator
from ..estimation.rvm_fit import fit_rvm_offset
from ..estimation.thermal_lag import cv_groups
from ..estimation.hysteresis import build_model, Features, fit_spec
from .time_folds import select_history


def _weighting_note(spec):
    return ('every window counts alike (time-weighted)' if spec.weighting == 'time' else
            'windows weighted so every part of the temperature span counts alike '
            '(uniform in temperature)')


@register_estimator('hysteresis')
def estimate_hysteresis(ctx):
    """Estimate offset models with thermal-history terms chosen on held-out history blocks."""
    if ctx.k == 0:
        raise CalibrationRefused('the hysteresis model needs a temperature input',
                                 'record the IMU temperature topic')
    if ctx.n_orientations != 1:
        raise CalibrationRefused('the hysteresis model is an offset model for one orientation',
                                 'use --model auto, field or field-lag for several poses')
    sel = getattr(ctx, 'thermal_selection', None)
    res = getattr(sel, 'history', None) or select_history(ctx)
    models, report, notes = {}, {}, []
    for sig, idx, t0 in (('accel', ctx.accel_input, ctx.t0),
                         ('gyro', ctx.gyro_input, ctx.gyro_t0)):
        spec = res['specs'][sig]
        if spec == 'rvm':     # the one-way path's RVM (seed 003) in the reading
            kernels = (res.get('rvm_kernels') or {}).get(sig)
            models[sig], report[f'{sig}_offset'] = fit_rvm_offset(
                ctx.windows, ctx.windows.temp[:, idx], sig, sig, cv_groups(ctx.windows)[0],
                offset_only=sig == 'accel', t_ref=t0, kernels=kernels)
            report[f'{sig}_history'] = {'spec': 'rvm', 'weighting': 'rvm',
                                        'history_terms': [], 'spec_state': 'rvm'}
            notes.append(f'{sig}: rvm (seed 003) in the reading, chosen on held-out blocks '
                         f'of the thermal history ({res["kind"]})')
            continue
        # every spec, the flight stacks' cubic too, is fitted about the data's own reference
        # temperature: the fitted shape is the same polynomial family whatever its origin,
        # and an offset-only accelerometer model is pinned (output = reading) there. Pinned
        # at ArduPilot's TEMP_REFERENCE (35 degC), often outside the data, the output's
        # level would be the cubic extrapolated there (tens of mm/s^2 off, and moving from
        # one estimate to the next). ArduPilot itself pins its correction at the
        # calibration temperature, not at 35 degC.
        ref = np.asarray(t0, float)
        feats = Features(ctx.windows, idx, ctx.options.levels(sig))
        rows = np.ones(len(ctx.windows), bool)
        coef, std = fit_spec(feats, spec, getattr(ctx.windows, sig), rows, ref)
        models[sig] = build_model(spec, coef, std, ref, sig, include_constant=sig == 'gyro',
                                  feats=feats)
        report[f'{sig}_history'] = {'spec': spec.label(), 'weighting': spec.weighting,
                                    'history_terms': getattr(models[sig], 'history_keys', []),
                                    'spec_state': spec.to_dict()}
        notes.append(f'{sig}: {spec.label()} (weighting: {_weighting_note(spec)}), chosen '
                     f'on held-out blocks of the thermal history ({res["kind"]})')
    notes.append(f'model choice: {res["reason"]}')
    poly = not getattr(models['gyro'], 'history_keys', ()) and models['gyro'].kind == \
        'offset_polynomial'
    notes.append(('gyroscope: bias polynomial' if poly else 'gyroscope: bias model') +
                 ' from stationary windows; earth rotation is not removed (up to 7.3e-5 rad/s)')
    if any(getattr(m, 'history_keys', ()) for m in models.values()):
        notes.append('the models use the temperature history (lagged readings): stream data '
                     'through Calibration.stream(); Calibration.apply alone means thermal '
                     'equilibrium')
    notes.append('offset-only model for one orientation: the accelerometer model removes the '
                 'drift relative to its output at the reference temperature; valid for this '
                 'mounting pose only')
    fit = {'pose': 'single orientation (offset-only)',
           'selection': {'model': 'hysteresis', 'reason': res['reason'],
                         'cv_groups': res['kind'], 'folds': res['folds'],
                         'heldout': res['table'], 'seconds': round(res['seconds'], 2),
                         'export_loss': res['export_loss']}}
    report['heldout'] = res['table']
    return Estimate(accel=models['accel'], gyro=models['gyro'], notes=notes, fit=fit,
                    report=report)
