"""Repeated poses that disagree: holds taken in another sensor state (pose-repeat test).

A still hold measures gravity, so two holds in the same pose (same gravity direction in
the sensor frame) must read the same specific force, whatever the calibration: no model
parameter can make them differ. A hold can be genuinely still (gyro at its bias, accel
noise at its floor) and still disagree with an earlier visit of the same pose: the
sensor's output changed while it was handled (package stress when clamped or held,
a temperature step without a temperature input). The imucal Ferraris session is the
example: the still periods around the 360 deg turns read |a| up to 0.86 mg lower than the
face held in the same pose a minute earlier, with the same noise (12 sigma). Fitting
such holds drags every face; a fit of all holds cannot tell which visit is wrong (the
axis' bias and scale absorb either level), so the test is made before any fit.

:func:`hold_consistency`:

* pose clusters: holds whose mean accel directions are within ``CLUSTER_DEG``;
* noise of a hold mean along gravity: ``sigma_h^2 = u' var u / N_h + (FLOOR_G g)^2``
  (``var``: within-window variance plus the spread of the window means, at least
  LSB^2/12; ``N_h`` samples; the floor is what averaging cannot remove);
* |a| of each hold after a rough per-axis bias and scale fit to all holds (so the bias
  does not turn the small tilt between two visits into a |a| difference);
* two visits of a pose disagree when ``| |m_i| - |m_j| | > z sqrt(sigma_i^2 + sigma_j^2)``
  with z the Bonferroni normal quantile at ``ALPHA`` over the pairs tested. With a
  temperature input only visits within ``TEMP_MATCH`` of each other are compared (a
  thermal model explains the rest);
* which visit describes the calibrated state: an axis' bias and scale come from its up
  and down poses, which must be read in the same state, so the reference of a cluster is
  the visit closest in time to a hold of the opposite pose (the first visit when there is
  none). Visits that disagree with the reference are left out of the accelerometer fit;
  the reference itself is never left out, so no face is lost.

The holds left out are still: the gyro bias and the pose changes around them use them.
"""

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import norm

#: family error rate of the pairwise tests
ALPHA = 1e-3
#: noise floor of a hold mean that averaging cannot remove, as a fraction of g (10 ug)
FLOOR_G = 10e-6
#: holds within this angle are the same pose, deg
CLUSTER_DEG = 5.0
#: with a temperature input, visits are compared only within this difference (its unit)
TEMP_MATCH = 0.5
#: a hold of the opposite pose: direction within this angle of the reversed direction, deg
OPPOSITE_DEG = 45.0


def hold_table(windows, temps=None):
    """Return ids, (h,3) mean accel, (h,3) variance of a sample, (h,) samples, (h,) t, (h,3) T.

    The variance is the within-window variance plus the spread of the window means (so a
    drift inside the hold counts as noise); t is the hold's mid time, s.
    """
    ids = windows.hold_ids
    h = len(ids)
    pos = {int(i): j for j, i in enumerate(ids)}
    idx = np.array([pos[int(i)] for i in windows.hold], int)
    w = windows.n.astype(float)
    n = np.bincount(idx, w, h)

    def wmean(x):
        x = np.asarray(x, float).reshape(len(idx), -1)
        return np.stack([np.bincount(idx, w * x[:, c], h) for c in range(x.shape[1])],
                        1) / n[:, None]

    mean = wmean(windows.accel)
    spread = wmean((windows.accel - mean[idx]) ** 2)
    var = wmean(windows.accel_var) + spread
    t0 = np.full(h, np.inf)
    t1 = np.full(h, -np.inf)
    np.minimum.at(t0, idx, windows.t0)
    np.maximum.at(t1, idx, windows.t1)
    tmid = 0.5 * (t0 + t1)
    tm = wmean(temps) if temps is not None and len(temps) else np.full((h, 3), np.nan)
    return ids, mean, var, n, tmid, tm


def _has_faces(up):
    """Return True when every axis has a pose within OPPOSITE_DEG of up and one of down."""
    c = np.cos(np.radians(OPPOSITE_DEG))
    return bool(np.all(np.any(up > c, axis=0) & np.any(up < -c, axis=0)))


def rough_magnitudes(mean, gravity):
    """Return |a| per hold after a rough bias + scale fit (raw |m| without the six faces).

    Two visits of a pose are never exactly the same direction: with a bias b, a tilt
    d_theta between them changes the raw |m| by about |b| d_theta (4 mg for 0.5 m/s^2 and
    5 deg), far above the noise. A per-axis bias and scale fitted to every hold (Huber
    loss) removes that; its errors enter the difference of two visits only times
    d_theta.
    """
    mag = np.linalg.norm(mean, axis=1)
    if len(mean) < 6 or not _has_faces(mean / mag[:, None]):
        return mag

    def fun(p):
        return np.linalg.norm((mean - p[:3]) * (1.0 + p[3:]), axis=1) - gravity

    p = least_squares(fun, np.zeros(6), loss='huber', f_scale=1e-3 * gravity).x
    return np.linalg.norm((mean - p[:3]) * (1.0 + p[3:]), axis=1)


def hold_consistency(windows, gravity, temps=None, lsb=None):
    """Return (bool mask over windows of the holds kept, report dict).

    windows: segments.Windows; gravity m/s^2; temps: (m, 3) per-axis thermal input of the
    accel axes per window (None without temperature); lsb: (3,) accel resolution, m/s^2
    (None: not known). The report lists every hold left out with its pose reference, the
    difference of |a| (ug) and its z-score.
    """
    ids, mean, var, n, tmid, tm = hold_table(windows, temps)
    report = {'test': f'pose-repeat |a| test: visits within {CLUSTER_DEG:g} deg compared, '
                      f'Bonferroni alpha {ALPHA:g}, floor {FLOOR_G * 1e6:.0f} ug',
              'holds_tested': int(len(ids)), 'left_out': []}
    if len(ids) < 2:
        return np.ones(len(windows), bool), report
    if lsb is not None:
        var = np.maximum(var, np.asarray(lsb, float) ** 2 / 12.0)
    up = mean / np.linalg.norm(mean, axis=1)[:, None]
    mag = rough_magnitudes(mean, gravity)
    sigma = np.sqrt(np.einsum('hi,hi->h', up ** 2, var) / n + (FLOOR_G * gravity) ** 2)
    cos = up @ up.T
    same = cos >= np.cos(np.radians(CLUSTER_DEG))
    if temps is not None and len(temps):
        dtemp = np.nanmax(np.abs(tm[:, None, :] - tm[None, :, :]), axis=2)
        same &= dtemp <= TEMP_MATCH
    opposite = cos <= -np.cos(np.radians(OPPOSITE_DEG))
    z = np.abs(mag[:, None] - mag[None, :]) / np.hypot(sigma[:, None], sigma[None, :])
    pairs = int(np.triu(same, 1).sum())
    if pairs == 0:
        return np.ones(len(windows), bool), report
    limit = float(norm.isf(ALPHA / (2.0 * pairs)))
    report['z_limit'] = limit
    keep = np.ones(len(ids), bool)
    done = np.zeros(len(ids), bool)
    for j in np.argsort(tmid):
        if done[j]:
            continue
        members = np.flatnonzero(same[j] & ~done)
        done[members] = True
        if len(members) < 2:
            continue
        opp = np.flatnonzero(opposite[members].any(axis=0))
        if len(opp):
            gap = np.abs(tmid[members][:, None] - tmid[opp][None, :]).min(axis=1)
            ref = members[int(np.argmin(gap))]
        else:
            ref = members[int(np.argmin(tmid[members]))]
        for i in members:
            if i != ref and z[i, ref] > limit:
                keep[i] = False
                report['left_out'].append({
                    'hold': int(ids[i]), 'reference_hold': int(ids[ref]),
                    'start_s': float(windows.t0[windows.hold == ids[i]].min()),
                    'end_s': float(windows.t1[windows.hold == ids[i]].max()),
                    'difference_ug': float((mag[i] - mag[ref]) / gravity * 1e6),
                    'sigma_ug': float(np.hypot(sigma[i], sigma[ref]) / gravity * 1e6),
                    'z': float(z[i, ref])})
    report['holds_kept'] = int(keep.sum())
    return np.isin(windows.hold, ids[keep]), report


__all__ = ['hold_consistency', 'hold_table', 'ALPHA', 'FLOOR_G', 'CLUSTER_DEG']
