"""Seed 000 estimator: two-step iterative estimation of the accelerometer thermal model.

Unknowns: the thermal vector x (per axis dk0, k1, k2, db0, b1, b2; paper eq. 9) and one
unit tilt vector c_h per hold (the gravity direction in the reference frame p, eq. 7).
Observations: window means of the raw accelerometer output with their standard errors.

1. Initial tilts from the normalised outputs mapped through the prior (eq. 29).
2. Given tilts, x by weighted linear least squares, axis by axis (eq. 16).
3. Given x, each tilt by Newton iteration on the KKT conditions of the unit-norm
   constrained problem (eqs. 20-27), generalised to all windows of a hold.
4. Repeat 2-3 until x and the tilts stop changing; then, optionally, a joint refinement
   of x and all tilts with scipy.optimize.least_squares that also gives the parameter
   covariance from the Jacobian.
"""

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, least_squares

from ..models.field import FieldPolynomialModel, THERMAL_NAMES
from .fixed_point import fixed_point
from .observability import converged, FitNotConverged

#: columns of the per-axis design for each polynomial order
_COLS = {0: [0, 3], 1: [0, 1, 3, 4], 2: [0, 1, 2, 3, 4, 5]}

#: evaluations of the joint refinement (``_refine``) before it counts as not converged
REFINE_MAX_NFEV = 200
#: the two-step sweeps stop when one moves every fitted window mean by less than this times
#: the median standard error of the window means (``fit_field_model``'s ``tol``)
SWEEP_TOL = 1e-5


@dataclass
class FieldFit:
    """Result of ``fit_field_model``."""

    model: FieldPolynomialModel
    tilts: np.ndarray          # (h, 3) unit gravity-up directions per hold, frame p
    hold_ids: np.ndarray
    iterations: int
    converged: bool
    residual_rms: float        # m/s^2, RMS of window-mean residuals
    chi2_dof: float            # reduced chi-square with the windows' standard errors
    refined: bool
    #: why the joint refinement was not used ('' when it was, or was not asked for)
    refine_note: str = ''
    #: with ``free_s``: stds of S's below-diagonal terms (s10, s20, s21), else None
    s_std: object = None
    #: with ``free_s``: the thermal vector given S (``SCondition``), else None
    s_condition: object = None


@dataclass
class SCondition:
    """The thermal vector given S, and what the data say about S (``free_s``).

    In the linearised fit at its solution: thermal(S) = thermal + gain (S terms - fitted
    terms), with stds ``std`` at a known S; the data's information about S's terms without
    the prior (``info``, 1/1^2) and their information vector ``eta`` (``info`` times the
    data's own estimate of the terms; with the prior's zero mean, the posterior information
    times the fitted terms). Both are divided by the covariance's misfit factor. Logs of one
    unit share S: summing their ``info`` and ``eta`` with the prior's information once pools
    it (``fleet.alarms``).
    """

    gain: np.ndarray        # (3, 6, 3): d thermal (THERMAL_NAMES layout) / d (s10, s20, s21)
    std: np.ndarray         # (3, 6): stds of the thermal vector given S
    info: np.ndarray        # (3, 3): data information about S's terms, prior removed
    eta: np.ndarray         # (3,): data information vector about S's terms
    #: (3, 6, 3, 3): d^2 thermal / d (s_m, s_n) (``_gain_curvature``). The thermal vector
    #: depends on S to second order even where the gains vanish: a face's tilt takes up
    #: the cross terms and |c| = 1 then shortens the axis' own component by s^2 / 2 (on
    #: the +x face the scale factor of x grows by (s10^2 + s20^2) / 2)
    curvature: object = None


def kkt_unit_tilt(a_mats, y, w, c0, max_iter=50, tol=1e-14):
    """Solve min sum_j ||w_j (A_j c - y_j)||^2 subject to |c| = 1 (paper eqs. 20-27).

    a_mats: (m, 3, 3), y: (m, 3), w: (m, 3) weights, c0: (3,) start.
    Returns (c, u, iterations); see ``kkt_unit_tilt_batch``.
    """
    aw = a_mats * w[:, :, None]
    m_mat = np.einsum('mki,mkj->ij', aw, aw)
    v = np.einsum('mki,mk->i', aw, y * w)
    c, u, it = kkt_unit_tilt_batch(m_mat[None], v[None], np.asarray(c0, float)[None],
                                   max_iter, tol)
    return c[0], float(u[0]), it


def kkt_unit_tilt_batch(m_mat, v, c0, max_iter=50, tol=1e-14):
    """Newton-KKT for many holds at once: min c'Mc - 2v'c s.t. |c| = 1, per hold.

    m_mat: (h, 3, 3) = sum A' W^2 A, v: (h, 3) = sum A' W^2 y, c0: (h, 3) starts.
    Newton steps on the Lagrangian L = f(c) + u (c'c - 1) with the bordered KKT system of
    eq. (24): gradient eq. (26), Hessian eq. (27), constraint gradient eq. (25).

    A Newton point is accepted only where it has converged: its KKT residual (gradient of
    L and |c|^2 - 1, relative to the scale of M and v) is below ``tol_kkt`` and the Hessian
    of L is positive semi-definite (u >= -lambda_min(M)), which makes it the global
    minimiser. Every other hold (Newton stopped at ``max_iter``, landed on a saddle or a
    maximum, or produced non-finite values) is solved through the secular equation
    (``_secular``), which always gives the global minimiser.
    Returns (c (h, 3), u (h,), iterations).
    """
    m_mat = np.asarray(m_mat, float)
    v = np.asarray(v, float)
    h = m_mat.shape[0]
    c = c0 / np.linalg.norm(c0, axis=1, keepdims=True)
    u = -np.einsum('hi,hi->h', c, np.einsum('hij,hj->hi', m_mat, c) - v)
    kkt = np.zeros((h, 4, 4))
    eye = np.eye(3)
    it = 0
    with np.errstate(all='ignore'):
        for it in range(1, max_iter + 1):
            grad = 2.0 * (np.einsum('hij,hj->hi', m_mat, c) - v) + 2.0 * u[:, None] * c
            hc = np.einsum('hi,hi->h', c, c) - 1.0
            kkt[:, :3, :3] = 2.0 * m_mat + 2.0 * u[:, None, None] * eye
            kkt[:, :3, 3] = kkt[:, 3, :3] = 2.0 * c
            rhs = -np.concatenate([grad, hc[:, None]], 1)[..., None]
            try:
                step = np.linalg.solve(kkt, rhs)[..., 0]
            except np.linalg.LinAlgError:       # a singular bordered system: let the
                step = (np.linalg.pinv(kkt) @ rhs)[..., 0]   # acceptance test decide
            c = c + step[:, :3]
            u = u + step[:, 3]
            if not np.all(np.isfinite(step)) or \
                    np.max(np.linalg.norm(step[:, :3], axis=1)) < tol:
                break
        ok = _kkt_converged(m_mat, v, c, u)
    for j in np.flatnonzero(~ok):
        c[j], u[j] = _secular(m_mat[j], v[j])
    return c / np.linalg.norm(c, axis=1, keepdims=True), u, it


def _kkt_converged(m_mat, v, c, u, tol_kkt=1e-10):
    """Per hold, whether (c, u) is a converged global minimiser of c'Mc - 2v'c on |c| = 1.

    True where c and u are finite, the KKT residual |Mc - v + uc| is below ``tol_kkt``
    times the problem's scale (|M| + |v|), |c|^2 - 1 is below ``tol_kkt``, and
    u >= -lambda_min(M) to within 1e-12 of the scale (second-order condition of the
    trust-region subproblem).
    """
    finite = np.all(np.isfinite(c), axis=1) & np.isfinite(u)
    c0 = np.where(finite[:, None], c, 0.0)
    u0 = np.where(finite, u, 0.0)
    lam = np.linalg.eigvalsh(m_mat)
    scale = np.abs(lam).max(axis=1) + np.linalg.norm(v, axis=1) + 1e-300
    res = np.linalg.norm(np.einsum('hij,hj->hi', m_mat, c0) - v + u0[:, None] * c0, axis=1)
    unit = np.abs(np.einsum('hi,hi->h', c0, c0) - 1.0)
    psd = u0 >= -lam[:, 0] - 1e-12 * scale     # eigvalsh is good to ~eps |M|
    return finite & (res <= tol_kkt * scale) & (unit <= tol_kkt) & psd


def _secular(m_mat, v):
    """Global minimiser of c'Mc - 2v'c on |c| = 1 via the secular equation in u.

    With M = Q diag(lam) Q' and w = Q'v, the minimiser is c = Q (w / (lam + u)) with the
    unique u > -lam_min solving sum w_i^2 / (lam_i + u)^2 = 1. In the "hard case" (w has
    no component on the eigenvectors of lam_min and the sum stays below 1 at u = -lam_min),
    u = -lam_min and the remainder of the unit norm is put along that eigenvector.
    """
    lam, q = np.linalg.eigh(m_mat)
    vq = q.T @ v
    scale = max(abs(lam[-1]), abs(lam[0]), float(np.linalg.norm(v)), 1e-300)
    low = lam - lam[0] <= 1e-12 * scale          # the eigenspace of lam_min

    def norm2(u):
        return float(np.sum((vq / (lam + u)) ** 2)) - 1.0

    lo = max(-lam[0] + 1e-15 * scale, float(np.nextafter(-lam[0], np.inf)))
    if norm2(lo) <= 0:                           # the hard case (or numerically so)
        c = np.zeros(3)
        c[~low] = vq[~low] / (lam[~low] - lam[0])
        j = np.flatnonzero(low)[0]
        c[j] = np.copysign(np.sqrt(max(0.0, 1.0 - float(c @ c))), vq[j])
        return q @ c, -lam[0]
    hi = -lam[0] + float(np.linalg.norm(v)) + scale * 1e-12   # norm2(hi) <= 0 here
    while norm2(hi) > 0:
        hi = -lam[0] + 2.0 * (hi + lam[0])
    u = brentq(norm2, lo, hi, xtol=1e-15 * max(abs(hi), 1.0), rtol=4 * np.finfo(float).eps,
               maxiter=500)
    c = vq / (lam + u)
    # Near the pole lam_min + u -> 0 the lam_min components lose their precision; they
    # follow from the well-conditioned others through |c| = 1 (their sign is that of w).
    r2 = float(np.sum(c[~low] ** 2))
    wl = float(np.linalg.norm(vq[low]))
    if r2 <= 1.0 and wl > 0:
        c[low] = vq[low] / wl * np.sqrt(1.0 - r2)
    return q @ (c / np.linalg.norm(c)), u


def _design(f, dt, order):
    """Per-axis linear design of eq. (16): columns f, dT f, dT^2 f, 1, dT, dT^2."""
    full = np.stack([f, dt * f, dt * dt * f, np.ones_like(f), dt, dt * dt], axis=1)
    return full[:, _COLS[order]]


def fit_field_model(windows, axis_temps, gravity, t0, k0=None, b0=None, s=None, order=2,
                    refine=True, max_iter=1000, tol=SWEEP_TOL, free_s=False):
    """Estimate the seed 000 model from stationary windows.

    windows: estimation.segments.Windows (accel means in m/s^2 with per-sample variances).
    axis_temps: (m, 3) per-axis temperature of each window, degC.
    gravity: local gravity magnitude, m/s^2. t0: (3,) reference temperatures, degC.
    k0, b0, s: prior scale factor, bias (m/s^2) and lower-triangular S (identity if None).
    order: temperature polynomial order 0, 1 or 2 (0 = temperature-independent dk0, db0).
    free_s: also estimate S in the joint refinement (``s`` must be None): its three
    below-diagonal terms, unit diagonal (``s_of_terms``), zero-mean prior
    ``S_PRIOR_STD``; needs ``refine``.
    max_iter, tol: steps 2-3 are repeated (``fixed_point.fixed_point``) until one pass moves every
    fitted window mean by less than ``tol`` times the median standard error of the window
    means, at most ``max_iter`` times (``FieldFit.converged`` says which).
    """
    if free_s and (s is not None or not refine):
        raise ValueError('free_s estimates S from identity in the joint refinement: '
                         'pass s=None and refine=True')
    k0 = np.ones(3) if k0 is None else np.asarray(k0, float)
    b0 = np.zeros(3) if b0 is None else np.asarray(b0, float)
    s = np.eye(3) if s is None else np.asarray(s, float)
    t0 = np.asarray(t0, float)
    raw = windows.accel
    se = np.sqrt(np.maximum(windows.accel_var, 1e-30) / windows.n[:, None])
    w = 1.0 / se
    dt = np.asarray(axis_temps, float) - t0
    hold_ids, hold_idx = np.unique(windows.hold, return_inverse=True)
    nh = len(hold_ids)
    cols = _COLS[order]

    # eq. (28)-(29): initial tilts from the normalised outputs through the prior
    s_inv = np.linalg.inv(s)
    tilts = np.zeros((nh, 3))
    for j in range(nh):
        sel = hold_idx == j
        fp = ((raw[sel] - b0) / k0) @ s_inv.T
        m = fp.mean(axis=0)
        tilts[j] = m / np.linalg.norm(m)

    se_min = float(np.median(se))

    def sweep(c):
        """One pass of steps 2-3 from tilts c: (new tilts, thermal vector, window means)."""
        # step 1: thermal vector given tilts (eq. 16), weighted, axis by axis
        th = np.zeros((3, 6))
        fa = gravity * (c[hold_idx] @ s.T)            # specific force in frame a
        for i in range(3):
            a = _design(fa[:, i], dt[:, i], order) * w[:, i:i + 1]
            y = (raw[:, i] - k0[i] * fa[:, i] - b0[i]) * w[:, i]
            sol, *_ = np.linalg.lstsq(a, y, rcond=None)
            th[i, cols] = sol
        # step 2: tilt per hold given the thermal vector (eqs. 20-27)
        model = FieldPolynomialModel(t0, th, k0, b0, s)
        k, b = model.scale_bias(t0 + dt)
        aw = gravity * k[:, :, None] * s[None, :, :] * w[:, :, None]   # W diag(k) S g
        m_win = np.einsum('mki,mkj->mij', aw, aw)
        v_win = np.einsum('mki,mk->mi', aw, (raw - b) * w)
        m_hold = np.zeros((nh, 3, 3))
        v_hold = np.zeros((nh, 3))
        np.add.at(m_hold, hold_idx, m_win)
        np.add.at(v_hold, hold_idx, v_win)
        c_new, _, _ = kkt_unit_tilt_batch(m_hold, v_hold, c)
        return c_new, th, model.forward(gravity * c_new[hold_idx], t0 + dt)

    tilts, thermal, converged, it = fixed_point(sweep, tilts, tol * se_min, max_iter)
    refined = False
    thermal_std = None
    refine_note = ''
    s_std = s_cond = None
    if refine:
        try:
            thermal, tilts, thermal_std, s, s_std, s_cond = _refine(
                raw, w, dt, hold_idx, tilts, thermal, gravity, t0, k0, b0, s, order, free_s)
            refined = True
        except FitNotConverged as e:    # stopped by its budget: the two-step estimate stands
            refine_note = f'{e.what}: {e.advice}'
    model = FieldPolynomialModel(t0, thermal, k0, b0, s, thermal_std)
    pred = model.forward(gravity * tilts[hold_idx], t0 + dt)
    res = raw - pred
    n_s = len(S_TERM_NAMES) if refined and free_s else 0
    dof = max(res.size - (3 * len(cols) + 2 * nh + n_s), 1)
    return FieldFit(model, tilts, hold_ids, it, converged,
                    float(np.sqrt(np.mean(res ** 2))), float(np.sum((res * w) ** 2) / dof),
                    refined, refine_note, s_std, s_cond)


def _tangent_basis(c):
    """Return two unit vectors orthogonal to c (and to each other)."""
    a = np.eye(3)[np.argmin(np.abs(c))]
    e1 = np.cross(c, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(c, e1)


#: (rows, columns) of S's below-diagonal terms estimated with ``free_s``: s10, s20, s21
S_TERMS = np.tril_indices(3, -1)
#: their names, in that order (``FieldFit.s_std``)
S_TERM_NAMES = tuple(f's{r}{c}' for r, c in zip(*S_TERMS))
#: 1-sigma prior of each of S's below-diagonal terms with ``free_s`` (zero mean): a
#: consumer MEMS datasheet's cross-axis sensitivity bound, +-2 % (MPU-6050, PS-MPU-6000A-00
#: rev. 3.4 sect. 6.2), taken as one sigma. Holds at the six faces alone do not determine
#: S (each hold gives only |S^-1 v| = 1, whose cross terms need tilted holds): the prior
#: keeps S, and the stds of the terms it moves, finite there.
S_PRIOR_STD = 2e-2


def s_of_terms(q):
    """Return the unit-diagonal lower-triangular S with below-diagonal terms q (s10, s20, s21).

    Unit diagonal (``sim.devices`` draws unit rows; the two differ in how the gain along an
    axis, k_i S_ii, is split, which ``models.alarm_terms`` reads whole): the terms enter
    linearly.
    """
    u = np.eye(3)
    u[S_TERMS] = q
    return u


def _refine(raw, w, dt, hold_idx, tilts, thermal, gravity, t0, k0, b0, s, order,
            free_s=False):
    """Joint least squares over the thermal vector and all tilts (analytic Jacobian).

    With ``free_s`` also over S's three below-diagonal terms (``s_of_terms``; S starts at
    identity, zero-mean prior ``S_PRIOR_STD`` as three extra residuals). Returns (thermal,
    tilts, thermal std, S, stds of S's terms or None, ``SCondition`` or None); raises
    ``FitNotConverged`` when the solver ran out of evaluations (``REFINE_MAX_NFEV``) before
    converging.
    """
    cols = _COLS[order]
    nh = len(tilts)
    nc = len(cols)
    m = len(raw)
    ns = len(S_TERM_NAMES) if free_s else 0
    bases = [_tangent_basis(c) for c in tilts]
    e1 = np.array([b[0] for b in bases])
    e2 = np.array([b[1] for b in bases])
    c0 = tilts.copy()
    n_tilt = 3 * nc + 2 * nh          # first S term's column

    def unpack(p):
        th = np.zeros((3, 6))
        th[:, cols] = p[:3 * nc].reshape(3, nc)
        ab = p[3 * nc:n_tilt].reshape(nh, 2)
        v = c0 + ab[:, :1] * e1 + ab[:, 1:] * e2
        return th, v, (s_of_terms(p[n_tilt:]) if free_s else s)

    def fun(p):
        th, v, sp = unpack(p)
        c = v / np.linalg.norm(v, axis=1, keepdims=True)
        model = FieldPolynomialModel(t0, th, k0, b0, sp)
        pred = model.forward(gravity * c[hold_idx], t0 + dt)
        return np.r_[((raw - pred) * w).ravel(), p[n_tilt:] / S_PRIOR_STD]

    def jac(p):
        th, v, sp = unpack(p)
        nv = np.linalg.norm(v, axis=1, keepdims=True)
        c = v / nv
        k, _ = FieldPolynomialModel(t0, th, k0, b0, sp).scale_bias(t0 + dt)
        fa = gravity * (c[hold_idx] @ sp.T)
        jm = np.zeros((m, 3, n_tilt + ns))
        for i in range(3):
            d = _design(fa[:, i], dt[:, i], order)
            jm[:, i, i * nc:(i + 1) * nc] = -d * w[:, i:i + 1]
        # d c / d(a, b) = (e - c (c.e)) / |v|
        for q, e in enumerate((e1, e2)):
            dc = (e - c * np.sum(c * e, axis=1, keepdims=True)) / nv     # (nh, 3)
            dfa = gravity * (dc[hold_idx] @ sp.T)                       # (m, 3)
            col = 3 * nc + 2 * hold_idx + q
            jm[np.arange(m), :, col] = -(k * dfa) * w
        if free_s:                # d(S f)_r / d s_rc = f_c
            f = gravity * c[hold_idx]                                      # (m, 3)
            for q, (r, cc) in enumerate(zip(*S_TERMS)):
                jm[:, r, n_tilt + q] = -k[:, r] * f[:, cc] * w[:, r]
        prior = np.zeros((ns, n_tilt + ns))
        prior[:, n_tilt:] = np.eye(ns) / S_PRIOR_STD
        return np.vstack([jm.reshape(m * 3, -1), prior])

    p0 = np.r_[thermal[:, cols].ravel(), np.zeros(2 * nh + ns)]
    sol = least_squares(fun, p0, jac=jac, method='trf', x_scale='jac', xtol=1e-15,
                        ftol=1e-15, gtol=1e-15, max_nfev=REFINE_MAX_NFEV)
    if not converged(sol):
        raise FitNotConverged(f'the joint refinement did not converge in {sol.nfev} '
                              f'evaluations ({sol.message})', 'the two-step estimate is used, '
                              'without its standard deviations')
    th, v, sp = unpack(sol.x)
    c = v / np.linalg.norm(v, axis=1, keepdims=True)
    j = sol.jac
    dof = max(j.shape[0] - j.shape[1], 1)
    s2 = 2.0 * sol.cost / dof
    hess = j.T @ j
    try:
        cov = np.linalg.pinv(hess) * max(s2, 1.0)
        var = np.diag(cov)
        cond = (_s_condition(hess, n_tilt, cols, max(s2, 1.0), sol.x[n_tilt:]) if free_s
                else None)
        if cond is not None:
            cond.curvature = _gain_curvature(jac, sol.x, n_tilt, cols, hess)
    except np.linalg.LinAlgError:
        var, cond = np.full(j.shape[1], np.nan), None
    std = np.zeros((3, 6))
    std[:, cols] = np.sqrt(np.maximum(var[:3 * nc], 0)).reshape(3, nc)
    s_std = np.sqrt(np.maximum(var[n_tilt:], 0)) if free_s else None
    return th, c, std, sp, s_std, cond


#: step on S's terms of the gain's central differences (``_gain_curvature``): half the
#: prior's std
CURVATURE_STEP = S_PRIOR_STD / 2


def _gain_curvature(jac, x, n_x, cols, hess, h=CURVATURE_STEP):
    """Return (3, 6, n_s, n_s) d^2 thermal / d (s_m, s_n): the Gauss-Newton gain's derivative.

    ``jac(p)``: the refinement's Jacobian (S's columns last, after ``n_x``); ``hess``: its
    J'J at the solution ``x``. The gain -H_xx^-1 H_xs is re-evaluated at the solution
    moved along itself by +- ``h`` on each of S's terms (the first-order path of the fit at
    a fixed S), and differenced: six Jacobians, no refit (on a simulated cold start, 1810
    windows: 0.03 s, and within 0.002 of ten refits at fixed S, which took 2.6 s).
    """
    def gain(hs):
        return -np.linalg.pinv(hs[:n_x, :n_x]) @ hs[:n_x, n_x:]                # (n_x, n_s)

    def full_gain(p):
        j = jac(p)
        return gain(j.T @ j)

    g0 = gain(hess)
    n_s, nc = g0.shape[1], len(cols)
    d = np.zeros((3 * nc, n_s, n_s))
    for m in range(n_s):
        step = h * np.r_[g0[:, m], np.eye(n_s)[m]]
        d[:, :, m] = (full_gain(x + step)[:3 * nc] - full_gain(x - step)[:3 * nc]) / (2 * h)
    curv = np.zeros((3, 6, n_s, n_s))
    curv[:, cols] = d.reshape(3, nc, n_s, n_s)
    return (curv + curv.swapaxes(2, 3)) / 2


def _s_condition(hess, n_x, cols, scale, q):
    """Return the ``SCondition`` of a refinement with S free (Gauss-Newton ``hess``).

    ``n_x``: thermal and tilt columns before S's; ``scale``: the covariance's factor
    (reduced chi-square, at least 1); ``q``: the fitted terms. Given S, the thermal and tilt
    block's covariance is pinv(H_xx) scale and its regression on S -pinv(H_xx) H_xs; S's
    marginal information is the Schur complement, from which the prior's is removed.
    """
    hxx, hxs, hss = hess[:n_x, :n_x], hess[:n_x, n_x:], hess[n_x:, n_x:]
    hxx_inv = np.linalg.pinv(hxx)
    nc = len(cols)
    gain, std = np.zeros((3, 6, len(q))), np.zeros((3, 6))
    gain[:, cols] = (-hxx_inv[:3 * nc] @ hxs).reshape(3, nc, len(q))
    std[:, cols] = np.sqrt(np.maximum(np.diag(hxx_inv)[:3 * nc] * scale, 0)).reshape(3, nc)
    post = hss - hxs.T @ hxx_inv @ hxs
    return SCondition(gain, std, (post - np.eye(len(q)) / S_PRIOR_STD ** 2) / scale,
                      post @ q / scale)


def per_axis_vertical_range(windows, axis_temps, tilts, hold_ids, min_cos=0.7):
    """Return (3, 2) per-axis [min, max] temperature (degC) seen with that axis near vertical.

    NaN where an axis was never near vertical. Outside this range the axis' scale and bias
    temperature terms are extrapolated (seed 000 sect. 3: the sensitivity is largest with
    the axis vertical).
    """
    out = np.full((3, 2), np.nan)
    idx = {h: j for j, h in enumerate(hold_ids)}
    c = tilts[[idx[h] for h in windows.hold]]
    for i in range(3):
        sel = np.abs(c[:, i]) >= min_cos
        if np.any(sel):
            out[i] = [float(axis_temps[sel, i].min()), float(axis_temps[sel, i].max())]
    return out


__all__ = ['FieldFit', 'fit_field_model', 'kkt_unit_tilt', 'THERMAL_NAMES']
