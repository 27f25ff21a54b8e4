"""Motion hints: when was the robot commanded still, and which windows does that admit.

A hint source reports, at header stamps (s), whether it says "still": a velocity command
(cmd_vel, geometry_msgs/Twist) or odometry (nav_msgs/Odometry) with every component below
its threshold, or a ``std_msgs/Bool`` (true: still). The node turns messages into
``(stamp, still)`` events; this core keeps them and answers for a window [t0, t1] whether
every source said still over all of it. A hold counts only when the detector found it
and the hints agree; without sources the detector alone decides.

Each source's state holds from one event to the next. A source silent for longer than
its ``timeout_s`` is *stale*: a command source then counts as still (a base controller
stops the robot when commands stop: ``cmd_vel_timeout``), a state source (odometry, the
Bool) as unknown, which admits nothing. Events older than ``history_s`` before the newest
are forgotten (bounded memory: a hold longer than that is admitted from its newest part).
"""

from dataclasses import dataclass

import numpy as np

#: threshold of a Twist component (m/s linear, rad/s angular) still counted as "still"
STILL_SPEED = 1e-3


@dataclass
class HintSource:
    """One hint input: its name, whether silence means still, its timeout (s)."""

    name: str
    stale_means_still: bool = False
    timeout_s: float = 1.0


class HintGate:
    """Collect hint events and filter windows by the commanded-still intervals."""

    def __init__(self, sources=(), history_s=3600.0):
        self.sources = {s.name: s for s in sources}
        self.history_s = float(history_s)
        self.events = {s.name: [] for s in sources}      # [(stamp s, still)], time order
        self.counts = {'windows_admitted': 0, 'windows_refused': 0, 'hint_events': 0}

    @property
    def active(self):
        """Return True when there is at least one hint source."""
        return bool(self.sources)

    def add(self, name, stamp, still):
        """Record that source ``name`` said ``still`` (bool) at ``stamp`` (s).

        Consecutive events with the same answer, each within the timeout of the previous,
        extend one segment ``[start, last seen, still]``: memory grows with the changes,
        not with the message rate.
        """
        ev = self.events[name]
        stamp, still = float(stamp), bool(still)
        self.counts['hint_events'] += 1
        if ev and stamp < ev[-1][1]:
            if stamp >= ev[-1][0] and still == ev[-1][2]:
                return                     # inside the last segment already
            # out of order (a restarted publisher): start again from it
            ev[:] = [e for e in ev if e[0] < stamp]
        if ev and still == ev[-1][2] and stamp - ev[-1][1] <= self.sources[name].timeout_s:
            ev[-1][1] = stamp
        else:
            ev.append([stamp, stamp, still])
        horizon = stamp - self.history_s
        while len(ev) > 1 and ev[1][0] < horizon:
            ev.pop(0)

    def intervals(self, name):
        """Return [(a, b)] of the times source ``name`` says still (b may be inf)."""
        src, ev = self.sources[name], self.events[name]
        out = []
        if not ev:
            return [(-np.inf, np.inf)] if src.stale_means_still else []
        if src.stale_means_still:
            out.append((-np.inf, ev[0][0]))
        for i, (start, last, still) in enumerate(ev):
            nxt = ev[i + 1][0] if i + 1 < len(ev) else np.inf
            fresh_end = min(nxt, last + src.timeout_s)
            if still:
                out.append((start, fresh_end))
            if src.stale_means_still and fresh_end < nxt:
                out.append((fresh_end, nxt))
        return _merge(out)

    def still_over(self, t0, t1):
        """Return a bool array: every source said still over all of [t0_i, t1_i]."""
        t0, t1 = np.atleast_1d(np.asarray(t0, float)), np.atleast_1d(np.asarray(t1, float))
        ok = np.ones(len(t0), bool)
        for name in self.sources:
            iv = self.intervals(name)
            inside = np.zeros(len(t0), bool)
            for a, b in iv:
                inside |= (t0 >= a) & (t1 <= b)
            ok &= inside
        return ok

    def filter(self, windows):
        """Return the windows that lie in a commanded-still interval of every source."""
        if not self.sources or not len(windows):
            return windows
        ok = self.still_over(windows.t0, windows.t1)
        self.counts['windows_admitted'] += int(ok.sum())
        self.counts['windows_refused'] += int((~ok).sum())
        return windows.select(ok)

    def still_now(self, t):
        """Return True/False whether the hints say still at ``t`` (None without sources)."""
        if not self.sources:
            return None
        return bool(self.still_over([t], [t])[0])


def twist_still(linear, angular, threshold=STILL_SPEED):
    """Return True when every component of a twist (m/s, rad/s) is below ``threshold``."""
    return bool(np.all(np.abs(np.r_[linear, angular]) <= threshold))


def _merge(iv):
    iv = sorted((a, b) for a, b in iv if b > a)
    out = []
    for a, b in iv:
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out
