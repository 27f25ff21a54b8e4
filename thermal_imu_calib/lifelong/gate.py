"""The swap gate: score calibrations on held-out holds, decide whether a new one replaces.

Per held-out hold (windows of one unknown orientation, ``collection.segments.Windows``)
the calibration compensates the window means at their temperatures and the hold is
reduced to its sample-weighted mean:

* gyro error: ``|mean gyro|`` (rad/s): a still gyro reads the earth rate only
  (<= 7.3e-5 rad/s, the same for every calibration compared). With the latitude known the
  earth rate is no longer part of the error: its vertical part (``EARTH_RATE`` sin(lat)
  along the hold's specific force) is known, and so is the size of its horizontal part
  (``EARTH_RATE`` cos(lat)), whose direction depends on the unknown heading; the error is
  then ``sqrt(v^2 + (|h| - EARTH_RATE cos(lat))^2)`` with v the mean's vertical part less
  the known one and h its horizontal part (a calibration fitted with the latitude leaves
  the earth rate in its output). Without it the earth rate's 5e-5 rad/s at a random
  heading is in every hold's error and hides biases of that size;
* accelerometer error: ``|mean accel| - g`` (m/s^2) *centred* on its median over the
  held-out holds in the mounting pose (the gyro is judged on all of them): in one
  mounting pose bias and scale are not separable from gravity and the single-orientation
  (offset) model leaves a constant that depends on its reference temperature, so only the
  change between holds is compared;
* noise: the standard error of each hold mean (``sqrt(var / n)``, per-sample variance of
  its windows), the floor no calibration can go below.

``decide``: per sensor the *margin* is the noise of the comparison: the larger of the RMS
standard error of the hold means and ``sigmas`` times the standard error of the paired
per-hold difference. The new calibration replaces the active one only when, on holds it
did not see, its RMS error is lower by more than the margin for the gyro or the
accelerometer (verdict 'better'), and the two gains in units of their margins add up to
more than one margin (a large gain of one sensor outweighs a small loss of the other;
a loss as large as the gain keeps the active one).
Without an active calibration the raw output is the reference.
"""

import numpy as np

from ..estimation.gyro_static import earth_rate_parts

#: how ``score`` measures the accelerometer's error on a held-out hold
ACCEL_SCORES = ('magnitude', 'vector')


def hold_errors(cal, windows, gravity, latitude=None):
    """Return per-hold arrays: ids, t (s, end), temp (degC), gyro, accel, se_gyro, se_accel.

    ``cal`` None: the raw output. ``latitude`` (deg): the gyro error leaves the earth rate
    out (see the module docstring), and ``gyro_vec`` is the mean less its vertical part.
    """
    if latitude is not None:
        vertical, horizontal = earth_rate_parts(latitude)
    ids = windows.hold_ids if len(windows) else np.zeros(0, int)
    temps = windows.temp if windows.n_inputs else None
    if not len(windows):
        acc, gyr = windows.accel, windows.gyro
    elif cal is None:
        acc, gyr = windows.accel, windows.gyro
    else:
        if temps is not None and cal.temperature_filter is not None:
            temps = cal.temperature_filter.window_temperatures(windows)
        res = cal.apply(windows.accel, windows.gyro, temps,
                        stamps=0.5 * (windows.t0 + windows.t1))   # a gyro ageing term's time
        acc, gyr = res.accel, res.gyro
    h = len(ids)
    out = {'ids': ids, 't': np.zeros(h), 'temp': np.full(h, np.nan), 'gyro': np.zeros(h),
           'accel': np.zeros(h), 'se_gyro': np.zeros(h), 'se_accel': np.zeros(h),
           'gyro_vec': np.zeros((h, 3)), 'accel_vec': np.zeros((h, 3))}
    for j, hid in enumerate(ids):
        m = windows.hold == hid
        w = windows.n[m].astype(float)
        n = w.sum()
        a = np.average(acc[m], 0, w)
        g = np.average(gyr[m], 0, w)
        if latitude is None:
            out['gyro'][j] = np.linalg.norm(g)
        else:
            up = a / max(np.linalg.norm(a), 1e-12)
            v = float(g @ up)
            h = np.linalg.norm(g - v * up)
            out['gyro'][j] = np.hypot(v - vertical, h - horizontal)
            g = g - vertical * up
        out['gyro_vec'][j] = g
        out['accel_vec'][j] = a
        out['accel'][j] = np.linalg.norm(a) - gravity
        out['se_gyro'][j] = np.sqrt(np.mean(np.average(windows.gyro_var[m], 0, w)) / n)
        out['se_accel'][j] = np.sqrt(np.mean(np.average(windows.accel_var[m], 0, w)) / n)
        out['t'][j] = float(windows.t1[m].max())
        if windows.n_inputs:
            out['temp'][j] = float(np.average(windows.temp[m, 0], weights=w))
    return out


def limit(errors, which, rms, factor, floor):
    """Return the (h,) per-hold limit of ``misses`` for one sensor.

    ``which``: 'gyro' (rad/s) or 'accel' (m/s^2). ``factor`` times ``rms``, at least
    ``floor`` times the hold's own standard error.
    """
    return np.maximum(factor * rms, floor * errors['se_' + which])


def misses(errors, accel_median, gyro_rms, accel_rms, factor, floor):
    """Return the (h,) mask of the holds a calibration misses.

    ``errors``: ``hold_errors`` of that calibration. A hold is missed when its gyro error
    exceeds ``factor`` times ``gyro_rms`` (rad/s, the calibration's own held-out error), or
    its accelerometer error less ``accel_median`` (m/s^2) exceeds ``factor`` times
    ``accel_rms``; each limit is at least ``floor`` times the hold's own standard error
    (``limit``). The change alarm's limit, per hold.
    """
    g = np.abs(errors['gyro']) > limit(errors, 'gyro', gyro_rms, factor, floor)
    a = np.abs(errors['accel'] - accel_median) > limit(errors, 'accel', accel_rms, factor,
                                                       floor)
    return g | a


def unexplained(s_new, state, config, has_active):
    """Return why a swap is refused because the new calibration misses the newest holds too.

    '' when it is not. Only with ``LifelongConfig.swap_must_explain`` (on by default since
    2026-12-06; docs/lifelong.md). ``s_new``: the new calibration's ``score``; ``state``:
    the lifelong state (``active_gyro_rms``, the change alarm's gyro reference, rad/s).

    A swap re-measures the change alarm's reference on the new calibration. When the
    newest (held-out) holds are ones the new calibration also misses, by the alarm's
    per-hold gyro limit against the active's reference (``misses``), the holds say the
    sensor changed, not that the new model is better: after seed 2's knock the gate called
    such estimates "better" (107 -> 106 mdeg/s on holds the active fitted to 2), and each
    swap raised the reference until the alarm came 21 h late. At least ``misfit_holds``
    such holds keep the active calibration, so the alarm can see the change. Not after an
    alarm (the reference is the old sensor's) nor without an active calibration.
    """
    c = config
    if not c.swap_must_explain or not has_active or state.get('alarm_pending') \
            or state.get('active_gyro_rms') is None:
        return ''
    e = s_new['errors']
    lim = limit(e, 'gyro', state['active_gyro_rms'], c.alarm_factor, c.alarm_floor)
    missed = int(np.sum(np.abs(e['gyro']) > lim))
    if missed < c.misfit_holds:
        return ''
    return (f'; not swapped: the new calibration also misses {missed} of the '
            f'{len(e["gyro"])} held-out holds (gyro error > {float(np.min(lim)):.3g} rad/s, '
            'the change alarm\'s limit): the sensor may have changed')


def rms(x):
    """Return the root mean square of ``x`` (its unit), NaN when ``x`` is empty."""
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float('nan')


def score(cal, windows, gravity, accel_windows=None, latitude=None, accel_score='magnitude'):
    """Return {'gyro_rms', 'accel_rms', 'noise_gyro', 'noise_accel', 'holds', errors}.

    The gyro is scored on every hold of ``windows``, the accelerometer on those of
    ``accel_windows`` (default: the same; the node passes the holds in the mounting pose).
    ``latitude``: see ``hold_errors``. ``accel_score`` (one of ``ACCEL_SCORES``):
    'magnitude', each hold's ``|mean accel| - g`` about their median (blind to the
    horizontal axes in a level mounting pose); 'vector', the length of each hold's mean
    accel vector less the per-axis median of the holds: the horizontal axes count too,
    with the floor's tilt from stop to stop in their scatter (the noise is then that of
    three axes). ``accel_magnitude_rms`` is the 'magnitude' figure either way (the change
    alarm's reference).
    """
    if accel_score not in ACCEL_SCORES:
        raise ValueError(f'accel_score {accel_score!r} is not one of {", ".join(ACCEL_SCORES)}')
    e = hold_errors(cal, windows, gravity, latitude)
    ea = e if accel_windows is None else hold_errors(cal, accel_windows, gravity, latitude)
    noise_a = rms(ea['se_accel'])
    mag = ea['accel'] - np.median(ea['accel']) if len(ea['accel']) else ea['accel']
    acc = mag
    if accel_score == 'vector' and len(mag):
        v = ea['accel_vec']
        acc = np.linalg.norm(v - np.median(v, 0), axis=1)
        noise_a *= np.sqrt(3.0)
    return {'holds': int(len(e['ids'])), 'accel_holds': int(len(ea['ids'])),
            'gyro_rms': rms(e['gyro']), 'accel_rms': rms(acc),
            'accel_magnitude_rms': rms(mag),
            'noise_gyro': rms(e['se_gyro']), 'noise_accel': noise_a,
            'gyro': e['gyro'], 'accel': acc, 'errors': e}


def compare(active, new, noise, sigmas=2.0):
    """Return one sensor's figures: per-hold errors of two calibrations on the same holds.

    ``active``, ``new``: (h,) errors (their unit); ``noise``: the RMS standard error of the
    hold means. The margin is the larger of ``noise`` and ``sigmas`` times the standard error
    of the paired difference of |error|; the verdict is 'better' when the new RMS is lower
    by more than the margin, 'worse' when higher by more, else 'same'.
    """
    if len(new) == 0:
        return {'active_rms': float('nan'), 'new_rms': float('nan'), 'gain': 0.0,
                'margin': 0.0, 'noise': 0.0, 'paired_se': float('inf'), 'verdict': 'same'}
    paired = np.abs(active) - np.abs(new)
    se = float(np.std(paired, ddof=1) / np.sqrt(len(paired))) if len(paired) > 1 \
        else float('inf')
    margin = max(noise, sigmas * se)
    gain = rms(active) - rms(new)
    return {'active_rms': rms(active), 'new_rms': rms(new), 'gain': gain, 'margin': margin,
            'noise': noise, 'paired_se': se,
            'verdict': 'better' if gain > margin else ('worse' if -gain > margin else 'same')}


def decide(active, new, sigmas=2.0):
    """Return (swap: bool, figures dict) from two ``score`` results on the same holds."""
    fig = {'holds': new['holds']}
    verdict = {}
    for which in ('gyro', 'accel'):
        fig[which] = compare(active[which], new[which], new[f'noise_{which}'], sigmas)
        verdict[which] = fig[which]['verdict']
    net = sum(fig[w]['gain'] / fig[w]['margin'] for w in ('gyro', 'accel')
              if fig[w]['margin'] > 0 and np.isfinite(fig[w]['margin']))
    fig['net_margins'] = float(net)
    swap = 'better' in verdict.values() and net > 1.0
    return swap, fig


def describe(fig):
    """Return the figures of a decision as one line (units: gyro mdeg/s, accel mm/s^2)."""
    parts = []
    for which, scale, unit in (('gyro', np.degrees(1.0) * 1e3, 'mdeg/s'),
                               ('accel', 1e3, 'mm/s^2')):
        f = fig[which]
        parts.append(f'{which} RMS {f["active_rms"] * scale:.3g} -> {f["new_rms"] * scale:.3g}'
                     f' {unit} (margin {f["margin"] * scale:.2g}: {f["verdict"]})')
    return (f'{fig["holds"]} held-out holds: ' + '; '.join(parts)
            + f'; net gain {fig.get("net_margins", 0.0):+.1f} margins')
