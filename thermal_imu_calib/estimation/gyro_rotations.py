"""Gyroscope rotation fit (imu_tk, Tedaldi et al. 2014) over pose changes.

Between consecutive holds i -> j the compensated gyro is integrated (quaternions,
all transitions at once by a pairwise tree product) and the gravity direction
measured before is carried over and compared with the one measured after:
``r = u_j - dR' u_i``. Transitions flagged ``closed`` (full turns, start and end
orientation identical, as the Ferraris protocol) add ``rotvec(dR) = 0``. A pose change
that starts and ends in the same pose (gravity directions within ``SAME_POSE_DEG``) and
turns the unit by a whole number of turns (integrated angle within ``FULL_TURN_TOLERANCE``
of n x 360 deg, n >= 1) is taken as closed: gravity alone cannot see a turn about the
vertical, the closure can (``is_full_turn``).
Unknowns: Omega1 (3x3 scale/misalignment relative to the accelerometer frame)
and the per-axis nonlinearity Omega2, Omega3; observability as in
``observability``. The earth rate during a 2-4 s pose change (< 3e-4 rad) is
neglected. The pose changes come from ``collection.motion``.

Cohesive: one fit (residuals with their Jacobian, the term selection, the fit, its notes).
"""

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..collection.outliers import robust_scale
from .observability import (converged, decide_determined, DETERMINED_RATIO, fit_free, Layout,
                            NOT_CONVERGED_KEY, Priors, StoppedFolds)

from ..rotations import (cross, integrate_quaternions, prefix_products, quat_from_rotvec,
                         quat_rotate_inverse, quat_to_matrix, quat_to_rotvec, right_jacobian,
                         right_jacobian_inverse, SKEW, sum_sq)

#: reason of the estimated rotation terms left at their prior by a fit that did not converge
NOT_CONVERGED_REASON = 'the fit on the pose changes did not converge: fixed at the prior'
#: evaluations of each fold fit of the term selection
FOLD_MAX_NFEV = 50


# ------------------------------------------------------------------------ rotation fit
@dataclass
class RotationFit:
    """Omega1 (and Omega2, Omega3) from rotations between holds."""

    omega1: np.ndarray
    omega2: np.ndarray
    omega3: np.ndarray
    std: dict
    estimated: dict
    fixed: dict
    ratios: dict
    used: int
    error_before_deg: np.ndarray     # per transition, with the prior Omega1
    error_after_deg: np.ndarray
    notes: list
    #: the transitions the fit used (for leave-one-pose-change-out scores)
    prepared: Optional['PreparedTransitions'] = None


@dataclass
class PreparedTransitions:
    """Fixed per-transition arrays of the rotation fit (padded with zeros to one length).

    The rotation increment of sample interval k is linear in the unknowns:
    ``theta_k = Omega1 b_k + Omega2 o c2_k + Omega3 o c3_k`` (trapezoid rule).
    """

    b: np.ndarray          # (k, n, 3) integrated bias/g-sensitivity-free raw rate, rad
    c2: np.ndarray         # (k, n, 3) integrated W^2
    c3: np.ndarray         # (k, n, 3) integrated W^3
    u_from: np.ndarray     # (k, 3)
    u_to: np.ndarray       # (k, 3)
    sigma: np.ndarray      # (k,) rad, direction-residual standard deviation
    closed: np.ndarray     # (k,) bool
    index: List[int] = field(default_factory=list)   # positions in the input list
    cone: Optional[np.ndarray] = None                 # (k, n, 3) coning increments, rad


def _trapezoid(x, dt):
    return 0.5 * (x[1:] + x[:-1]) * dt[:, None]


#: consecutive increments are summed into one while the neglected second-order term of the
#: composition (1/2 sum_{i<j} theta_i x theta_j, Baker-Campbell-Hausdorff) stays below this
MERGE_COMMUTATOR = 1e-7      # rad
#: motion = smoothed bias-free rate above this many noise standard deviations
MOTION_SIGMAS = 8.0
#: still time kept around the detected motion of a transition, s
MOTION_MARGIN_S = 0.25
#: start and end of a pose change in the same pose: gravity directions within this (deg)
SAME_POSE_DEG = 5.0
#: a same-pose change is a full turn when its integrated angle is within this fraction of
#: n x 360 deg (n >= 1): covers the raw scale error of MEMS gyros (imucal's Ferraris
#: session: +3.4 % on x) and a hand-made turn that ends a few degrees off
FULL_TURN_TOLERANCE = 0.10
#: leave-one-pose-change-out up to this many pose changes, round-robin folds beyond
HELDOUT_FOLDS = 12


def is_full_turn(rate, dt, up_from, up_to):
    """Return True when a pose change is a whole number of turns back to the same pose.

    rate: (n, 3) bias-free angular rate (rad/s) over the samples; dt: (n - 1,) s; up_from,
    up_to: unit gravity directions of the holds before and after. The rotation angle is the
    norm of the integrated rate (exact for a turn about a fixed axis).
    """
    if float(np.dot(up_from, up_to)) < np.cos(np.radians(SAME_POSE_DEG)) or len(dt) == 0:
        return False
    angle = float(np.degrees(np.linalg.norm(np.sum(_trapezoid(rate, dt), axis=0))))
    turns = round(angle / 360.0)
    return turns >= 1 and abs(angle - 360.0 * turns) <= FULL_TURN_TOLERANCE * 360.0 * turns


def _group_starts(increments, window=64):
    """Return the first sample of every merged group of each (n_t, 3) increment array, rad.

    A group grows while the neglected second-order term of its composition,
    E = 1/2 sum_{l<j} theta_l x theta_j over the group, stays within ``MERGE_COMMUTATOR``;
    the sample that would exceed it starts the next group. All transitions advance together
    by ``window`` samples per step, and the running sums are sequential cumulative sums
    seeded with the group's sums so far: they repeat, in the same order, the additions of a
    sample-by-sample loop (test_gyro_rotations_fast keeps it as the reference), so the groups are
    identical to it bit for bit.
    """
    k = len(increments)
    lens = np.array([len(x) for x in increments], int)
    pad = np.zeros((k, (max(lens) if k else 0) + window, 3))
    for j, x in enumerate(increments):
        pad[j, :len(x)] = x
    lim2 = MERGE_COMMUTATOR ** 2
    starts = [[0] for _ in range(k)]
    pos = np.ones(k, int)                  # next sample to append
    s = pad[:, 0].copy()                   # group sum before it
    e = np.zeros((k, 3))                   # group commutator before it
    offs = np.arange(window)
    a, b = [1, 2, 0], [2, 0, 1]            # (S x theta)_i = S_a theta_b - S_b theta_a
    act = np.flatnonzero(pos < lens)
    while len(act):
        idx = pos[act, None] + offs
        th = pad[act[:, None], idx]                                        # (m, w, 3)
        ss = np.cumsum(np.concatenate([s[act, None], th], axis=1), axis=1)
        sp = ss[:, :-1]
        c = 0.5 * (sp[..., a] * th[..., b] - sp[..., b] * th[..., a])
        ee = np.cumsum(np.concatenate([e[act, None], c], axis=1), axis=1)[:, 1:]
        n2 = ee[..., 0] * ee[..., 0] + ee[..., 1] * ee[..., 1] + ee[..., 2] * ee[..., 2]
        over = (n2 > lim2) & (idx < lens[act, None])
        hit = over.any(axis=1)
        first = np.argmax(over, axis=1)
        for j, f in zip(act[hit], first[hit]):
            starts[j].append(int(pos[j] + f))
        rows = np.arange(len(act))
        s[act] = np.where(hit[:, None], th[rows, first], ss[:, -1])
        e[act] = np.where(hit[:, None], 0.0, ee[:, -1])
        pos[act] = np.where(hit, pos[act] + first + 1, pos[act] + window)
        act = act[pos[act] < lens[act]]
    return [np.array(x) for x in starts]


def _merge_commuting(parts):
    """Sum runs of increments whose composition is their sum to 1e-7 rad, per transition.

    parts: one (b, c2, c3, cone) tuple of (n_t, 3) arrays per transition; the groups come
    from b (``_group_starts``, all transitions at once) and apply to all four.
    """
    return [tuple(np.add.reduceat(x, starts, axis=0) for x in p)
            for p, starts in zip(parts, _group_starts([p[0] for p in parts]))]


def _motion_extent(t, d, noise):
    """Return the sample slice of a transition that holds its motion (plus a margin).

    Outside it the unit is still (the detector guard), so its true rotation is zero and
    integrating it would only add angle random walk. ``noise``: per-sample rate std.
    """
    n = len(t)
    if noise is None or n < 8:
        return slice(0, n)
    dt = float(np.median(np.diff(t)))
    k = max(3, int(round(0.1 / max(dt, 1e-6))))
    mag = np.sqrt(sum_sq(d))                   # np.linalg.norm(d, axis=1), bit for bit
    smooth = np.convolve(mag, np.ones(k) / k, mode='same')
    moving = np.flatnonzero(smooth > MOTION_SIGMAS * float(np.mean(noise)) / np.sqrt(k)
                            + float(np.mean(noise)) * np.sqrt(2.0 / np.pi))
    if len(moving) == 0:
        return slice(0, n)
    lo = np.searchsorted(t, t[moving[0]] - MOTION_MARGIN_S)
    hi = np.searchsorted(t, t[moving[-1]] + MOTION_MARGIN_S, side='right')
    return slice(int(lo), int(max(hi, lo + 2)))


def prepare_transitions(transitions, hold_up, hold_sigma, static, accel_model, accel_input,
                        gyro_input, t0g, gyro_noise=None):
    """Precompute the static-compensated, integrated raw rates of each usable transition.

    hold_up: dict hold id -> unit up (3,); hold_sigma: dict hold id -> direction std (rad).
    static: StaticGyroFit; accel_model corrects the transition's specific force (g-sensitivity
    during motion). Transitions between unknown holds are skipped.
    """
    rows = []
    for i, tr in enumerate(transitions):
        if tr.hold_from not in hold_up or tr.hold_to not in hold_up or len(tr.t) < 3:
            continue
        temps = np.asarray(tr.temps, float)
        ta = np.broadcast_to(temps[list(accel_input)] if temps.size else accel_model.t0,
                             (len(tr.t), 3))
        xg = temps[list(gyro_input)] if temps.size else np.asarray(t0g, float)
        a = accel_model.correct(tr.accel, ta)
        dxg = xg - t0g
        c = np.zeros(3)
        for row in static.offset[::-1]:
            c = c * dxg + row
        w = tr.gyro - c
        d = w - static.beta - a @ static.g.T
        keep = _motion_extent(tr.t, d, gyro_noise)
        tt, d, w = tr.t[keep], d[keep], w[keep]
        dt = np.diff(tt)
        closed = bool(tr.closed) or is_full_turn(d, dt, hold_up[tr.hold_from],
                                                 hold_up[tr.hold_to])
        # within-interval coning of a linearly varying rate (Bortz): dt^2/12 w_a x w_b,
        # evaluated with the prior scale (its Omega1 dependence is second order)
        cone = cross(d[:-1], d[1:]) * (dt ** 2 / 12.0)[:, None]
        rows.append([i, tr, _trapezoid(d, dt), _trapezoid(w * w, dt), _trapezoid(w ** 3, dt),
                     cone, dt, closed])
    for r, merged in zip(rows, _merge_commuting([tuple(r[2:6]) for r in rows])):
        r[2:6] = merged
    k = len(rows)
    n = max([len(r[2]) for r in rows], default=1)
    b = np.zeros((k, n, 3))
    c2 = np.zeros((k, n, 3))
    c3 = np.zeros((k, n, 3))
    c0 = np.zeros((k, n, 3))
    uf, ut, sg, cl, idx = [], [], [], [], []
    for j, (i, tr, bb, cc2, cc3, cc, dt, closed) in enumerate(rows):
        b[j, :len(bb)], c2[j, :len(bb)], c3[j, :len(bb)], c0[j, :len(bb)] = bb, cc2, cc3, cc
        uf.append(hold_up[tr.hold_from])
        ut.append(hold_up[tr.hold_to])
        gn = 0.0 if gyro_noise is None else \
            float(np.mean(gyro_noise)) * np.sqrt(np.sum(dt ** 2))
        sg.append(np.sqrt(hold_sigma[tr.hold_from] ** 2 + hold_sigma[tr.hold_to] ** 2
                          + gn ** 2 + 1e-12))
        cl.append(closed)
        idx.append(i)
    return PreparedTransitions(b, c2, c3, np.array(uf).reshape(k, 3),
                               np.array(ut).reshape(k, 3), np.array(sg), np.array(cl, bool),
                               idx, c0)


def increment_quaternions(prep, omega1, omega2, omega3):
    """Return the increments theta (k, n, 3) rad and their (k, n, 4) quaternions."""
    theta = prep.b @ np.asarray(omega1).T + omega2 * prep.c2 + omega3 * prep.c3
    if prep.cone is not None:
        theta = theta + prep.cone
    return theta, quat_from_rotvec(theta)


def transition_rotations(prep, omega1, omega2, omega3, prefixes=False, increments=None):
    """Return (k, 4) quaternions dR of every transition, the prefixes and the increments.

    The increments theta (k, n, 3) rad; the prefixes (k, n, 4) (inclusive ordered products)
    only when ``prefixes``, else None. ``increments``: ``increment_quaternions`` of the same
    arguments when the caller has them.
    """
    theta, q = increments or increment_quaternions(prep, omega1, omega2, omega3)
    if not prefixes:
        return integrate_quaternions(q), None, theta
    pre = prefix_products(q)
    return pre[:, -1], pre, theta


def rotation_residuals(prep, omega1, omega2, omega3, want_jac=False, increments=None):
    """Return (k, 3) residuals u_to - dR' u_from (rad; closure rotvec if closed) [, jac].

    ``increments``: ``increment_quaternions`` of the same arguments when the caller has them
    (the fit evaluates the Jacobian where it last evaluated the residuals).

    The Jacobian (k, 3, 15) w.r.t. (Omega1 row-major, Omega2, Omega3) uses the
    right-perturbation dR -> dR exp(dphi), dphi = dR' sum_k P_k J_r(theta_k) dtheta_k (P_k
    inclusive prefix products, J_r the right Jacobian of SO(3): exact, so Gauss-Newton
    converges in a few steps even with the large merged increments of a turn about one axis).
    """
    q, pre, theta = transition_rotations(prep, omega1, omega2, omega3, want_jac, increments)
    rot = quat_to_matrix(q)                                    # (k, 3, 3)
    carried = np.einsum('kji,kj->ki', rot, prep.u_from)        # dR' u_from
    r = prep.u_to - carried
    if np.any(prep.closed):
        r[prep.closed] = quat_to_rotvec(q[prep.closed])
    if not want_jac:
        return r
    k, n = theta.shape[:2]
    pm = (quat_to_matrix(pre) @ right_jacobian(theta)).reshape(k, n, 9)
    # sum_n pm[n, i, a] x[n, c] for x = (b, c2, c3): (k, 3, 3, 9) as [k, i, a, c]
    s = (pm.transpose(0, 2, 1) @ np.concatenate([prep.b, prep.c2, prep.c3], axis=2)
         ).reshape(k, 3, 3, 9)
    diag = np.arange(3)
    dphi_start = np.concatenate([s[..., :3].reshape(k, 3, 9), s[:, :, diag, 3 + diag],
                                 s[:, :, diag, 6 + diag]], axis=2)     # (k, 3, 15)
    dphi = rot.transpose(0, 2, 1) @ dphi_start                  # end frame
    jac = -(carried @ SKEW).reshape(k, 3, 3) @ dphi             # dphi x carried
    if np.any(prep.closed):
        jac[prep.closed] = right_jacobian_inverse(r[prep.closed]) @ dphi[prep.closed]
    return r, jac


def direction_error_deg(prep, omega1, omega2=0.0, omega3=0.0):
    """Return (k,) angle between u_to and the carried u_from (deg); closure angle if closed."""
    q = transition_rotations(prep, omega1, omega2, omega3)[0]
    carried = quat_rotate_inverse(q, prep.u_from)
    c = np.clip(np.sum(carried * prep.u_to, axis=1), -1, 1)
    ang = np.degrees(np.arccos(c))
    if np.any(prep.closed):
        ang[prep.closed] = np.degrees(np.linalg.norm(quat_to_rotvec(q[prep.closed]), axis=1))
    return ang


def _subset(prep, rows):
    """Return the prepared transitions selected by a bool mask."""
    return PreparedTransitions(prep.b[rows], prep.c2[rows], prep.c3[rows], prep.u_from[rows],
                               prep.u_to[rows], prep.sigma[rows], prep.closed[rows],
                               [i for i, r in zip(prep.index, rows) if r],
                               None if prep.cone is None else prep.cone[rows])


def _select_rotation_terms(lay, free, p1, prep, solve_rows, k, tol=0.01):
    """Drop Omega3, then Omega2, unless leave-pose-changes-out validation supports them."""
    if k < 6 or not any(np.any(free[lay.slices[g]]) for g in ('Omega3', 'Omega2')):
        return free, {}
    folds = np.arange(k) % min(5, k)
    stopped = StoppedFolds()

    def cv_error(fr):
        err = 0.0
        for f in np.unique(folds):
            test = folds == f
            p, res = solve_rows(fr, p1, ~test)
            stopped.add(res)
            r = rotation_residuals(_subset(prep, test), lay.get(p, 'Omega1'),
                                   lay.get(p, 'Omega2'), lay.get(p, 'Omega3'))
            err += float(np.sum((r / prep.sigma[test, None]) ** 2))
        return err / k

    current = free.copy()
    best = cv_error(current)
    scores = {'all determined': best}
    for g in ('Omega3', 'Omega2'):
        i = np.arange(lay.slices[g].start, lay.slices[g].stop)
        i = i[current[i]]
        if not len(i):
            continue
        fr = current.copy()
        fr[i] = False
        e = cv_error(fr)
        scores[f'without {g}'] = e
        if e <= best * (1.0 + tol):
            current = fr
            best = min(best, e)
            for j in i:
                lay.reason[j] = ('determined, but leave-pose-changes-out validation does not '
                                 'support it: fixed at its prior')
        else:
            break
    stopped.record(scores)
    return current, scores


def fit_gyro_rotations(prep, priors=None, omega1_prior=None, ratio=DETERMINED_RATIO,
                       robust=True, select=True, estimate_only=False):
    """Estimate Omega1 (and, when determined, Omega2/Omega3) from prepared transitions.

    ``select``: keep the nonlinear terms only when leave-pose-changes-out validation
    supports them (as the accelerometer's optional terms). ``estimate_only``: leave out
    what a held-out refit does not use (standard deviations: NaN; direction errors before
    and after: empty); the estimate is the same.
    """
    priors = priors or Priors()
    lay = Layout()
    std1 = np.full((3, 3), priors.gyro_misalignment)
    np.fill_diagonal(std1, priors.gyro_scale)
    lay.add('Omega1', (3, 3), np.eye(3) if omega1_prior is None else omega1_prior, std1)
    lay.add('Omega2', (3,), 0.0, priors.gyro_nonlin2)
    lay.add('Omega3', (3,), 0.0, priors.gyro_nonlin3)
    k = len(prep.sigma)
    before = direction_error_deg(prep, lay.get(lay.mean, 'Omega1')) if k and not \
        estimate_only else np.zeros(0)

    def residuals_of(pr):
        last = [None, None]      # parameters and increments of the last evaluation

        def resid(p, want_jac=False):
            om = lay.get(p, 'Omega1'), lay.get(p, 'Omega2'), lay.get(p, 'Omega3')
            if last[0] is None or not np.array_equal(p, last[0]):
                last[:] = p.copy(), increment_quaternions(pr, *om)
            out = rotation_residuals(pr, *om, want_jac, last[1])
            if not want_jac:
                return (out / pr.sigma[:, None]).ravel()
            r, j = out
            return ((r / pr.sigma[:, None]).ravel(),
                    (j / pr.sigma[:, None, None]).reshape(-1, lay.size))
        return resid

    resid = residuals_of(prep)

    def solve(free, base, with_prior, use_robust):
        return fit_free(resid, lay.std, base, free, with_prior, use_robust, max_nfev=100)

    def solve_rows(free, base, rows):
        """Plain least squares of the free parameters on a subset: (parameters, result)."""
        return fit_free(residuals_of(_subset(prep, rows)), lay.std, base, free, tight=False,
                        max_nfev=FOLD_MAX_NFEV)

    if k < 2:
        free = np.zeros(lay.size, bool)
        for i in range(lay.size):
            lay.reason[i] = ('no rotations between holds were collected: fixed at the prior'
                             if k == 0 else 'one rotation cannot determine it: fixed at the '
                             'prior')
        ratios = {}
        p = lay.mean.copy()
        std = lay.std.copy()
        notes = ['gyroscope scale factor and misalignment (Omega1) not estimated: '
                 f'{k} usable pose changes between holds (need several, about different '
                 'axes)']
        after = before
    else:
        p1, _ = solve(lay.candidates, lay.mean, True, False)
        r1, j1 = resid(p1, True)
        s = max(robust_scale(r1), 1.0)
        free, ratios = decide_determined(lay, j1, s, ratio,
                                         chains=[[9 + i, 12 + i] for i in range(3)])
        cv = {}
        if select:
            free, cv = _select_rotation_terms(lay, free, p1, prep, solve_rows, k)
        p0 = lay.mean.copy()
        p0[free] = p1[free]
        p, res = solve(free, p0, False, robust)
        stopped = [lay.label(i) for i in np.flatnonzero(free)] if not converged(res) else []
        if stopped:         # a point where the solver ran out of evaluations is no fit
            for i in np.flatnonzero(free):
                lay.reason[i] = NOT_CONVERGED_REASON
            p, free = lay.mean.copy(), np.zeros(lay.size, bool)
        std = np.where(free, 0.0, lay.std)
        if estimate_only:
            std[free] = np.nan
            after = np.zeros(0)
        else:
            r, jf = resid(p, True)
            scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
            jf = jf[:, free]
            try:
                cov = np.linalg.pinv(jf.T @ jf) * max(scale, 1.0) ** 2
                std[free] = np.sqrt(np.maximum(np.diag(cov), 0))
            except np.linalg.LinAlgError:
                std[free] = np.nan
            after = direction_error_deg(prep, lay.get(p, 'Omega1'), lay.get(p, 'Omega2'),
                                        lay.get(p, 'Omega3'))
        notes = []
        if stopped:
            notes.append(f'gyroscope {", ".join(stopped)} not estimated: their fit on the {k} '
                         f'pose changes did not converge ({res.message}); fixed at the prior')
        by_cv = [lay.label(i) for i in range(lay.size) if not free[i]
                 and (lay.reason[i] or '').startswith('determined, but')]
        labels = [lay.label(i) for i in range(lay.size) if not free[i] and not stopped
                  and lay.label(i) not in by_cv]
        if labels:
            notes.append(f'gyroscope {", ".join(labels)} not determined by the {k} pose '
                         'changes: fixed at the prior (scale needs rotations about each axis; '
                         'nonlinearity needs fast ones)')
        if NOT_CONVERGED_KEY in cv:
            notes.append(f'gyroscope Omega2/Omega3 chosen by leave-pose-changes-out validation '
                         f'in which {cv[NOT_CONVERGED_KEY]} fold fits stopped at {FOLD_MAX_NFEV} '
                         'evaluations before converging: that choice is uncertain')
        if by_cv:
            notes.append(f'gyroscope {", ".join(by_cv)}: determined, but held-out pose changes '
                         'do not support it (leave-pose-changes-out validation): fixed at the '
                         'prior')
    return RotationFit(lay.get(p, 'Omega1'), lay.get(p, 'Omega2'), lay.get(p, 'Omega3'),
                       {n: lay.get(std, n) for n in lay.names}, lay.masks(free),
                       lay.reasons(free), {lay.label(i): v for i, v in ratios.items()}, k,
                       before, after, notes, prep)


def priors_like(fit, priors=None):
    """Return ``priors`` with Omega2/Omega3 fixed (std 1e-12) where ``fit`` left them out.

    Refits on part of the pose changes (held-out scores) then estimate the terms the fit on
    all of them kept, without repeating its leave-pose-changes-out selection.
    """
    from dataclasses import replace
    changes = {attr: 1e-12 for name, attr in (('Omega2', 'gyro_nonlin2'),
                                              ('Omega3', 'gyro_nonlin3'))
               if not np.any(fit.estimated[name])}
    return replace(priors or Priors(), **changes)


def heldout_rotation_errors(prep, priors=None, robust=True, max_folds=HELDOUT_FOLDS):
    """Return (k,) held-out errors (deg) of the rotation fit, one pose change out at a time.

    Each prepared transition is left out (with more than ``max_folds`` of them: round-robin
    folds, to bound the cost), Omega1 (Omega2, Omega3 unless ``priors`` fix them, see
    ``priors_like``) refitted on the others and the left-out ones scored by
    ``direction_error_deg`` (closure angle of a full turn, else the angle between the carried
    and the measured gravity direction).
    """
    k = len(prep.sigma)
    out = np.full(k, np.nan)
    folds = np.arange(k) % max(min(k, max_folds), 1)
    for f in np.unique(folds):
        test = folds == f
        fit = fit_gyro_rotations(_subset(prep, ~test), priors, robust=robust, select=False,
                                 estimate_only=True)
        out[test] = direction_error_deg(_subset(prep, test), fit.omega1, fit.omega2,
                                        fit.omega3)
    return out
