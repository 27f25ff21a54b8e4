"""What /diagnostics shows of a lifelong loop: age, range, held-out error, coverage.

``figures`` reads a ``manager.Lifelong`` (its store, state and calibrations) and changes
nothing. Units: seconds, degC, rad/s, m/s^2. No ROS import.
"""

from . import compose, follower, gate


def figures(life, temperature=None, now=None):
    """Return the status dict of ``life`` (``Lifelong.status``).

    ``temperature``: degC, the reading now (``in_range`` against the active calibration's
    valid range); ``now``: s, for the active calibration's age.
    """
    s, active = life.state, life.active
    out = dict(life.store.summary())
    out.update(swaps=s['swaps'], kept=s['kept'], alarms=s['alarms'],
               estimates=s['estimates'], last_decision=s['last_decision'],
               active=active.id if active is not None else '',
               **follower.status(life.output),
               candidate=life.candidate.id if life.candidate is not None else '',
               pending=life.pending.id if life.pending is not None else '')
    if s.get('alarm_pending'):
        out['alarm'] = ('re-estimating from every hold, the older ones moved by the '
                        "knock's step" if s.get('alarm_shifted')
                        else 're-estimating from the holds after it')
    if active is None:
        return out
    if s.get('active_since') is not None and now is not None:
        out['active_age_s'] = float(now - s['active_since'])
    if active.valid_range is not None and life.k:
        lo, hi = compose.common_range(active, life.config.range_sensors)[0]
        out['valid_range'] = [float(lo), float(hi)]
        if temperature is not None:
            out['in_range'] = bool(lo <= temperature <= hi)
    held = life.store.holds(life.store.newest_holds(life.config.holdout_holds))
    if len(held):
        sc = gate.score(active, held, active.gravity, latitude=life.latitude)
        out['recent_gyro_rms_rad_s'] = sc['gyro_rms']
        out['recent_accel_rms_mps2'] = sc['accel_rms']
    return out
