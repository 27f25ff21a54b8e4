"""When the lifelong loop re-estimates: ``due`` says why a re-estimate is due now, or ''.

The first time enough holds are in; when the collected temperatures extend by
``range_extension_degc`` both the active calibration's valid range (where neither sensor's
model clamps) and what the last estimate fitted (``fit_span``; so a sensor kept with a
narrow range does not make every few holds an estimate of the same temperatures); when
``new_holds`` holds came in since the last estimate; when ``misfit_holds`` new holds since
the last estimate were missed by the active calibration (``gate.misses``: the change
alarm's limit, at any temperature, consecutive or not; a re-estimate only makes a
candidate that must pass the swap gate, so it needs no stronger evidence); after a change
alarm. After a swap to a calibration fitted on every hold (``refit_on_swap``), not before
``min_holds + holdout_holds`` holds newer than its fit are in. With ``alarm_first``, none
of the others while the change alarm is deciding (``alarm.pending_since``: a sensor's
newest tracked holds all miss its limit, fewer than ``alarm_holds`` of them) and fewer than
``alarm_holds`` holds have come in since that run began: a swap would re-measure the
alarm's reference on the changed holds and hide the change (seeds 2, 19 and 52 of the
simulated month, docs/lifelong.md). Units: s, degC, holds. No ROS import.
"""

import numpy as np

from . import alarm, compose


def fit_span(fit, k):
    """Return the temperature span [lo, hi] (degC) an estimate fitted, None without one.

    ``fit``: the windows it fitted; ``k``: the number of thermal inputs (none: None).
    """
    return ([float(fit.temp[:, 0].min()), float(fit.temp[:, 0].max())]
            if len(fit) and k else None)


def holds_after(recent, t):
    """Return how many raw holds of ``recent`` (the store's raw windows) begin after ``t`` (s)."""
    if not len(recent):
        return 0
    _, starts = recent.hold_starts()
    return int(np.sum(starts > t))


def due(store, state, config, active, k, track=()):
    """Return why a re-estimate is due now ('' when it is not).

    ``store``: the ``HoldStore``; ``state``: the loop's counters (``manager.Lifelong.state``);
    ``config``: its ``LifelongConfig``; ``active``: the active calibration (None: none);
    ``k``: the number of thermal inputs; ``track``: the change alarm's tracked holds
    (``alarm.Tracked``; for ``alarm_first``).
    """
    c, s = config, state
    raw = len(store.recent.hold_ids) if len(store.recent) else 0
    enough = store.total_holds and raw + (1 if len(store.bins) else 0) >= \
        c.min_holds + c.holdout_holds
    if not enough:
        return ''
    until = s.get('active_fit_until')
    if until is not None and holds_after(store.recent, until) < c.min_holds + c.holdout_holds:
        # the gate's held-out holds must be ones the active never saw, and the new fit
        # needs new holds of its own (as the first estimate: 6 to fit, 8 to judge)
        return ''
    if s.get('alarm_pending'):
        return 'change alarm'
    if active is None:
        if store.total_holds - s['holds_at_estimate'] >= c.min_holds or \
                not s['estimates']:
            return 'no active calibration'
        return ''
    if c.alarm_first and track:
        since = alarm.pending_since(track, s, c)
        if since is not None and 1 + holds_after(store.recent, since) < c.alarm_holds:
            return ''
    new = store.total_holds - s['holds_at_estimate']
    if new >= c.new_holds:
        return f'{new} new holds'
    missed = s.get('missed') or []
    if len(missed) >= c.misfit_holds:
        temps = ', '.join(f'{x[1]:.1f}' for x in missed[-c.misfit_holds:])
        return (f'the active calibration missed {len(missed)} new holds (the newest at '
                f'{temps} degC)')
    span = store.temperature_span()
    if span and active.valid_range is not None and k and new >= c.min_holds:
        lo, hi = compose.common_range(active, c.range_sensors)[0]
        ref_lo, ref_hi, also = lo, hi, ''
        seen = s.get('fit_span')
        if seen:
            ref_lo, ref_hi = min(lo, seen[0]), max(hi, seen[1])
            if (ref_lo, ref_hi) != (lo, hi):
                also = (f' and what the last estimate fitted '
                        f'({seen[0]:.1f}..{seen[1]:.1f})')
        ext = max(ref_lo - span[0], span[1] - ref_hi)
        if ext >= c.range_extension_degc:
            return (f'collected {span[0]:.1f}..{span[1]:.1f} degC extends the valid range '
                    f'{lo:.1f}..{hi:.1f}{also} by {ext:.1f} degC')
    return ''
