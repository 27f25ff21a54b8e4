"""The estimate's other calibrations: the gyro ageing removed, a kept history, a refit.

A lifelong estimate is the plain fit of the store's windows in the mounting pose, the
newest ``holdout_holds`` holds held out for the swap gate (``manager.Lifelong.estimate``).
These make the other calibrations it judges or puts in use instead:

* ``with_ageing``: the fit with the gyro ageing removed (``ageing``), kept only when the
  held-out holds prefer it by more than their noise (``LifelongConfig.ageing``);
* ``with_kept``: after a change alarm that cut one sensor's history only
  (``alarm_cut`` 'sensor'), the other sensor's model fitted on its kept history too and
  composed with the new estimate's model of the sensor that changed;
* ``refit``: the swap's calibration fitted again, with the same choices, on every hold
  (``refit_on_swap``).

Each takes ``calibrate``, the loop's fit (windows -> ``app.calibrate.calibrate_collected``'s
result, ``manager.Lifelong._calibrate``), and records in the decision dict what it did.
Times in s, gyro errors in rad/s. No ROS import.
"""

import numpy as np

from ..app.calibrate import SettingsError
from ..calibration import CalibrationError
from ..estimation.calibrate import CalibrationRefused
from . import ageing, compose, gate
from .pose import main_pose_mask

#: what a fit raises when the holds do not allow a calibration (the loop records a refusal)
REFUSALS = (CalibrationRefused, SettingsError, CalibrationError, ValueError)


def with_ageing(calibrate, fit, times, now, holdout, pose, s_plain, decision, config,
                latitude):
    """Return (result, score) of the fit with the gyro ageing removed, when it is better.

    The gyro ageing rate is estimated jointly with a cubic in temperature
    (``ageing.trend``); when an axis' rate is resolved, the fit is repeated with every
    window's gyro mean moved to ``now`` (``ageing.detrended``), and that estimate is
    kept only when its gyro error on the held-out holds is lower than the plain fit's
    by more than their noise (``gate.decide``'s gyro verdict, the swap gate's margin).
    Returns None otherwise; the decision records the rates and both figures.
    ``fit``, ``times`` (s): the plain fit's windows and their mean times; ``holdout``,
    ``pose``: the held-out holds (all, and those in the mounting pose); ``s_plain``: the
    plain fit's ``gate.score`` on them; ``config``: the ``LifelongConfig``; ``latitude``
    (deg or None): see ``gate.score``.
    """
    if not config.ageing:
        return None
    found = ageing.trend(fit, times, now)
    if found is None or not found.resolved.any():
        if found is not None:
            decision['ageing'] = {'text': found.text(), 'used': False}
        return None
    try:
        result = calibrate(ageing.detrended(fit, times, now, found))
    except REFUSALS as e:
        decision['ageing'] = {'text': f'{found.text()}; the fit without it refused ({e})',
                              'used': False}
        return None
    score = gate.score(result.calibration, holdout, result.calibration.gravity, pose,
                       latitude, config.accel_score)
    _, fig = gate.decide(s_plain, score, config.swap_sigmas)
    used = fig['gyro']['verdict'] == 'better'
    plain_md, aged_md, margin_md = (np.degrees(x) * 1e3 for x in (
        s_plain['gyro_rms'], score['gyro_rms'], fig['gyro']['margin']))
    decision['ageing'] = {
        'text': (f'{found.text()}; held-out gyro RMS {plain_md:.3g} mdeg/s as fitted, '
                 f'{aged_md:.3g} with the ageing removed (margin {margin_md:.2g}): '
                 f'{"removed" if used else "not removed"}'),
        'margin': fig['gyro']['margin'],
        'used': used, 'rate_rad_s_per_day': found.rate, 'std_rad_s_per_day': found.std,
        'heldout_gyro_rms': [s_plain['gyro_rms'], score['gyro_rms']]}
    if used and config.gyro_ageing_forward:
        result.calibration.gyro_ageing = {'rate': found.applied, 'epoch': float(now),
                                          'max_days': float(found.span_days)}
        carried_text = (f'carried forward in the file for up to {found.span_days:.1f} '
                        'days')
        decision['ageing']['text'] += '; ' + carried_text
        result.calibration.notes.append(f'gyro ageing: {found.text()}, {carried_text} from '
                                        f'the estimate\'s time (gyro_ageing)')
        score = gate.score(result.calibration, holdout, result.calibration.gravity, pose,
                           latitude, config.accel_score)
    return (result, score) if used else None


def with_kept(calibrate, store, pose_deg, new, now, held, decision):
    """Return ``new`` with one sensor's model fitted on its kept history too, or None.

    After a change alarm that cut one sensor's history (``alarm_cut`` 'sensor'), the
    other sensor keeps the holds from before it (``HoldStore.cut``): its model is
    fitted on them and this epoch's holds (the held-out ones, ``held``, left out, as
    always; those within ``pose_deg`` of the mounting pose) and composed with ``new``'s
    model of the sensor that changed. None: nothing is kept, or that fit or the
    composition fails (the decision says so and ``new`` is used).
    """
    which = next((w for w in compose.SENSORS if store.has_kept(w)), None)
    if which is None:
        return None
    windows, _ = store.fit_windows(now, exclude=held, sensor=which)
    fit = windows.select(main_pose_mask(windows, pose_deg))
    try:
        long = calibrate(fit).calibration
        pick = {which: long, 'gyro' if which == 'accel' else 'accel': new}
        cal = compose.compose(pick['accel'], pick['gyro'],
                              note=f'the {which} fitted on its history kept across a '
                                   'change alarm of the other sensor')
    except REFUSALS as e:
        decision['kept_history'] = {'sensor': which, 'used': False,
                                    'text': f'{which} on its kept history: not used ({e})'}
        return None
    decision['kept_history'] = {
        'sensor': which, 'used': True, 'holds': int(len(fit.hold_ids)),
        'text': f'{which} fitted on {len(fit.hold_ids)} holds with its history kept '
                'across a change alarm of the other sensor'}
    return cal


def refit(calibrate, store, config, active, judged, now, decision, only=None):
    """Return (the swap's calibration fitted again on every hold or ``judged``, the windows).

    The gate judged ``judged``, fitted without the newest holds; the same procedure
    (the calibrate code's own choice, the gyro ageing removed when the judged estimate
    removed it, the kept history of a sensor, one sensor's model only when ``only``
    names it, the other taken from ``active``) runs again on every hold, so the
    calibration put in use covers the newest temperatures too. A refit that fails or does
    not compose leaves ``judged`` in use; ``decision['refit']`` says which. The windows
    are those the refit fitted (or tried to).
    """
    everything, times = store.fit_windows(now)
    in_pose = main_pose_mask(everything, config.pose_deg)
    fit, times = everything.select(in_pose), times[in_pose]
    scratch = {}
    try:
        found = ageing.trend(fit, times, now) \
            if decision.get('ageing', {}).get('used') else None
        if found is not None and found.resolved.any():
            fit = ageing.detrended(fit, times, now, found)
        cal = calibrate(fit).calibration
        if decision.get('kept_history', {}).get('used'):
            kept = with_kept(calibrate, store, config.pose_deg, cal, now, (), scratch)
            if kept is None:
                raise ValueError(scratch.get('kept_history', {}).get('text', 'kept history'))
            cal = kept
        if only:
            cal, why = compose.with_sensor(
                active, cal, only, config.raw_kept,
                f'the {only} fitted again on every hold after passing the gate; the '
                'other sensor kept')
            if why:
                raise ValueError(why)
    except REFUSALS as e:
        decision['refit'] = {'used': False, 'text': f'not fitted again on every hold ({e}); '
                                                    f'the judged estimate {judged.id} is used'}
        return judged, fit
    decision['refit'] = {'used': True, 'judged_id': judged.id, 'holds': int(len(fit.hold_ids)),
                         'text': f'in use: {cal.id}, fitted again on all {len(fit.hold_ids)} '
                                 f'holds (the held-out ones too) after {judged.id} passed'}
    return cal, fit
