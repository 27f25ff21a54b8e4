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

Sensor-state epochs (:func:`_epochs`). A failed pair proves the output changed between its
two visits; it does not say whether the change lasted. The failed visits span a changed
epoch (from the first to the last of them: the state was changed at both ends, the fewest
change points keep it changed in between). The holds after it (the tail; before it for
failed visits earlier than their reference) are tested jointly against the earlier holds:
per pose visited in both, the weighted mean |a| of the tail's visits minus that of the
earlier visits over its standard deviation; the sum of squares is chi-square with one degree
of freedom per pose if the tail is in the earlier state. Each visit alone is typically 1-3
sigma off (short holds after a handling step), the pose means together are not. The
question is no longer whether anything changed (the pairwise test answered it at the family
rate ``ALPHA``) but which state the later holds are in, so the test runs at the conventional
``PERSIST_ALPHA``: a wrong keep drags every face of the fit, a wrong leave-out costs only the
precision of holds whose poses the kept epoch has anyway. When it rejects, the tail joins the
changed epoch. Two epochs cannot share one calibration: the accelerometer keeps the epoch
that observes more of a per-axis bias and scale (:func:`observability`: rank, then smallest
singular value, of the rows ``[u, u^2]``; the earlier epoch on a tie) and the other epoch's
holds are left out.

Nothing of this runs without a failed pair (a session whose state never changed leaves out
nothing more than before), nor with a temperature input: the state then moves with the
temperature and its history (lag, hysteresis), which the thermal model describes, so a later
visit at the same temperature may read differently without a step to a state no calibration
can share (on the simulated MEMS cold starts of ``bench_mems`` two such visits fail their
pair at 4.5 sigma against a 4.4 limit; as epochs they would take 56 of 130 holds out). On
the Ferraris session (no temperature) the x-turn holds prove the change (9.6 sigma), the y-
and z-turn holds after them read -182 +- 81 and -211 +- 102 ug off their faces (chi2 9.3 on
2 poses, p 0.010): they are left out too, the six faces kept.

The holds left out are still: the gyro bias and the pose changes around them use them.
"""

import numpy as np
from scipy.optimize import least_squares
# scipy.special, not scipy.stats: the same floats (chdtrc = chi2.sf, -ndtri = norm.isf)
# without scipy.stats' ~0.3 s import on every calibrate
from scipy.special import chdtrc, ndtri

#: family error rate of the pairwise tests
ALPHA = 1e-3
#: noise floor of a hold mean that averaging cannot remove, as a fraction of g (10 ug)
FLOOR_G = 10e-6
#: holds within this angle are the same pose, deg
CLUSTER_DEG = 5.0
#: with a temperature input, visits are compared only within this difference (its unit)
TEMP_MATCH = 0.5
#: once a pair proves a change, level of the joint test that it lasted (see module doc)
PERSIST_ALPHA = ALPHA
#: singular values below this fraction of the largest do not count in ``observability``
RANK_TOL = 1e-2
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


def _clusters(same, opposite, tmid):
    """Return (cluster label per hold, reference hold per cluster) of the pose visits.

    Clusters are built in time order; the reference of a cluster is its visit closest in
    time to a hold of the opposite pose (the first visit when there is none).
    """
    label = np.full(len(tmid), -1)
    refs = []
    for j in np.argsort(tmid):
        if label[j] >= 0:
            continue
        members = np.flatnonzero(same[j] & (label < 0))
        label[members] = len(refs)
        opp = np.flatnonzero(opposite[members].any(axis=0))
        if len(opp):
            gap = np.abs(tmid[members][:, None] - tmid[opp][None, :]).min(axis=1)
            refs.append(int(members[int(np.argmin(gap))]))
        else:
            refs.append(int(members[int(np.argmin(tmid[members]))]))
    return label, np.array(refs, int)


def observability(up):
    """Return (rank, smallest singular value) of |a|'s sensitivity to a bias and scale per axis.

    up: (h, 3) unit gravity directions of the holds of one epoch. The rows ``[u, u^2]`` are
    d|a|/d(bias) and d|a|/d(scale)/g: six faces give rank 6, three poses at most 3. Tuples
    compare lexicographically: the epoch with the larger one observes more of the model.
    """
    if len(up) == 0:
        return 0, 0.0
    s = np.linalg.svd(np.hstack([up, up ** 2]), compute_uv=False)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    return rank, float(s[rank - 1]) if rank else 0.0


def _gls(x, sigma):
    """Return the inverse-variance weighted mean of x and its variance."""
    w = 1.0 / sigma ** 2
    return float(np.sum(w * x) / np.sum(w)), float(1.0 / np.sum(w))


def _epoch_test(tail, earlier, label, mag, sigma):
    """Return (chi2, dof, p, per-pose rows) of the tail's repeat visits against the earlier holds.

    tail, earlier: bool masks of the holds tested and of the earlier epoch. For every pose
    visited in both, the weighted mean |a| of the tail's visits minus that of the earlier
    ones, over its standard deviation, is one normal variate under "the tail is in the
    earlier state": their sum of squares is chi-square with one degree of freedom per pose.
    """
    rows = []
    for c in np.unique(label[tail]):
        a = np.flatnonzero((label == c) & earlier)
        b = np.flatnonzero((label == c) & tail)
        if len(a):
            ma, va = _gls(mag[a], sigma[a])
            mb, vb = _gls(mag[b], sigma[b])
            rows.append((b, mb - ma, np.sqrt(va + vb)))
    if not rows:
        return 0.0, 0, 1.0, rows
    q = float(sum((d / s) ** 2 for _, d, s in rows))
    return q, len(rows), float(chdtrc(len(rows), q)), rows


def _sides(failed, tmid):
    """Yield (span, tail) bool masks of the changed epoch(s) the failed pairs prove.

    failed: (visit, reference) index pairs. The failed visits later than their reference
    span a changed epoch from the first to the last of them (the state was changed at both
    ends; the fewest change points keep it changed in between); its tail is every hold
    after the last. Failed visits earlier than their reference likewise, the tail before.
    """
    later = [i for i, r in failed if tmid[i] > tmid[r]]
    earlier = [i for i, r in failed if tmid[i] < tmid[r]]
    if later:
        lo, hi = tmid[later].min(), tmid[later].max()
        yield (tmid >= lo) & (tmid <= hi), tmid > hi
    if earlier:
        lo, hi = tmid[earlier].min(), tmid[earlier].max()
        yield (tmid >= lo) & (tmid <= hi), tmid < lo


def _epochs(report, keep, label, up, mag, sigma, tmid, ids, gravity, span_s):
    """Test whether the change the failed pairs prove lasts; return the new keep mask.

    The changed epoch is the span of the failed visits (``_sides``) and, when the tail's
    repeat visits differ jointly from the earlier holds at ``PERSIST_ALPHA``
    (``_epoch_test``: the change lasted), the tail. The two epochs cannot share one
    calibration: the accelerometer keeps the one that observes more of a per-axis bias and
    scale (``observability``; the earlier one on a tie) and the other's holds are left out.
    Only when the changed epoch is just the failed visits is nothing more left out.
    """
    failed = [(int(np.flatnonzero(ids == h['hold'])[0]),
               int(np.flatnonzero(ids == h['reference_hold'])[0])) for h in report['left_out']]
    for span, tail in _sides(failed, tmid):
        earlier = keep & ~span & ~tail
        q, dof, p, rows = _epoch_test(tail & keep, earlier, label, mag, sigma)
        lasting = bool(dof and p < PERSIST_ALPHA)
        changed = span | tail if lasting else span
        first = keep & ~changed
        ep = {'start_s': float(span_s[changed, 0].min()),
              'end_s': float(span_s[changed, 1].max()),
              'holds': [int(h) for h in ids[changed]], 'tail_chi2': q, 'tail_dof': dof,
              'tail_p': p, 'lasting': lasting,
              'tail_poses': [{'holds': [int(h) for h in ids[b]],
                              'difference_ug': d / gravity * 1e6, 'sigma_ug': s / gravity * 1e6}
                             for b, d, s in rows],
              'observability': {'earlier': observability(up[first]),
                                'changed': observability(up[changed])}}
        use_changed = ep['observability']['changed'] > ep['observability']['earlier']
        ep['accel_uses'] = 'changed' if use_changed else 'earlier'
        drop = first if use_changed else changed & keep
        for i in np.flatnonzero(drop):
            report['left_out'].append({'hold': int(ids[i]),
                                       'epoch': len(report.get('epochs', []))})
        if use_changed:
            keep = changed.copy()
            report['left_out'] = [h for h in report['left_out']
                                  if not changed[np.flatnonzero(ids == h['hold'])[0]]]
        else:
            keep = keep & ~changed
        report.setdefault('epochs', []).append(ep)
    return keep


def hold_consistency(windows, gravity, temps=None, lsb=None, magnitudes=None):
    """Return (bool mask over windows of the holds kept, report dict).

    windows: segments.Windows; gravity m/s^2; temps: (m, 3) per-axis thermal input of the
    accel axes per window (None without temperature); lsb: (3,) accel resolution, m/s^2
    (None: not known). The report lists every hold left out: a failed pose repeat with its
    reference, the difference of |a| (ug) and its z-score; a hold of an epoch left out
    with ``epoch`` set (the test in ``report['epochs']``; epochs only without ``temps``).
    magnitudes: (holds,) |a| of each hold mean after a calibration fitted to all holds
    (hold ids in sorted order, m/s^2; e.g. the standard fit), so that the difference of two
    visits a few degrees apart is not the scale and misalignment error the calibration
    removes; None: after a rough per-axis bias and scale fit (``rough_magnitudes``).
    """
    ids, mean, var, n, tmid, tm = hold_table(windows, temps)
    report = {'test': f'pose-repeat |a| test: visits within {CLUSTER_DEG:g} deg compared, '
                      f'Bonferroni alpha {ALPHA:g}, floor {FLOOR_G * 1e6:.0f} ug; a change '
                      'it proves lasted when the later repeat visits differ jointly at p < '
                      f'{PERSIST_ALPHA:g}',
              'holds_tested': int(len(ids)), 'left_out': []}
    if len(ids) < 2:
        return np.ones(len(windows), bool), report
    if lsb is not None:
        var = np.maximum(var, np.asarray(lsb, float) ** 2 / 12.0)
    up = mean / np.linalg.norm(mean, axis=1)[:, None]
    mag = rough_magnitudes(mean, gravity) if magnitudes is None else np.asarray(magnitudes)
    sigma = np.sqrt(np.einsum('hi,hi->h', up ** 2, var) / n + (FLOOR_G * gravity) ** 2)
    cos = up @ up.T
    same = cos >= np.cos(np.radians(CLUSTER_DEG))
    thermal = temps is not None and len(temps) > 0
    if thermal:
        dtemp = np.nanmax(np.abs(tm[:, None, :] - tm[None, :, :]), axis=2)
        same &= dtemp <= TEMP_MATCH
    pairs = int(np.triu(same, 1).sum())
    if pairs == 0:
        return np.ones(len(windows), bool), report
    limit = float(-ndtri(ALPHA / (2.0 * pairs)))
    report['z_limit'] = limit
    label, refs = _clusters(same, cos <= -np.cos(np.radians(OPPOSITE_DEG)), tmid)
    z = np.abs(mag - mag[refs[label]]) / np.hypot(sigma, sigma[refs[label]])
    keep = ~(z > limit)
    for i in np.flatnonzero(~keep):
        r = refs[label[i]]
        report['left_out'].append({
            'hold': int(ids[i]), 'reference_hold': int(ids[r]),
            'difference_ug': float((mag[i] - mag[r]) / gravity * 1e6),
            'sigma_ug': float(np.hypot(sigma[i], sigma[r]) / gravity * 1e6),
            'z': float(z[i])})
    span = np.column_stack(windows.hold_spans()[1:])
    if report['left_out'] and not thermal:
        keep = _epochs(report, keep, label, up, mag, sigma, tmid, ids, gravity, span)
    for h in report['left_out']:
        j = int(np.flatnonzero(ids == h['hold'])[0])
        h['start_s'], h['end_s'] = float(span[j, 0]), float(span[j, 1])
    report['left_out'].sort(key=lambda h: h['hold'])
    report['holds_kept'] = int(keep.sum())
    return np.isin(windows.hold, ids[keep]), report


__all__ = ['hold_consistency', 'hold_table', 'observability', 'ALPHA', 'PERSIST_ALPHA',
           'FLOOR_G', 'CLUSTER_DEG']
