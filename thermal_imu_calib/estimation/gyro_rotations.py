"""Gyroscope rotation fit (imu_tk, Tedaldi et al. 2014) over pose changes.

Between consecutive holds i -> j the compensated gyro is integrated (quaternions,
all transitions at once by a pairwise tree product) and the gravity direction
measured before is carried over and compared with the one measured after:
``r = u_j - dR' u_i``. Transitions flagged ``closed`` (full turns, start and end
orientation identical, as the Ferraris protocol) add ``rotvec(dR) = 0``. A pose change
that starts and ends in the same pose and turns the unit by a whole number of turns is
taken as closed: gravity alone cannot see a turn about the vertical, the closure can
(``gyro_transitions.is_full_turn``).
Unknowns: Omega1 (3x3 scale/misalignment relative to the accelerometer frame)
and the per-axis nonlinearity Omega2, Omega3; observability as in
``observability``. The earth rate during a 2-4 s pose change (< 3e-4 rad) is
neglected. The pose changes come from ``collection.motion``, prepared (compensated,
integrated, merged) by ``gyro_transitions``.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .gyro_transitions import PreparedTransitions
from .observability import (converged, decide_determined, DETERMINED_RATIO, fit_free, Layout,
                            NOT_CONVERGED_KEY, Priors, StoppedFolds)
from ..collection.outliers import robust_scale
from ..rotations import (integrate_quaternions, prefix_products, quat_from_rotvec,
                         quat_rotate_inverse, quat_to_matrix, quat_to_rotvec, right_jacobian,
                         right_jacobian_inverse, SKEW)

#: reason of the estimated rotation terms left at their prior by a fit that did not converge
NOT_CONVERGED_REASON = 'the fit on the pose changes did not converge: fixed at the prior'
#: evaluations of each fold fit of the term selection
FOLD_MAX_NFEV = 50
#: leave-one-pose-change-out up to this many pose changes, round-robin folds beyond
HELDOUT_FOLDS = 12


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
