"""The step a knock made, and where it began, measured on the holds (``alarm_cut`` 'shift').

A knock steps the sensors' offsets, not their thermal sensitivity. After a change alarm
(``alarm``) the holds before the change can then be kept, moved by the step
(``HoldStore.shift``), instead of being dropped: the estimate after the alarm keeps their
temperature span. Two things are measured with the active calibration's compensated hold
means (``gate.hold_errors``: the gyro less its vertical earth rate, the accelerometer
vector), on the raw holds in the mounting pose inside each sensor's alarm range:

* where the change began (``change_start``): the alarm fires on its ``alarm_holds``-th
  flagged hold in a row, and knocked holds before the first of them (a miss at another
  temperature, one under the limit) must not be moved again. The split of the newest
  holds into a before and an after part that explains both sensors' means best (the
  Gaussian likelihood ratio of one mean step, each sensor with its own unknown variance:
  no threshold, no units to weigh), at or before the first flagged hold;
* the step (``step``): per sensor, the component-wise median over the holds after that
  point less the median over the newest ``STEP_BEFORE_HOLDS`` before it.

Holds between the last in-range hold before the change and the first after it (outside
the range, or off the mounting pose) cannot be told apart: they are dropped, neither
moved nor kept as they are.

Units: s, rad/s, m/s^2. No ROS import.
"""

import numpy as np

from . import gate
from .pose import main_pose, one_family

#: raw holds before the change (the newest) the step is measured against
STEP_BEFORE_HOLDS = 10
#: in-range holds before the first flagged one searched for where the change began
SEARCH_HOLDS = 40
#: fewest holds on the before side of a split
MIN_BEFORE = 3


def change_start(vecs, first):
    """Return the index where the change began in time-ordered holds (``first`` at most).

    ``vecs``: {sensor: (h, 3)} the holds' compensated means, oldest first; ``first``: the
    index of the first flagged hold. The split ``k`` (holds ``k`` on are after) maximises
    sum over sensors of log(SSE without a split / SSE with it), ``k`` in
    ``[MIN_BEFORE, first]``; ``first`` when there is no room for a search.
    """
    if first <= MIN_BEFORE:
        return first
    score = 0.0
    ks = np.arange(MIN_BEFORE, first + 1)
    for x in vecs.values():
        x = np.asarray(x, float)
        n = len(x)
        c1, c2 = np.cumsum(x, 0), np.cumsum(np.sum(x * x, 1))
        total = c2[-1] - np.sum(c1[-1] ** 2) / n
        sb = c2[ks - 1] - np.sum(c1[ks - 1] ** 2, 1) / ks
        after = c1[-1] - c1[ks - 1]
        sa = (c2[-1] - c2[ks - 1]) - np.sum(after ** 2, 1) / (n - ks)
        score = score + np.log(max(total, 1e-300) / np.maximum(sb + sa, 1e-300))
    return int(ks[int(np.argmax(score))])


def step(cal, recent, t_flag, gravity, latitude, pose_deg, ranges):
    """Return the step of the biases the active calibration shows, or None.

    ``cal``: the active calibration; ``recent``: the store's raw windows; ``t_flag`` (s):
    the start of the first hold the alarm flagged; ``ranges``: ``alarm.alarm_ranges``.
    Returns {'t': where the change began (s, a hold's start), 'earlier': in-range holds
    between it and ``t_flag``, 'drop': raw hold ids that cannot be placed before or after
    it, 'accel': (3,) m/s^2, 'gyro': (3,) rad/s, 'after': holds, 'before': holds}; None
    when the holds are not one orientation family (``pose.one_family``: in several poses
    the accelerometer's mean vectors differ by the pose, not by a step) or a sensor has no
    hold on either side.
    """
    if not len(recent) or not one_family(recent):
        return None
    win = main_pose(recent, pose_deg)
    e = gate.hold_errors(cal, win, gravity, latitude)
    _, starts = win.hold_starts()                    # in e['ids'] order
    inside = {}
    for which in ('gyro', 'accel'):
        lo, hi = ranges[which]
        inside[which] = np.isnan(e['temp']) | ((e['temp'] >= lo) & (e['temp'] <= hi))
    both = np.flatnonzero(inside['gyro'] & inside['accel'])
    both = both[np.argsort(starts[both])]
    first = int(np.searchsorted(starts[both], t_flag))
    lo = max(0, first - SEARCH_HOLDS)
    part = both[lo:]
    k = lo + change_start({w: e[w + '_vec'][part] for w in ('gyro', 'accel')}, first - lo) \
        if first < len(both) else first
    t = float(starts[both[k]]) if k < len(both) else float(t_flag)
    t_before = float(starts[both[k - 1]]) if k > 0 else -np.inf
    after = starts >= t
    ids, begin = recent.hold_starts()
    out = {'t': t, 'earlier': int(first - k),
           'drop': ids[(begin > t_before) & (begin < t)].tolist()}
    for which in ('gyro', 'accel'):
        a = np.flatnonzero(after & inside[which])
        b = np.flatnonzero(~after & inside[which])
        b = b[np.argsort(starts[b])][-STEP_BEFORE_HOLDS:]
        if not len(a) or not len(b):
            return None
        vec = e[which + '_vec']
        out[which] = np.median(vec[a], axis=0) - np.median(vec[b], axis=0)
        out['after'] = min(out.get('after', len(a)), len(a))
        out['before'] = min(out.get('before', len(b)), len(b))
    return out
