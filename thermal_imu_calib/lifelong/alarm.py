"""The change alarm (a knock): new holds scored with the active calibration, and its limits.

Every new hold inside the active valid range (``alarm_ranges``; ``alarm_window`` 'common':
inside both sensors' ranges, 'sensor': each sensor's own) is kept as a ``Tracked`` hold
with the active calibration's errors (``tracked``). When, for one sensor, the last
``alarm_holds`` of them all exceed ``alarm_factor`` times the active's held-out error
(floored at ``alarm_floor`` times their noise; ``exceeded``), the store is cut at the first
of them (``first_hold_start``: older data no longer describe the sensor), an alarm is
logged (``alarm_decision``) and a re-estimate from the holds after the cut follows. With
``alarm_cut`` 'sensor' an alarm of one sensor cuts that sensor's history only: the other's
model is still fitted on the older holds too (``variants.with_kept``). With ``alarm_cut``
'shift' the holds before the change are moved by the step of the biases the holds
after the change show against the active calibration (``knock_step``, ``HoldStore.shift``).

The alarm's limit serves two more ends: the new holds the active calibration misses
(``new_misses``, ``trigger.due``'s misfit trigger) and the holds a swap measures the
alarm's new reference on (``reference_holds``). ``manager.Lifelong`` applies what these
return to its state, store and decision log. Units: s, degC, rad/s, m/s^2. No ROS import.
"""

from typing import NamedTuple

import numpy as np

from . import compose, gate


class Tracked(NamedTuple):
    """A hold the change alarm watches: its time and the active calibration's errors."""

    t: float            #: end of the hold (s)
    gyro: float         #: gyro error (rad/s)
    accel: float        #: accelerometer error less the active's median (m/s^2)
    se_gyro: float      #: the hold's standard error of its gyro mean (rad/s)
    se_accel: float     #: ... of its accelerometer mean (m/s^2)
    in_gyro: bool       #: inside the gyro's alarm range (``alarm_ranges``)
    in_accel: bool      #: inside the accelerometer's alarm range


def alarm_ranges(cal, k, window, sensors='every'):
    """Return {sensor: (lo, hi) degC} inside which a hold counts for that sensor's alarm.

    ``cal``: the active calibration; ``k``: the number of thermal inputs; ``window``:
    ``LifelongConfig.alarm_window``; ``sensors``: ``LifelongConfig.range_sensors`` (with
    'sensor', a sensor whose range bounds nothing, ``compose.bounds_range``, watches the
    valid range).
    """
    if cal.valid_range is None or not k:
        return {w: (-np.inf, np.inf) for w in compose.SENSORS}
    if window == 'sensor':
        return {w: tuple(np.asarray(cal.own_range(w) if compose.bounds_range(cal, w, sensors)
                                    else cal.valid_range)[0]) for w in compose.SENSORS}
    common = tuple(compose.common_range(cal, sensors)[0])
    return {w: common for w in compose.SENSORS}


def new_misses(e, state, config):
    """Return [[t s, temperature degC]] of the new holds the active calibration misses.

    ``e``: ``gate.hold_errors`` of the active calibration on the new holds; ``state``: the
    loop's counters, whose ``active_*`` figures are the alarm's reference (none yet: []);
    ``config``: the ``LifelongConfig`` (``gate.misses``' factor and floor).
    """
    s, c = state, config
    if s.get('active_gyro_rms') is None:
        return []
    bad = gate.misses(e, s.get('active_accel_median') or 0.0, s['active_gyro_rms'],
                      s.get('active_accel_rms') or 0.0, c.alarm_factor, c.alarm_floor)
    return [[float(e['t'][j]), float(e['temp'][j])] for j in np.flatnonzero(bad)]


#: holds the change alarm's track keeps (the newest)
TRACK_HOLDS = 200


def tracked(track, e, ranges, base_acc):
    """Return ``track`` with the new holds inside an alarm range added (newest ``TRACK_HOLDS``).

    ``e``: ``gate.hold_errors`` of the active calibration on the new holds; ``ranges``:
    ``alarm_ranges``; ``base_acc``: the active's accelerometer level (m/s^2), taken off
    each hold's accelerometer error.
    """
    track = list(track)
    for j in range(len(e['ids'])):
        inside = [bool(lo <= e['temp'][j] <= hi) for lo, hi in
                  (ranges['gyro'], ranges['accel'])]
        if not any(inside):
            continue
        track.append(Tracked(float(e['t'][j]), float(e['gyro'][j]),
                             float(e['accel'][j] - base_acc), float(e['se_gyro'][j]),
                             float(e['se_accel'][j]), *inside))
    return track[-TRACK_HOLDS:]


def exceeded(track, state, config):
    """Return ({sensor: (median error, limit)}, [end (s) of the first hold of each]).

    A sensor is in it when its last ``alarm_holds`` holds of ``track`` all exceed
    ``alarm_factor`` times its reference in ``state`` (``active_gyro_rms`` rad/s,
    ``active_accel_rms`` m/s^2), at least ``alarm_floor`` times the median of their
    standard errors. Empty: no alarm.
    """
    out, first = {}, []
    for which, last, err, limit in _newest_scored(track, state, config):
        if len(last) == config.alarm_holds and np.all(err > limit):
            out[which] = (float(np.median(err)), limit)
            first.append(last[0].t)
    return out, first


def _newest_scored(track, state, config):
    """Yield (sensor, newest holds, their |errors|, the alarm's limit) per tracked sensor.

    The holds are the sensor's newest ``alarm_holds`` of ``track`` (SI units). The limit
    is ``alarm_factor`` times the sensor's reference in ``state``, at least
    ``alarm_floor`` times the median of those holds' standard errors.
    """
    c = config
    for which in ('gyro', 'accel'):
        last = [r for r in track if getattr(r, 'in_' + which)][-c.alarm_holds:]
        if not last:
            continue
        err = np.abs([getattr(r, which) for r in last])
        base = state.get(f'active_{which}_rms') or 0.0
        floor = c.alarm_floor * float(np.median([getattr(r, 'se_' + which) for r in last]))
        yield which, last, err, max(c.alarm_factor * base, floor)


def pending_since(track, state, config):
    """Return the end (s) of the first hold of a run the alarm is still deciding, or None.

    A sensor's run: its newest holds of ``track`` that all exceed the alarm's limit (as
    ``exceeded`` will judge them, on its newest ``alarm_holds``), at least one and fewer
    than ``alarm_holds``: the alarm fires if the next ones miss too. With several, the
    earliest. None without a reference (``active_gyro_rms``) or a run.
    """
    if state.get('active_gyro_rms') is None:
        return None
    starts = []
    for _, last, err, limit in _newest_scored(track, state, config):
        run = 0
        while run < len(err) and err[-1 - run] > limit:
            run += 1
        if 0 < run < config.alarm_holds:
            starts.append(last[-run].t)
    return min(starts) if starts else None


def first_hold_start(recent, t_end):
    """Return the start (s) of the raw hold of ``recent`` (the store's) ending at ``t_end``.

    Matched to the millisecond: a relative tolerance on stamps of ~1.7e9 s (np.isclose's
    default, used before 2026-11-28) matched any hold ending within ~4.8 h, so the cut
    kept up to hours of holds from before the change in the new epoch.
    """
    rec = recent
    m = np.isclose(rec.t1, t_end, rtol=0.0, atol=1e-3) if len(rec) else np.zeros(0, bool)
    if not m.any():
        return t_end
    h = rec.hold[m][0]
    return float(rec.t0[rec.hold == h].min())


def alarm_decision(out, t_cut, t_now, config, moved=None):
    """Return (the alarm's decision dict, the sensor that keeps its older holds or None).

    ``out``: ``exceeded``'s sensors; ``t_cut`` (s): where the store is cut; ``t_now`` (s):
    the newest tracked hold's end. A sensor keeps its history only with ``alarm_cut``
    'sensor' and an alarm of the other sensor alone. ``moved``: ``step``'s result when
    the older holds are shifted by it instead (``alarm_cut`` 'shift'; ``knock_step.step``).
    """
    c = config
    text = '; '.join(f'{w} error {v:.3g} > {lim:.3g} on the last {c.alarm_holds} '
                     'holds in range' for w, (v, lim) in out.items())
    keep = None
    if c.alarm_cut == 'sensor' and len(out) == 1:
        keep = 'accel' if 'gyro' in out else 'gyro'
    if moved is not None:
        began = (f'; it began {moved["earlier"]} hold{"s" if moved["earlier"] != 1 else ""} '
                 'before the first of them' if moved['earlier'] else '')
        dropped = (f'holds before t={moved["t"]:.0f} s shifted by the step the holds after '
                   f'it show (gyro {np.linalg.norm(moved["gyro"]):.3g} rad/s, accel '
                   f'{np.linalg.norm(moved["accel"]):.3g} m/s^2; {moved["after"]} holds '
                   f'after, {moved["before"]} before{began}'
                   + (f'; {len(moved["drop"])} holds between dropped' if moved['drop'] else '')
                   + '), re-estimating from every hold')
    elif keep is None:
        dropped = (f'holds before t={t_cut:.0f} s dropped, re-estimating from the holds '
                   'after it')
    else:
        dropped = (f'holds before t={t_cut:.0f} s dropped for the {next(iter(out))} (the '
                   f'{keep} keeps them), re-estimating from the holds after it')
    decision = {'time': t_now, 'action': 'alarm',
                'reason': f'the active calibration no longer fits: {text}; {dropped}',
                'figures': out}
    if moved is not None:
        decision['step'] = {'t': float(moved['t']), 'earlier_holds': int(moved['earlier']),
                            'gyro_rad_s': [float(x) for x in moved['gyro']],
                            'accel_m_s2': [float(x) for x in moved['accel']],
                            'dropped_holds': len(moved['drop']),
                            'holds_after': int(moved['after']),
                            'holds_before': int(moved['before'])}
    return decision, keep


def reference_holds(both, errs, before, config, alarm_pending, only=None):
    """Return ({sensor: (h,) mask of the holds its alarm reference is measured on}, note).

    ``both``: ``gate.hold_errors`` of the new calibration; ``errs``: its per-sensor
    errors (the accelerometer's about its new level); ``before``: the old reference
    (``active_gyro_rms`` rad/s, ``active_accel_rms`` m/s^2, None: none). Every hold,
    unless ``alarm_reference`` is 'explained' and there is an old reference: then a hold
    the new calibration misses by the change alarm's limit against the old reference
    (``gate.limit``, as in ``gate.misses``) is left out of that sensor's reference,
    unless it would leave none.
    Not after a change alarm (``alarm_pending``): the old reference is then the old
    sensor's; not for the sensor a one-sensor swap (``only``) keeps, whose reference stays
    as it was.
    """
    c = config
    h = len(both['ids'])
    use = {'gyro': np.ones(h, bool), 'accel': np.ones(h, bool)}
    if c.alarm_reference != 'explained' or not h or alarm_pending:
        return use, ''
    parts = []
    for which in ('gyro', 'accel'):
        old = before[f'active_{which}_rms']
        if old is None or only not in (None, which):
            continue
        lim = gate.limit(both, which, old, c.alarm_factor, c.alarm_floor)
        missed = np.abs(errs[which]) > lim
        if missed.any() and not missed.all():
            use[which] = ~missed
            parts.append(f'{which} {int(missed.sum())} of {h}')
    note = ('; alarm reference without the holds it misses by the alarm limit ('
            + ', '.join(parts) + ')') if parts else ''
    return use, note
