"""Static gyroscope fit: bias and g-sensitivity from stationary windows.

Raw means y_w in rad/s, corrected specific force a_w::

    y_w = beta + cw(X_w) + G a_w + Omega1^-1 w_earth(hold)          (raw domain)

so that the seed 002 model ``w = Omega0 + Omega1 W + ... + C a`` (models.whole_unit)
gets ``Omega0 = -Omega1 beta`` and ``C = -Omega1 G``. The earth rate in the sensor
frame is ``W_e (sin(lat) u + cos(lat) (cos(psi) e1 + sin(psi) e2))`` with u the
hold's up direction (from the corrected accelerometer) and e1, e2 spanning its
horizontal plane:

* latitude given: the vertical component is removed exactly; the heading psi of
  each hold is unknown, so the horizontal component (fixed magnitude) is a
  per-hold nuisance angle;
* latitude unknown: the horizontal magnitude becomes one more nuisance (0..W_e),
  and the vertical component ``W_e sin(lat) u`` is indistinguishable from an
  isotropic g-sensitivity (both are proportional to u): it stays in the diagonal
  of C (at most 7.4e-6 rad/s per m/s^2), which the notes say.
"""

from dataclasses import dataclass

import numpy as np

from ..collection.outliers import robust_scale
from .observability import CONVENTION, decide_determined, DETERMINED_RATIO, Layout, Priors


EARTH_RATE = 7.2921150e-5    # rad/s, WGS84


def earth_rate_parts(latitude):
    """Return (vertical, horizontal) earth rate (rad/s) at a latitude (deg)."""
    lat = np.radians(latitude)
    return EARTH_RATE * np.sin(lat), EARTH_RATE * np.cos(lat)


# ------------------------------------------------------------------------ static fit
def _hold_frames(windows, acc):
    """Return (hold ids, index per window, (h, 3) up, e1, e2) from corrected accel means."""
    ids, inv = np.unique(windows.hold, return_inverse=True)
    up = np.zeros((len(ids), 3))
    np.add.at(up, inv, acc * windows.n[:, None])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    ref = np.eye(3)[np.argmin(np.abs(up), axis=1)]
    e1 = np.cross(up, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(up, e1)
    return ids, inv, up, e1, e2


@dataclass
class StaticGyroFit:
    """Raw-domain static solution: y = beta + cw(X) + G a + Omega1^-1 w_earth."""

    beta: np.ndarray
    offset: np.ndarray                # (no + 1, 3), row 0 = 0 (convention)
    g: np.ndarray                     # (3, 3)
    std: dict
    estimated: dict
    fixed: dict
    ratios: dict
    heading: np.ndarray               # (h,) rad nuisance per hold
    horizontal_fraction: float        # |horizontal earth rate| / W_e used
    residual_rms: float               # rad/s, window means
    outlier_holds: list
    notes: list


def _normal_solve(a, b):
    """Least squares by normal equations with column scaling (small, well-posed systems)."""
    if a.shape[1] == 0:
        return np.zeros(0)
    cs = np.sqrt(np.sum(a * a, axis=0))
    cs[cs == 0] = 1.0
    an = a / cs
    try:
        sol = np.linalg.solve(an.T @ an, an.T @ b)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(an, b, rcond=None)[0]
    return sol / cs


def _scaled_solver(n):
    """Return b -> the solution of the normal equations ``n s = b`` as ``_normal_solve`` finds it.

    Scaling the design columns by their norms (``_normal_solve``) is scaling ``n`` by
    sqrt(diag(n)) on both sides. Raises LinAlgError when the scaled matrix is singular.
    """
    cs = np.sqrt(np.diag(n))
    cs[cs == 0] = 1.0
    inv = np.linalg.inv(n / np.outer(cs, cs))
    return lambda b: inv @ (b / cs) / cs


class _AxisBlocks:
    """The linear design of the static fit, one small dense block per gyro axis.

    ``x`` (m, 3, n_lin) is block diagonal: axis i depends only on the columns ``cols[i]``
    (beta[i], cw_j[i], row i of G), so its weighted normal matrix is the sum over axes of
    ``D_i^T W_i D_i`` scattered into those columns. ``d`` (3, m, p) holds the blocks D_i,
    ``q`` (3, m, p * p) the row outer products (the normal matrix is then one weighted
    sum per axis).
    """

    def __init__(self, x, cols):
        self.cols = cols
        self.d = np.ascontiguousarray(x[:, np.arange(3)[:, None], cols].transpose(1, 0, 2))
        m, p = self.d.shape[1:]
        self.q = np.einsum('imp,imq->impq', self.d, self.d).reshape(3, m, p * p)

    def predict(self, theta):
        """Return the (m, 3) linear prediction ``einsum('nik,k->ni', x, theta)``."""
        return np.matmul(self.d, theta[self.cols][:, :, None])[:, :, 0].T

    def system(self, free):
        """Return functions (normal, rhs, gather) of the normal equations of the free columns.

        ``normal(wt)``: ``sum_n x_free^T diag(wt_n) x_free`` (k, k) for (m, 3) weights;
        ``rhs(wy)``: ``sum_n x_free^T wy_n`` (k,); ``gather(r3)``: the (k,) free entries
        of per-axis (3, p) block vectors; k = free.sum(), free columns in order.
        """
        k = int(np.sum(free))
        p = self.cols.shape[1]
        pos = np.full(len(free), -1)
        pos[np.flatnonzero(free)] = np.arange(k)
        lp = pos[self.cols]                                        # (3, p), -1: fixed
        ax, a, b = np.nonzero((lp[:, :, None] >= 0) & (lp[:, None, :] >= 0))
        tn, sn = lp[ax, a] * k + lp[ax, b], (ax * p + a) * p + b
        ax, a = np.nonzero(lp >= 0)
        tr, sr = lp[ax, a], ax * p + a

        def normal(wt):
            out = np.zeros(k * k)
            out[tn] = np.matmul(wt.T[:, None, :], self.q).ravel()[sn]
            return out.reshape(k, k)

        def gather(r3):
            out = np.zeros(k)
            out[tr] = r3.ravel()[sr]
            return out

        def rhs(wy):
            return gather(np.matmul(wy.T[:, None, :], self.d))
        return normal, rhs, gather


class _StaticProblem:
    """Data of the static alternation: window means, design, hold frames, earth-rate model.

    y, sig (m, 3) rad/s; x (m, 3, n_lin) linear design; cols (3, p) the columns of x
    each axis depends on; inv (m,) hold index per window; up, e1, e2 (h, 3) hold frames;
    om1 (3, 3); s_lat, c_lat: sin/cos latitude (0, 1 without latitude); mean, std the
    priors of the linear parameters.
    """

    def __init__(self, y, sig, x, cols, inv, frames, om1, lat, mean, std, k_robust):
        self.y, self.sig, self.x, self.inv = y, sig, x, inv
        self.up, self.e1, self.e2 = frames
        self.om1, self.om1_inv = om1, np.linalg.inv(om1)
        self.lat_known = lat is not None
        self.s_lat = np.sin(np.radians(lat)) if self.lat_known else 0.0
        self.c_lat = np.cos(np.radians(lat)) if self.lat_known else 1.0
        self.mean, self.std, self.k_robust = mean, std, k_robust
        self.blocks = _AxisBlocks(x, cols)
        m, nh = len(y), len(self.up)
        order = np.argsort(inv, kind='stable')     # windows by hold (every hold non-empty)
        self.order = None if np.array_equal(order, np.arange(m)) else order
        self.starts = np.r_[0, np.cumsum(np.bincount(inv, minlength=nh))[:-1]]
        self.up_rate = EARTH_RATE * self.s_lat * self.up[inv]   # vertical earth rate
        self.sig2 = sig ** 2
        self.up_earth = EARTH_RATE * self.s_lat * self.up     # vertical earth rate per hold

    def hold_sum(self, a, axis=0):
        """Return the sums of ``a`` over the windows (along ``axis``) of each hold."""
        if self.order is not None:
            a = np.take(a, self.order, axis=axis)
        return np.add.reduceat(a, self.starts, axis=axis)

    def earth_holds(self, psi, mh, hdir=None):
        """Return the (h, 3) earth rate per hold in the raw domain (rad/s).

        ``hdir``: the horizontal unit directions of the headings psi (``horizontal``) when
        the caller has them.
        """
        if hdir is None:
            hdir = self.horizontal(psi)
        return (self.up_earth + (EARTH_RATE * mh) * hdir) @ self.om1_inv.T

    def horizontal(self, psi):
        """Return the (h, 3) horizontal unit direction of each hold's heading psi (rad)."""
        return np.cos(psi)[:, None] * self.e1 + np.sin(psi)[:, None] * self.e2

    def residual(self, theta, psi, mh):
        """Return the (m, 3) whitened residual, data minus model over sigma."""
        return (self.y - self.blocks.predict(theta) - self.earth_holds(psi, mh)[self.inv]) \
            / self.sig

    def nuisance_rates(self, psi, mh):
        """Return d(earth rate)/d(heading), d(earth rate)/d(magnitude) per window (m, 3).

        Raw domain, rad/s per rad and rad/s; the second is None with a latitude.
        """
        inv, e1, e2 = self.inv, self.e1, self.e2
        dpsi = EARTH_RATE * mh * (-np.sin(psi)[inv, None] * e1[inv]
                                  + np.cos(psi)[inv, None] * e2[inv]) @ self.om1_inv.T
        if self.lat_known:
            return dpsi, None
        return dpsi, EARTH_RATE * self.horizontal(psi)[inv] @ self.om1_inv.T

    def gram(self, psi, mh, wts, size):
        """Return ``J^T diag(wts) J`` (size, size) of the whitened Jacobian, from its blocks.

        J (3m, size) of r = (y - pred) / sigma over (linear, psi[, mh]); the dense one is
        in test_gyro_static_fast as the reference.

        Linear columns: the per-axis normal matrices; a heading column is non-zero on
        its hold's windows only (its block with the others is diagonal).
        """
        n_lin, nh = self.x.shape[2], len(self.up)
        w = wts / self.sig2
        cols, d = self.blocks.cols, self.blocks.d
        dpsi, dmh = self.nuisance_rates(psi, mh)
        out = np.zeros((size, size))
        out[:n_lin, :n_lin] = self.blocks.system(np.ones(n_lin, bool))[0](w)
        lin_psi = self.hold_sum((w * dpsi).T[:, :, None] * d, axis=1)      # (3, h, p)
        for i in range(3):
            out[cols[i], n_lin:n_lin + nh] = lin_psi[i].T
        out[np.arange(n_lin, n_lin + nh), np.arange(n_lin, n_lin + nh)] = \
            self.hold_sum(np.sum(w * dpsi ** 2, axis=1))
        if dmh is not None:
            out[cols, size - 1] = np.matmul((w * dmh).T[:, None, :], d)[:, 0, :]
            out[n_lin:n_lin + nh, size - 1] = self.hold_sum(np.sum(w * dpsi * dmh, axis=1))
            out[size - 1, size - 1] = np.sum(w * dmh ** 2)
        out[n_lin:, :n_lin] = out[:n_lin, n_lin:].T
        out[size - 1, n_lin:size - 1] = out[n_lin:size - 1, size - 1]
        return out

    def dense_step(self, idx, wts, yy, with_prior):
        """Solve one linear step from the dense (3m, k) design (singular-system fallback)."""
        sw = np.sqrt(wts) / self.sig
        a = (self.x[:, :, idx] * sw[:, :, None]).reshape(-1, len(idx))
        b = (yy * sw).ravel()
        if with_prior:
            sd = self.std[idx]
            a = np.vstack([a, np.diag(1.0 / sd)])
            b = np.r_[b, self.mean[idx] / sd]
        return _normal_solve(a, b)


def _row_sums(a):
    """Return ``np.sum(a, axis=1)`` of an (h, 3) array, bit for bit (left to right)."""
    return (a[:, 0] + a[:, 1]) + a[:, 2]


def _alternate(pb, free_lin, theta0, with_prior, weights_kind):
    """Alternate linear LS and closed-form headings; return (theta, psi, mh, r, wts, c).

    Stages 'linear' (then 'soft_l1', 'cauchy' when ``weights_kind`` is 'robust'), each
    until the linear step is < 1e-6 prior std and the headings move < 1e-4 rad. With
    constant weights (the 'linear' stage) every per-window sum of an iteration is a sum
    over holds of precomputed per-hold sums (the earth rate is constant within a hold).
    """
    idx = np.flatnonzero(free_lin)
    k = len(idx)
    bl, sig, inv, om1 = pb.blocks, pb.sig, pb.inv, pb.om1
    normal, rhs, gather = bl.system(free_lin)
    theta = theta0.copy()
    y_fix = pb.y - bl.predict(np.where(free_lin, 0.0, theta))    # fixed columns: invariant
    prior_n = 1.0 / pb.std[idx] ** 2 if with_prior else 0.0
    prior_b = pb.mean[idx] / pb.std[idx] ** 2 if with_prior else 0.0
    std = pb.std[idx]
    psi = np.zeros(len(pb.up))
    mh = pb.c_lat if pb.lat_known else 0.5
    wts = np.ones((len(pb.y), 3))
    stages = ['linear'] if weights_kind == 'linear' else ['linear', 'soft_l1', 'cauchy']
    c = np.inf
    hdir = None                                # horizontal directions of psi, once known

    def solver(wt):
        """Return b -> linear step for the weights wt (None when the system is singular)."""
        if not k:
            return lambda b: np.zeros(0)
        n_eq = normal(wt)
        n_eq[np.diag_indices(k)] += prior_n
        try:
            return _scaled_solver(n_eq)
        except np.linalg.LinAlgError:
            return None

    def linear_step(solve, b, yy):
        if solve is None:           # singular: least squares on the dense design, as before
            return pb.dense_step(idx, wts, yy(), with_prior)
        return solve(b + prior_b)

    for stage in stages:
        if stage != 'linear':
            c = pb.k_robust * max(robust_scale(pb.residual(theta, psi, mh).ravel()), 1.0)
            p_free = bl.predict(np.where(free_lin, theta, 0.0))
        else:                                  # constant weights: per-hold sums, once
            wt = wts / pb.sig2
            ww = np.mean(wt, axis=1)
            hold_wd = pb.hold_sum(wt.T[:, :, None] * bl.d, axis=1)      # (3, h, p)
            hold_pd = pb.hold_sum(ww[:, None] * bl.d, axis=1)           # (3, h, p)
            solve, b_fix = solver(wt), rhs(wt * y_fix)
            dh_fix = pb.hold_sum((y_fix @ om1.T - pb.up_rate) * ww[:, None])
        for _ in range(60):
            if stage == 'linear':
                we = pb.earth_holds(psi, mh, hdir)
                b = b_fix - gather(np.matmul(we.T[:, None, :], hold_wd))
                new = linear_step(solve, b, lambda: y_fix - we[inv])
            else:
                yy = y_fix - np.take(pb.earth_holds(psi, mh, hdir), inv, axis=0)
                r = (yy - p_free) / sig
                wts = (1.0 / np.sqrt(1.0 + (r / c) ** 2) if stage == 'soft_l1' else
                       1.0 / (1.0 + (r / c) ** 2))
                wt = wts / pb.sig2
                new = linear_step(solver(wt), rhs(wt * yy), lambda: yy)
                ww = (wt[:, 0] + wt[:, 1] + wt[:, 2]) / 3.0           # mean over the axes
            step = np.max(np.abs(new - theta[idx]) / std) if k else 0.0
            theta[idx] = new
            # headings (and horizontal magnitude) in closed form, rate domain
            if stage == 'linear':
                th3 = np.where(free_lin, theta, 0.0)[bl.cols][:, :, None]
                dh = dh_fix - np.matmul(hold_pd, th3)[:, :, 0].T @ om1.T
            else:
                p_free = bl.predict(np.where(free_lin, theta, 0.0))
                dh = pb.hold_sum(((y_fix - p_free) @ om1.T - pb.up_rate) * ww[:, None])
            psi_new = np.arctan2(_row_sums(dh * pb.e2), _row_sums(dh * pb.e1))
            if not pb.lat_known:
                hdir = pb.horizontal(psi_new)
                mh = min(max(float(np.sum(dh * hdir)) / (EARTH_RATE * ww.sum()), 0.0), 1.0)
            moved, psi = psi_new - psi, psi_new
            if step < 1e-6:            # the heading change, wrapped: np.angle(exp(1j moved))
                turn = np.exp(1j * moved)
                if float(np.max(np.abs(np.arctan2(turn.imag, turn.real)))) < 1e-4:
                    break
    return theta, psi, mh, pb.residual(theta, psi, mh), wts, c


def _hold_medians(v, inv, nh):
    """Return the (nh,) median of the entries of the rows of ``v`` (m, 3) in each hold."""
    g = np.repeat(inv, v.shape[1])
    s = v.ravel()[np.lexsort((v.ravel(), g))]
    n = np.bincount(g, minlength=nh)
    start = np.cumsum(n) - n
    return (s[start + (n - 1) // 2] + s[start + n // 2]) / 2


def fit_gyro_static(windows, axis_inputs, acc, t0, latitude=None, omega1=None, priors=None,
                    order=2, ratio=DETERMINED_RATIO, robust=True, k_robust=3.0):
    """Estimate the gyro thermal bias polynomial and g-sensitivity from stationary windows.

    windows: Windows (gyro means rad/s); axis_inputs: (m, 3) thermal inputs or None;
    acc: (m, 3) corrected specific force per window (m/s^2); t0: (3,) input reference;
    latitude: degrees or None; omega1: current 3x3 scale/misalignment (identity if None).

    The model is linear in (beta, cw, G) for fixed headings, and each heading (and the
    horizontal magnitude without latitude) has a closed form for fixed linear parameters,
    so the solver alternates the two (with iteratively reweighted soft-L1 then Cauchy
    weights when ``robust``); observability is decided as in ``whole_unit_fit`` from the
    full Jacobian's normal matrix (``_StaticProblem.gram``, built from its blocks), headings
    included as nuisances.
    """
    priors = priors or Priors()
    om1 = np.eye(3) if omega1 is None else np.asarray(omega1, float)
    has_x = axis_inputs is not None
    no = order if has_x else 0
    y = np.asarray(windows.gyro, float)
    m = len(y)
    sig = np.sqrt(np.maximum(windows.gyro_var, 1e-30) / windows.n[:, None])
    dx = (np.asarray(axis_inputs, float) - t0) if has_x else np.zeros((m, 3))
    ids, inv, up, e1, e2 = _hold_frames(windows, acc)
    nh = len(ids)
    lat_known = latitude is not None

    lay = Layout()
    lay.add('beta', (3,), 0.0, priors.gyro_bias)
    lay.add('cw0', (3,), 0.0, 0.0, CONVENTION + ': cw0 = 0, the bias is carried by Omega0 '
            '(exactly redundant)')
    for j in range(1, no + 1):
        lay.add(f'cw{j}', (3,), 0.0, priors.gyro_offset_tc[j - 1])
    lay.add('G', (3, 3), 0.0, priors.g_sensitivity)
    n_lin = lay.size
    lay.add('psi', (nh,), 0.0, np.pi)
    if not lat_known:
        lay.add('mh', (1,), 0.5, 0.5)
    nuis = np.zeros(lay.size, bool)
    nuis[n_lin:] = True

    # linear design per window: (m, 3, n_lin)
    x = np.zeros((m, 3, n_lin))
    x[:, :, lay.slices['beta']] = np.eye(3)
    for j in range(1, no + 1):
        x[:, :, lay.slices[f'cw{j}']] = np.einsum('ij,ni->nij', np.eye(3), dx ** j)
    x[:, :, lay.slices['G']] = np.einsum('ij,nk->nijk', np.eye(3), acc).reshape(m, 3, 9)

    cols = np.array([[lay.slices['beta'].start + i]
                     + [lay.slices[f'cw{j}'].start + i for j in range(1, no + 1)]
                     + [lay.slices['G'].start + 3 * i + k for k in range(3)] for i in range(3)])
    pb = _StaticProblem(y, sig, x, cols, inv, (up, e1, e2), om1, latitude, lay.mean[:n_lin],
                        lay.std[:n_lin], k_robust)

    lin_cand = lay.candidates[:n_lin]
    theta1, psi1, mh1, r1, _, _ = _alternate(pb, lin_cand, lay.mean[:n_lin].copy(), True,
                                             'linear')
    s = max(robust_scale(r1), 1.0)
    chains = [[lay.slices[f'cw{j}'].start + i for j in range(1, no + 1)] for i in range(3)]
    free, ratios = decide_determined(lay, None, s, ratio, chains=chains, nuisance=nuis,
                                     normal=pb.gram(psi1, mh1, np.ones((m, 3)), lay.size))
    theta0 = lay.mean[:n_lin].copy()
    theta0[free[:n_lin]] = theta1[free[:n_lin]]
    theta, psi, mh, r, wts, c = _alternate(pb, free[:n_lin], theta0, False,
                                           'robust' if robust else 'linear')
    scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
    p = np.r_[theta, psi, [] if lat_known else [mh]]
    idx = np.flatnonzero(free | nuis)
    try:
        cov = np.linalg.pinv(pb.gram(psi, mh, wts, lay.size)[np.ix_(idx, idx)]) \
            * max(scale, 1.0) ** 2
        sd = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sd = np.full(len(idx), np.nan)
    std = lay.posterior_std(free, idx, sd)
    offset = np.stack([lay.get(p, f'cw{j}') for j in range(no + 1)])
    rw = r * sig
    holds_bad = []
    if robust:
        hold_r = _hold_medians(np.abs(r), inv, len(ids))
        holds_bad = [int(h) for h, v in zip(ids, hold_r) if v > 4 * max(scale, 1.0)]
    notes = []
    labels = [lay.label(i) for i in range(lay.size) if not free[i] and not nuis[i]
              and lay.reason[i] and not lay.reason[i].startswith(CONVENTION)]
    if labels:
        notes.append(f'gyroscope {", ".join(labels)} not determined by the static holds: '
                     'fixed at the prior (g-sensitivity needs holds in at least three '
                     'non-coplanar directions; thermal terms a temperature span)')
    if lat_known:
        notes.append(f'gyroscope: earth rate removed at latitude {latitude:g} deg (vertical '
                     'component exactly; horizontal component with an unknown heading per '
                     'hold as a nuisance)')
    else:
        notes.append('gyroscope: no latitude given: the horizontal earth rate is a per-hold '
                     'nuisance of unknown magnitude (<= 7.3e-5 rad/s) and the vertical '
                     'component stays in the diagonal of C (<= 7.4e-6 rad/s per m/s^2); pass '
                     '--latitude to remove it')
    if holds_bad:
        notes.append(f'gyroscope: holds {holds_bad} disagree with the others (down-weighted)')
    est = lay.masks(free)
    fixed = lay.reasons(free)
    for k in ('psi', 'mh'):
        est.pop(k, None)
        fixed.pop(k, None)
    return StaticGyroFit(
        lay.get(p, 'beta'), offset, lay.get(p, 'G'),
        {n: lay.get(std, n) for n in lay.names if n not in ('psi', 'mh')}, est, fixed,
        {lay.label(i): v for i, v in ratios.items() if not nuis[i]},
        psi, float(mh), float(np.sqrt(np.mean(rw ** 2))), holds_bad, notes)


def hold_directions(windows, acc):
    """Return dicts hold -> unit up (corrected accel) and hold -> direction std (rad)."""
    ids, inv, up, _, _ = _hold_frames(windows, acc)
    g = np.linalg.norm(acc, axis=1)
    var = np.zeros(len(ids))
    n = np.zeros(len(ids))
    np.add.at(var, inv, np.mean(windows.accel_var, axis=1) * windows.n)
    np.add.at(n, inv, windows.n)
    gm = np.zeros(len(ids))
    np.add.at(gm, inv, g * windows.n)
    gm /= n
    sig = np.sqrt(var / n / n) / gm
    return ({int(h): up[j] for j, h in enumerate(ids)},
            {int(h): float(sig[j]) for j, h in enumerate(ids)})
