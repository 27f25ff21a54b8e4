"""From stationary windows to a Calibration: the one estimation entry point.

``calibrate_windows`` is used by the CLI (offline logs), the calibrator node (live segment
statistics) and the fleet, through ``app.calibrate``. It checks the windows, builds the
estimators' Context, leaves out the holds that disagree with a repeat of their pose, lets
the ``--model`` estimator (or the ``auto`` policy) fit, adds the default gyro model, and
assembles the Calibration, its ``fit`` report and a one-line summary. ``readiness`` says
whether it would succeed now and what to hold next.

Its parts: ``options`` (CalibrateOptions, CalibrationRefused, input mapping and valid
range), ``context`` (Context, Estimate, the estimator registry and ``AUTO_POLICY``),
``hold_rules`` (leaving holds out), ``builtin_estimators`` (offset, field, the default gyro
bias), ``summary`` (the summary line, notes and report). The public names they had here,
and ``_gyro_bias``, are still imported from this module (``# noqa: F401``: re-exported).
"""

import dataclasses

import numpy as np

from ..calibration import Calibration
from ..collection.segments import (coverage, distinct_orientations, FACE_NAMES,
                                   MOUNTING_POSE_DEG, mounting_pose_mask)
from ..input_units import is_temperature
from ..io.imu_units import accel_unit_problem
from . import alarm_yardstick
from .allan import window_noise
from .builtin_estimators import (_gyro_bias, check_faces_up_and_down,  # noqa: F401
                                 DEFAULT_GYRO, estimate_field, estimate_offset,
                                 EXTRAPOLATION_WARN_DEGC)
from .context import (AUTO_POLICY, auto_choice, Context, Estimate,  # noqa: F401
                      ESTIMATOR_MODULES, ESTIMATORS, make_context, model_choices,
                      register_estimator)
from .gyro_static import earth_rate_parts
from .hold_rules import (consistency_notes, HOLD_MAGNITUDES,  # noqa: F401
                         HOLD_RULE_JUDGE, leave_out_holds)
from .observability import ORDER_SPAN
from .thermal_lag import with_restart_spread
from .options import (CalibrateOptions, CalibrationRefused,  # noqa: F401
                      CalibrationResult, default_input_map, gyro_reference, hold_seconds,
                      input_margins, input_units, narrow_high_order, PROXY_MARGIN_FRACTION,
                      valid_range)
from .summary import (_adequacy_notes, _amax, _face_text, _margin_report,  # noqa: F401
                      _model_choice, _pose_change_text, _rms, _rotation_stats, _span_text,
                      ADEQUACY_CHI2, gravity_residuals)

#: tilted holds the whole-unit model asks for before it calls the collection complete
WHOLE_UNIT_TILTED = 3

#: how the reason of ``auto``'s choice names the judging of a thermal family against the
#: standard fit (``selection/standard_floor.judge_family`` appends it after '; '); the
#: part after it becomes a note
FLOOR_REASON = 'against the standard fit'


def readiness(windows, model='auto', min_holds=1):
    """Say whether ``calibrate_windows`` would succeed now and what to hold next.

    Returns a dict: ready (bool), mode, reason, next_pose (face label or None), coverage.
    Cheap: no fitting, only the coverage rules.
    """
    cov = coverage(windows)
    if cov['holds'] < min_holds:
        return {'ready': False, 'mode': None, 'reason': 'no stationary holds yet',
                'next_pose': '+z', 'coverage': cov}
    n_orient = distinct_orientations(windows)
    missing = cov['missing']
    if model == 'offset' or (model == 'auto' and n_orient == 1):
        return {'ready': True, 'mode': 'offset', 'reason': 'single orientation: offset-only model',
                'next_pose': missing[0] if missing else None, 'coverage': cov}
    if missing:
        return {'ready': False, 'mode': 'field', 'reason': f'faces missing: {" ".join(missing)}',
                'next_pose': missing[0], 'coverage': cov}
    # all faces held: suggest the face seen at the fewest temperatures to repeat
    least = min(FACE_NAMES, key=lambda f: cov['faces'][f]['holds'])
    if model == 'whole_unit':
        tilted = cov['tilted_holds']
        if tilted < WHOLE_UNIT_TILTED:
            return {'ready': True, 'mode': 'whole_unit',
                    'reason': f'all six faces held; {tilted} of {WHOLE_UNIT_TILTED} corner-up '
                              '(tilted) holds for the misalignment (it stays at its prior '
                              'until then)', 'next_pose': 'tilted', 'coverage': cov}
        return {'ready': True, 'mode': 'whole_unit',
                'reason': f'all six faces and {tilted} tilted holds', 'next_pose': least,
                'coverage': cov}
    return {'ready': True, 'mode': 'field', 'reason': 'all six faces held',
            'next_pose': least, 'coverage': cov}


def _check_accel_units(means, gravity):
    """Refuse holds whose accelerations are not in m/s^2 (g, milli-g, raw counts).

    ``means``: (h, 3) hold means (``Windows.hold_means``).
    The median |a| of the hold means over ``gravity``: a driver publishing g reads 0.10
    of it, milli-g about 100, raw counts thousands. Calibrated anyway, a several-orientation
    fit ended at "the accel model is implausible ... a coefficient is corrupt", and a
    one-orientation drift model was written in the wrong unit. Every path (CLI, node,
    fleet) refuses such holds here, naming the likely unit (``io.imu_units``, which the
    compensator's warning shares).
    """
    problem = accel_unit_problem(float(np.median(np.linalg.norm(means, axis=1))), gravity)
    if problem:
        seen, rule, fix = problem
        raise CalibrationRefused(f'{seen}, {rule}', f'{fix}, then record or replay again')


#: a pose change counts for the gyro's unit when gravity turned by more than this (rad)
UNIT_TURN_MIN = np.radians(30.0)
#: median (gyro path length / angle gravity turned) above which the gyro is not in rad/s:
#: at least 1 and about 1-2 in rad/s (a hand's detours add to the path; the largest single
#: pose change of the shared recordings: 12.5), at least 57.3 in deg/s
GYRO_TURN_RATIO_MAX = 25.0


def _check_gyro_units(windows, ids, means, transitions):
    """Refuse a gyro that is not in rad/s (deg/s), seen in the pose changes between holds.

    ``ids``, ``means``: the windows' ``hold_means``.

    For each pose change in which gravity turned by more than ``UNIT_TURN_MIN`` (the angle
    between the two holds' mean accelerations), the angle the gyro turned (its path length,
    the integral of |w - the earlier hold's mean|) over that angle: at least 1 and about
    1-2 in rad/s (the shared posing recordings: medians 1.0-1.8, at most 12.5 for one pose
    change), 57 in deg/s (getovermassif data4 in deg/s: 58). Refused when their median
    exceeds ``GYRO_TURN_RATIO_MAX``. Before, such a log lost most holds to the rotation
    test and was refused for missing faces, or was calibrated in the wrong unit.
    """
    if not transitions or not len(windows):
        return
    pos = {int(h): i for i, h in enumerate(ids)}
    ratios = []
    for tr in transitions:
        if tr.hold_from not in pos or tr.hold_to not in pos or len(tr.t) < 2:
            continue
        a, b = means[pos[tr.hold_from]], means[pos[tr.hold_to]]
        angle = np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))
        if angle < UNIT_TURN_MIN:
            continue
        bias = windows.gyro[windows.hold == tr.hold_from].mean(axis=0)
        path = np.trapezoid(np.linalg.norm(np.asarray(tr.gyro) - bias, axis=1), tr.t)
        ratios.append(path / angle)
    if not ratios or np.median(ratios) <= GYRO_TURN_RATIO_MAX:
        return
    raise CalibrationRefused(
        f'the gyroscope turned {np.median(ratios):.3g} times the angle gravity turned between '
        f'holds (median over {len(ratios)} pose changes of more than '
        f'{np.degrees(UNIT_TURN_MIN):.0f} deg): its values look in deg/s, while '
        'sensor_msgs/Imu angular_velocity is in rad/s (REP 145)',
        'publish the IMU in rad/s (for deg/s, multiply by pi/180 = 0.0174533; check the '
        "driver's unit parameters), then record or replay again")


def _without_flat_temperature(windows, o):
    """Return (windows, options, notes) with degC inputs that barely moved taken out.

    Several orientations: when every thermal input is a temperature (degC) spanning less
    than ``ORDER_SPAN[1]`` over the holds, no temperature term can be resolved from it, so
    the estimation is the one without the inputs (the same calibration as without the
    topic, temperature-independent) and a note says so. One orientation keeps them: its
    offset model is what ``auto`` ends at either way (``select.SINGLE_MIN_SPAN``).
    """
    k = windows.n_inputs
    if not k or distinct_orientations(windows) < 2:
        return windows, o, []
    units = input_units(o, k)
    if not all(is_temperature(u) for u in units):
        return windows, o, []
    span = float(np.max(np.ptp(windows.temp, axis=0)))
    if span >= ORDER_SPAN[1]:
        return windows, o, []
    w = dataclasses.replace(windows, temp=windows.temp[:, :0],
                            temp_rate=windows.temp_rate[:, :0])
    trs = [dataclasses.replace(t, temps=np.asarray(t.temps)[:0]) for t in o.transitions]
    o = dataclasses.replace(o, inputs=[], accel_input=None, gyro_input=None, transitions=trs)
    return w, o, [f'the temperature spanned only {span:.2f} degC over the holds (< '
                  f'{ORDER_SPAN[1]:g} degC, too little for any temperature term): treated as '
                  'no temperature input, a temperature-independent calibration (the same as '
                  'without the topic); collect across a warm-up for thermal terms']


def _mounting_pose_only(windows, o):
    """Return (windows, options, notes): one orientation family, only the mounting pose's holds.

    The one-orientation models describe one pose: a hold tilted by 1 deg from it puts
    g sin(1 deg) = 0.17 m/s^2 on the horizontal axes, which they would read as drift (a
    robot's stops on slopes; on simulated robot logs the accelerometer then kept no thermal
    terms). When the holds are one orientation family (``mounting_pose_mask``: every hold
    within 20 deg of the mounting pose) only those within ``MOUNTING_POSE_DEG`` of it are
    fitted, as lifelong mode does (``lifelong.pose``); the pose changes touching a hold
    left out are dropped with it. Several orientations: unchanged.
    """
    keep = mounting_pose_mask(windows, MOUNTING_POSE_DEG)
    if keep.all():
        return windows, o, []
    kept = windows.select(keep)
    ids = set(int(h) for h in kept.hold_ids)
    trs = [t for t in o.transitions if t.hold_from in ids and t.hold_to in ids]
    n_all, n_out = len(windows.hold_ids), len(windows.hold_ids) - len(ids)
    return kept, dataclasses.replace(o, transitions=trs), [
        f'{n_out} of {n_all} holds are more than {MOUNTING_POSE_DEG:g} deg from the mounting '
        'pose (slopes, or the unit moved) and are not used: the one-orientation models '
        'describe one pose, and a tilt would read as drift to them (1 deg puts 0.17 m/s^2 '
        'on the horizontal axes)']


def _without_vertical_earth_rate(windows, o):
    """Return (windows, notes): one orientation with a latitude, the vertical earth rate removed.

    A still gyroscope reads the earth rate. In one pose its vertical part along the up
    direction (``gyro_static.earth_rate_parts``: 5.2e-5 rad/s at 45 deg) is a constant the
    offset models would take for bias, and a compensated output would then lack it. With the
    latitude known it is taken out of every window's gyro mean before the fit (up: the
    window's measured specific force direction). The horizontal part depends on the heading,
    which one pose does not give: it stays, and averages out over holds at many headings.
    Several orientations: the gyro fits remove the earth rate themselves (``gyro_static``).
    """
    if o.latitude is None or not len(windows) or distinct_orientations(windows) != 1:
        return windows, []
    up = windows.accel / np.linalg.norm(windows.accel, axis=1, keepdims=True)
    vertical, _ = earth_rate_parts(o.latitude)
    w = dataclasses.replace(windows, gyro=windows.gyro - vertical * up)
    return w, [f'gyroscope: the vertical earth rate ({vertical:.3g} rad/s at latitude '
               f'{o.latitude:g} deg) removed before the fit (one orientation; the horizontal '
               'part depends on the heading and stays in the hold means)']


def calibrate_windows(windows, options=None):
    """Estimate a Calibration from stationary windows; raise CalibrationRefused if impossible."""
    o = options or CalibrateOptions()
    choices = model_choices()
    if o.model not in choices:
        raise CalibrationRefused(f'unknown model {o.model!r}', f'use one of {choices}')
    if len(windows) == 0:
        raise CalibrationRefused(
            'no stationary segments were found',
            f'hold the IMU still for at least {hold_seconds(o.min_hold_s)} s in each pose '
            '(check the IMU topic, and that the log contains still periods)')
    if len(o.inputs) != windows.n_inputs:
        raise ValueError(f'{len(o.inputs)} temperature inputs named but windows carry '
                         f'{windows.n_inputs}')
    ids, means = windows.hold_means()
    _check_accel_units(means, o.gravity)
    _check_gyro_units(windows, ids, means, o.transitions)
    windows, o, flat = _without_flat_temperature(windows, o)
    windows, o, pose = _mounting_pose_only(windows, o)
    windows, earth = _without_vertical_earth_rate(windows, o)
    ctx = make_context(windows, o)
    consistency = leave_out_holds(ctx)
    accel_input, gyro_input, units = ctx.accel_input, ctx.gyro_input, input_units(o, ctx.k)
    name, why = ((o.model, 'requested') if o.model != 'auto'
                 else AUTO_POLICY[0](ctx.accel_view()))
    est = ESTIMATORS[name](ctx)
    notes = flat + pose + earth + consistency_notes(consistency) + list(est.notes)
    levels = o.level_sensors()
    if levels:
        notes.append(f'placement levels: the {" and ".join(levels)} thermal fits '
                     'give each hold a level of its own (a random effect, REML), so a tilt '
                     'or heading that differs from stop to stop is not read as temperature')
    floor = why.split(f'; {FLOOR_REASON}', 1)
    if o.model == 'auto' and len(floor) == 2:   # the thermal family judged by the floor
        notes.append(f'auto, a thermal family judged {FLOOR_REASON}{floor[1]}')
    report = {'coverage': ctx.coverage, 'distinct_orientations': ctx.n_orientations,
              'model_choice': {'model': name, 'reason': why}, **est.report}
    gyro_model = est.gyro
    if gyro_model is None:
        gyro_model, gyro_report, gyro_notes = DEFAULT_GYRO[0](ctx, est)
        report.update(gyro_report)
        notes += gyro_notes
    cov = ctx.coverage
    g = o.gravity
    cal = Calibration(
        accel=est.accel, gyro=gyro_model, inputs=list(o.inputs),
        valid_range=valid_range(windows, o),
        out_of_range=o.out_of_range, accel_input=accel_input, gyro_input=gyro_input,
        frame_id=o.frame_id, gravity=g, gravity_source=o.gravity_source,
        accel_noise_std=np.sqrt(np.median(windows.accel_var, axis=0)),
        gyro_noise_std=np.sqrt(np.median(windows.gyro_var, axis=0)), notes=notes,
        temperature_filter=est.temperature_filter, noise_model=window_noise(windows))
    narrow_high_order(cal, windows, o)
    with_restart_spread(cal, windows)
    before, after = gravity_residuals(ctx.accel_view().windows, cal, g)
    fit_stats = dict(est.fit)
    fit_stats.update({
        'hold_consistency': consistency,
        'model_choice': _model_choice(name, why, report),
        'holds': cov['holds'], 'windows': cov['windows'],
        'distinct_orientations': ctx.n_orientations,
        'faces': {f: cov['faces'][f]['holds'] for f in FACE_NAMES},
        'tilted_holds': cov['tilted_holds'],
        'temperature_span': cov['temperature_span'],
        'valid_range_margin': _margin_report(windows, o),
        'gravity_residual_ug': {'before_rms': _rms(before), 'after_rms': _rms(after),
                                'before_max': _amax(before), 'after_max': _amax(after),
                                'note': 'per hold, |mean f| - g in micro-g, on the fit data'},
    })
    if alarm_yardstick.needed(name, ctx.n_orientations, est.accel,
                              lab_s=ctx.prior_model is not None):
        fit_stats['alarm_yardstick'] = alarm_yardstick.yardstick(ctx)
    rot = _rotation_stats(est.fit, report)
    if o.transitions or rot:
        fit_stats['pose_changes'] = report['pose_changes'] = {
            'collected': len(o.transitions), 'used': int(rot.get('rotations_used', 0))}
    if 'rotation_direction_error_deg' in rot:
        fit_stats['rotation_direction_error_deg'] = rot['rotation_direction_error_deg']
    if levels:
        fit_stats['placement_levels'] = list(levels)
    cal.fit = fit_stats
    kind = est.accel.kind if est.accel is not None else 'gyro bias only'
    if name == 'standard':
        kind = 'standard static fit (imu_tk)'
    cal.notes = list(cal.notes) + _adequacy_notes(fit_stats, kind)
    summary = (f'{kind}: {cov["holds"]} holds ({cov["windows"]} windows), faces '
               f'{_face_text(cov)}, {_span_text(cov, units)}, gravity residual '
               f'{_amax(before):.0f} -> {_amax(after):.1f} ug max')
    if flat:
        summary += ' (the temperature input barely moved: treated as none, see notes)'
    if pose:
        summary += (f' ({len(ids) - cov["holds"]} of {len(ids)} holds off the mounting pose by '
                    f'more than {MOUNTING_POSE_DEG:g} deg not used, see notes)')
    if consistency['left_out']:
        summary += (f', {len(consistency["left_out"])} holds left out of the accelerometer '
                    'fit (pose repeats that disagree, sensor-state epochs; held-out holds '
                    'support it; see notes)')
    elif consistency.get('not_applied'):
        summary += (f', {len(consistency["not_applied"])} holds disagree with a repeat of '
                    'their pose but stay in (held-out holds do not support leaving them out)')
    if 'residual_rms' in fit_stats:
        summary += f', fit residual {fit_stats["residual_rms"]["value"] * 1e6 / g:.1f} ug RMS'
    gyro_text = report.get('gyro_choice', {}).get('text')
    summary += _pose_change_text(rot, len(o.transitions))
    summary += f'; {gyro_text}' if gyro_text else ''
    return CalibrationResult(cal, summary, report)
