"""A swap confirmed on holds collected after its estimate (``LifelongConfig.prequential_holds``).

The swap gate scores a new calibration on the newest holds: its fit left them out, but
they were collected before it. The issue asks that no swap make the next day worse, and
the next day is made of holds that come after. With ``prequential_holds`` N > 0 a swap the
gate passes is held back (the calibration in ``pending.yaml``, its record in
``state['pending']``) until N holds collected after its estimate are in. Then the
held-back and the active calibration are scored on those holds (``gate.score``: the gyro
on every hold, the accelerometer on those in the mounting pose) and the swap takes effect
when they favour the new one: ``gate.decide``'s net gain in margins above 0, with no
margin of its own (the gate has already asked for one). Otherwise the held-back
calibration becomes the candidate.

While a swap is held back no other estimate is due (``Lifelong.due``), so each one is
judged; a change alarm or a reset turns it into the candidate, and the alarm's
re-estimate follows. Nothing is held back without an active calibration or after a
change alarm: the first calibration and a knock's recovery do not wait.
No ROS import.
"""

import numpy as np

from . import gate
from .pose import main_pose

#: the file the held-back calibration is kept in (the lifelong directory)
PENDING = 'pending.yaml'
#: ``Lifelong.due``'s reason when the held-back swap can be judged
REASON = 'prequential'


def holds_back(config, state, active):
    """Return True when a swap the gate passes waits for later holds (see the module)."""
    return (config.prequential_holds > 0 and active is not None
            and not state.get('alarm_pending'))


def record(cal, now, only, fit_until):
    """Return the state's record of a held-back swap.

    ``now``: s, the estimate's newest hold (later holds judge it); ``only``: 'gyro',
    'accel' or None (both); ``fit_until``: the refit's time or None (``active_fit_until``
    once it takes effect).
    """
    return {'id': cal.id, 'time': float(now), 'only': only, 'fit_until': fit_until}


def later_ids(store, t):
    """Return the ids of the raw holds that start after ``t`` (s)."""
    rec = store.recent
    if not len(rec):
        return np.zeros(0, int)
    ids, start = rec.hold_starts()
    return ids[start > t]


def ready(store, state, config):
    """Return True when a held-back swap has its ``prequential_holds`` later holds."""
    p = state.get('pending')
    return bool(p) and len(later_ids(store, p['time'])) >= config.prequential_holds


def judge(active, cal, store, state, config, latitude):
    """Score the held-back ``cal`` and ``active`` on the holds after its estimate.

    Returns (take: bool, figures (``gate.decide``'s), the new calibration's ``gate.score``,
    the holds in the mounting pose (windows), the hold ids). ``take``: the net gain in
    margins is above 0.
    """
    ids = later_ids(store, state['pending']['time'])
    holds = store.holds(ids)
    pose = main_pose(holds, config.pose_deg)
    g = cal.gravity
    s_new = gate.score(cal, holds, g, pose, latitude, config.accel_score)
    s_act = gate.score(active, holds, g, pose, latitude, config.accel_score)
    _, fig = gate.decide(s_act, s_new, config.swap_sigmas)
    return fig['net_margins'] > 0.0, fig, s_new, pose, ids


def describe(fig, take, n):
    """Return the decision's text on the later holds (see ``gate.describe``)."""
    what = 'favour it' if take else 'do not favour it'
    return (f'the {n} holds collected after its estimate {what} '
            f'({gate.describe(fig).replace("held-out holds", "later holds")})')
