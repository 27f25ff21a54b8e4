"""From a still run of detector blocks to a hold: guards, minimum length, windows, record.

The stationary detector (``stationary.StationaryDetector``) decides which blocks are still;
this module makes one hold of such a run. ``guard_s`` is trimmed from both ends (not where
the log itself starts or ends); a derived guard grows with the run (``GUARD_FRACTION`` at the
start, ``GUARD_TAIL_FRACTION`` at the end, at most ``GUARD_MAX_S``) and is undone as far as
its blocks' means agree with the rest of the hold (``settle_guards``). Guards and the
minimum hold are counted in samples at the derived rate (jittered stamps change nothing);
a run shorter than ``min_hold_s`` is dropped, the rest is cut into windows of ``window_s``
(``segments.Windows``) and described by one record (start, duration, face, tilt,
stillness score; ``format_holds`` renders them).
"""

import numpy as np

from .segments import face_of, Windows

#: a derived guard is this fraction of the still run, between guard_s and GUARD_MAX_S
GUARD_FRACTION = 0.02
#: ... and at the end of a hold, before a pose change, this fraction
GUARD_TAIL_FRACTION = 0.05
GUARD_MAX_S = 1.0
#: a guard block is kept when the chi-square statistic of its mean against the hold's core
#: is below this many times its degrees of freedom (``settle_guards``: mean square error)
EDGE_Z2_PER_DOF = 2.0


def settle_guards(b, keep):
    """Return ``keep`` with the guards undone as far as their blocks agree with the hold.

    ``keep`` marks the blocks inside the derived guards, which are now an upper bound:
    going outwards from the kept core, each guard block is kept until the first one whose
    mean accel or gyro differs from the core's, so a guard removes only what the data
    show to differ (the settling of a placed unit, the start of a turn) and nothing
    beyond it.  Keeping samples whose mean is off by ``d`` (per axis) lowers the hold
    mean's error when ``d^2`` is below the noise variance they remove; with ``d``
    estimated from the block, that is ``z^2 < 2 dof`` for the chi-square statistic of the
    block-minus-core difference (``EDGE_Z2_PER_DOF``).  The per-sample noise is the
    floor the run's last block was scored with, or what the scatter of the core's block
    means implies when that is larger (noise that is not white at the block scale: a
    ringing mount, bias wander).
    """
    nf = (float(b.fa[-1]), float(b.fg[-1]))
    inner = np.flatnonzero(keep)
    if len(inner) == 0 or len(inner) == len(keep):
        return keep
    core = slice(inner[0], inner[-1] + 1)
    n = b.n.astype(float)
    out = keep.copy()
    for j in range(core.start - 1, -1, -1):
        if not _agrees(b, n, slice(j, j + 1), core, nf):
            break
        out[j] = True
    for j in range(core.stop, len(keep)):
        if not _agrees(b, n, slice(j, j + 1), core, nf):
            break
        out[j] = True
    return out


def _agrees(b, n, zone, core, nf):
    """Return True when the mean accel and gyro of blocks ``zone`` agree with ``core``'s."""
    m = core.stop - core.start
    n_zone, n_core = float(n[zone].sum()), float(n[core].sum())
    for mean, floor in ((b.am, nf[0]), (b.gm, nf[1])):
        ref = np.average(mean[core], 0, n[core])
        var = floor / 3.0
        if m >= 2:
            var = max(var, float(np.sum((mean[core] - ref) ** 2 * n[core, None]))
                      / (3.0 * (m - 1)))
        d = np.average(mean[zone], 0, n[zone]) - ref
        if np.sum(d ** 2) / (var * (1.0 / n_zone + 1.0 / n_core)) > EDGE_Z2_PER_DOF * 3:
            return False
    return True


def make_hold(b, score, hold, config, rate_hz, derived_guard, n_inputs, edge=(False, False)):
    """Return (Windows, hold record) of one still run of blocks, or None when too short.

    ``b``: the run's Blocks, ``score``: their motion scores, ``hold``: the id it gets,
    ``config``: the resolved DetectorConfig, ``rate_hz``: the derived sample rate,
    ``derived_guard``: True when ``guard_s`` was derived (it then grows with the run and is
    undone where the data agree, ``settle_guards``), ``n_inputs``: temperature inputs;
    ``edge``: (log starts, log ends) at the run, where no guard is trimmed.
    """
    c = config
    if len(b) == 0:
        return None
    guard = lead = c.guard_s
    if derived_guard:
        # derived guard: grows with the hold up to GUARD_MAX_S; at the end of a hold, where
        # a pose change begins slowly before the blocks see it (a hand starting to turn
        # the unit), by GUARD_TAIL_FRACTION of the run, at the start by GUARD_FRACTION
        run = b.t1[-1] - b.t0[0]
        lead = min(max(guard, GUARD_FRACTION * run), max(guard, GUARD_MAX_S))
        guard = min(max(guard, GUARD_TAIL_FRACTION * run), max(guard, GUARD_MAX_S))
    # guards and the minimum hold count samples (at the derived rate), not stamp
    # differences: with jittered stamps (a driver stamping on arrival) a 0.2 s guard
    # would drop two or three 0.1 s blocks by chance, and a run's first-to-last stamp
    # span is one sample interval short of the time it covers, so a run of exactly the
    # minimum hold failed it
    rate = rate_hz
    before = np.cumsum(b.n) - b.n
    after = int(np.sum(b.n)) - np.cumsum(b.n)
    keep = ((before >= (0 if edge[0] else round(lead * rate)))
            & (after >= (0 if edge[1] else round(guard * rate))))
    if derived_guard:
        keep = settle_guards(b, keep)
    b = b.take(keep)
    score = score[keep]
    if len(b) == 0 or np.sum(b.n) < round(c.min_hold_s * rate):
        return None
    per = max(1, int(round(c.window_s / c.block_s)))
    groups = np.arange(len(b)) // per
    if groups[-1] > 0 and np.sum(groups == groups[-1]) < (per + 1) // 2:
        groups[groups == groups[-1]] -= 1  # merge a short tail into the previous window
    starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
    n = np.add.reduceat(b.n, starts)
    w = b.n[:, None].astype(float)

    def wmean(x):
        return np.add.reduceat(x * w, starts, axis=0) / n[:, None]

    m = len(starts)
    temp = wmean(b.tm) if n_inputs else np.zeros((m, 0))
    rate = np.zeros((m, n_inputs))
    if n_inputs:
        ends = np.r_[starts[1:], len(b)]
        for j, (s, e) in enumerate(zip(starts, ends)):
            if e - s >= 2:
                tt = b.tt[s:e] - b.tt[s:e].mean()
                rate[j] = (tt @ (b.tm[s:e] - b.tm[s:e].mean(0))) / max(tt @ tt, 1e-12)
    mean_a = np.average(b.am, 0, b.n)
    record = {'hold': hold, 'start': float(b.t0[0]),
              'duration': float(b.t1[-1] - b.t0[0]), 'face': face_of(mean_a),
              'tilt_deg': tilt_deg(mean_a),
              'stillness': float(np.clip(1.0 - np.quantile(score, 0.95), 0, 1))}
    windows = Windows(
        hold=np.full(m, hold, int),
        t0=b.t0[starts], t1=b.t1[np.r_[starts[1:], len(b)] - 1], n=n.astype(int),
        accel=wmean(b.am), gyro=wmean(b.gm),
        accel_var=wmean(b.av), gyro_var=wmean(b.gv), temp=temp, temp_rate=rate)
    return windows, record


def tilt_deg(accel_mean):
    """Return the angle (deg) between the gravity-up direction and the nearest sensor axis."""
    u = np.abs(np.asarray(accel_mean, float))
    return float(np.degrees(np.arccos(np.clip(u.max() / np.linalg.norm(u), -1.0, 1.0))))


def format_holds(holds):
    """Render hold records (``StationaryDetector.holds``) as a table for people."""
    out = ['  hold   start [s]  duration [s]  face     tilt [deg]  stillness']
    for h in holds:
        out.append(f'  {h["hold"]:4d}  {h["start"]:10.2f}  {h["duration"]:12.2f}  '
                   f'{h["face"]:7s}  {h["tilt_deg"]:10.1f}  {h["stillness"]:9.2f}')
    return '\n'.join(out)
