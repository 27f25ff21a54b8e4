"""What a calibration run tells people: its summary line, notes and fit report parts.

The faces and temperature span of the summary, the valid-range margin and model choice of
``fit``, the clause on the pose changes between holds, the note on an inadequate fit
(``ADEQUACY_CHI2``) and the per-hold gravity residuals before and after the calibration.
"""

import numpy as np

from ..collection.segments import FACE_NAMES
from ..input_units import DEGC, is_temperature
from .options import input_margins, input_units


def _margin_report(windows, options):
    units = input_units(options, windows.n_inputs)
    if all(map(is_temperature, units)) and not options.unit_margins:
        return {'value': options.range_margin, 'unit': DEGC}
    return {'value': input_margins(windows, options).tolist(), 'unit': units,
            'note': 'per input; a proxy without an explicit margin gets range_margin degC '
                    'scaled by its span relative to the degC inputs\''}


def _face_text(cov):
    parts = []
    for f in FACE_NAMES:
        n = cov['faces'][f]['holds']
        if n:
            parts.append(f'{f}({n})' if n > 1 else f)
    if cov['tilted_holds']:
        parts.append(f'{cov["tilted_holds"]} tilted')
    return ' '.join(parts) or 'none'


def _span_text(cov, units=None):
    span = cov['temperature_span']
    if not span:
        return 'no temperature'
    units = units if units and len(units) == len(span) else [DEGC] * len(span)
    return ', '.join(f'{lo:.1f}-{hi:.1f} {u}' for (lo, hi), u in zip(span, units))


def _model_choice(name, why, report):
    """Return fit.model_choice: the model, why, and the gyro comparison with pose changes."""
    out = {'model': name, 'reason': why}
    if 'heldout' in report:       # every candidate's held-out figure (one orientation)
        out['heldout'] = report['heldout']
    gyro = report.get('gyro_choice', {})
    if 'text' in gyro:
        out['gyro'] = {'model': gyro['model'], 'reason': gyro['text'],
                       'heldout': gyro['candidates']}
    return out


def _rotation_stats(fit, report):
    """Return the stats of the gyro fit that could use pose changes ({} if none ran).

    The estimator's own gyro (``whole_unit``) reports them in its fit, the seed 002 gyro
    chosen for an accelerometer-only estimator in ``report['gyro_whole_unit']``.
    """
    for stats in (fit, report.get('gyro_whole_unit') or {}):
        if 'rotations_used' in stats:
            return stats
    return {}


def _pose_change_text(rot, collected):
    """Return the summary's clause on the pose changes between holds."""
    if rot and not collected:
        return (', no pose changes between holds: gyro scale and misalignment stay at their '
                'prior')
    if not collected:
        return ''
    if not rot:
        return (f', {collected} pose changes collected but not used (the gyro model chosen has '
                'no scale or misalignment terms)')
    return (f', {rot["rotations_used"]} of {collected} pose changes used for gyro scale and '
            'misalignment')


#: chi2/dof of the accelerometer fit above which the notes say the model is inadequate
#: (a device the model describes gives ~1-1.3; errors outside it, 3 and more)
ADEQUACY_CHI2 = 2.5


def _adequacy_notes(fit_stats, kind):
    """Return a note when the fit residuals are well above what the sensor noise explains."""
    chi2 = fit_stats.get('chi2_per_dof')
    if chi2 is None or not np.isfinite(chi2) or chi2 <= ADEQUACY_CHI2:
        return []
    return [f'fit inadequate: the residuals are {np.sqrt(chi2):.1f}x what the sensor noise '
            f'explains (chi2/dof {chi2:.1f} > {ADEQUACY_CHI2:g}); the device has errors the '
            f'{kind} model does not describe (higher-order or lagged thermal response, '
            'hysteresis, bias wander), so the error left after compensation can exceed the '
            'reported std. Check it on an independent recording (thermal-imu-calib '
            'evaluate), or record longer holds over a slower warm-up']


def gravity_residuals(windows, cal, g):
    """Return per-hold |mean f| - g in micro-g, before and after ``cal`` (fit data)."""
    ids = windows.hold_ids
    before = np.zeros(len(ids))
    after = np.zeros(len(ids))
    temps = windows.temp if windows.n_inputs else None
    if temps is not None and cal.temperature_filter is not None:
        temps = cal.temperature_filter.window_temperatures(windows)
    res = cal.apply(windows.accel, windows.gyro, temps)
    for j, h in enumerate(ids):
        m = windows.hold == h
        wts = windows.n[m]
        before[j] = np.linalg.norm(np.average(windows.accel[m], 0, wts)) - g
        after[j] = np.linalg.norm(np.average(res.accel[m], 0, wts)) - g
    return before / g * 1e6, after / g * 1e6


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def _amax(x):
    return float(np.max(np.abs(x))) if len(x) else 0.0
