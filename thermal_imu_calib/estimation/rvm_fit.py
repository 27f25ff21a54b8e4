"""Relevance Vector Machine regression of thermal errors (seed 003), fitted on window statistics.

Seed 003 (Ning et al.) models the temperature error with an RVM (Tipping): targets
``t = Phi w + noise`` (eqs. 6-8) with one Gaussian prior precision per weight (eq. 10);
the evidence is maximised by the fixed-point updates ``alpha_i = gamma_i / mu_i^2`` and
``sigma^2 = |t - Phi mu|^2 / (N - sum gamma)`` (eqs. 26-27) around the posterior
``Sigma = (sigma^-2 Phi^T Phi + A)^-1``, ``mu = sigma^-2 Sigma Phi^T t`` (eqs. 16-17); most
alphas diverge and their basis functions are pruned, the rest are the relevance vectors.
The prediction is ``mu^T phi(x)`` with variance ``sigma^2 + phi^T Sigma phi`` (eqs. 30-31).

These are exactly the updates of scikit-learn's ``ARDRegression`` (``lambda_`` there is the
weight precision alpha here, ``alpha_`` there the noise precision 1/sigma^2); ``sbl_fit``
runs them on a batch of design matrices at once (one per hyperparameter set, CV fold and
axis) using the Gram matrices, which is what makes the grid search fast. The test suite
checks it against ``ARDRegression`` to the last digits.

Kernel (eq. 33) on inputs normalised to [-1, 1] (eq. 34)::

    K(x, xi) = lambda exp(-|x - xi|^2 / (2 sigma2)) + (1 - lambda) (x xi + 1)^d

Basis candidates are ``n_centres`` quantiles of the training inputs (snapped to a grid of
as many points) rather than every training point: the design stays N x 17 instead of N x N,
and the sparse prior prunes further. Bias- and scale-type errors are separated by pose as
in seed 003 sect. 3: with a pose factor ``u`` (the axis' share of gravity, +-1 vertical,
0 horizontal) the design is ``[1, K(x, c)] + u [1, K(x, c)]``, so horizontal holds pin the
bias and vertical ones the scale factor; one orientation only gives the offset part.

Hyperparameters (sigma2, d, lambda) are chosen per axis by grouped cross-validation on the
training data (leave one temperature leg, hold or time block out), never on test data.
"""

from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np
from scipy import linalg

from ..models.rvm import kernel as mixed_kernel, RvmAxis, RvmModel

#: ARD hyperprior shape/rate (the same small values as scikit-learn's defaults)
HYPERPRIOR = 1e-6


def normalise(x, lo, hi):
    """Map x from [lo, hi] to [-1, 1] (seed 003 eq. 34); a zero span maps to 0."""
    lo = np.asarray(lo, float)
    span = np.asarray(hi, float) - lo
    return 2.0 * (np.asarray(x, float) - lo) / np.where(span > 0, span, 1.0) - 1.0


def denormalise(y, lo, hi):
    """Invert ``normalise``."""
    lo = np.asarray(lo, float)
    return lo + (np.asarray(y, float) + 1.0) * 0.5 * (np.asarray(hi, float) - lo)


def design(x, centres, sigma2, d, lam, u=None):
    """Return the design matrix [1, K(x, c)] (+ u [1, K(x, c)] with a pose factor u)."""
    x = np.asarray(x, float)
    base = np.concatenate([np.ones(x.shape + (1,)), mixed_kernel(x, centres, sigma2, d, lam)],
                          axis=-1)
    if u is None:
        return base
    return np.concatenate([base, np.asarray(u, float)[..., None] * base], axis=-1)


@dataclass
class SblResult:
    """Batched sparse Bayesian learning result (normalised units), batch index first."""

    mu: np.ndarray        # (B, M) posterior mean weights, 0 where pruned (eq. 17)
    sigma: np.ndarray     # (B, M, M) posterior covariance, 0 rows/cols where pruned (eq. 16)
    alpha: np.ndarray     # (B, M) weight precisions (eq. 26)
    beta: np.ndarray      # (B,) noise precision 1/sigma^2 (eq. 27)
    keep: np.ndarray      # (B, M) bool, the relevance vectors
    n_iter: np.ndarray    # (B,) iterations used


def _posterior(gram, h, alpha, beta, keep):
    """Return (Sigma, mu) for a batch, with pruned basis functions removed."""
    m = gram.shape[1]
    kk = keep[:, :, None] & keep[:, None, :]
    a = np.where(kk, beta[:, None, None] * gram, 0.0)
    a[:, np.arange(m), np.arange(m)] += np.where(keep, alpha, 1.0)
    try:
        sig = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        sig = np.stack([linalg.pinvh(ai) for ai in a])
    sig = np.where(kk, sig, 0.0)
    mu = beta[:, None] * (sig @ np.where(keep, h, 0.0)[:, :, None])[:, :, 0]
    return sig, mu


def sbl_fit(phi, t, rows=None, max_iter=300, tol=1e-3, threshold=1e4):
    """Fit a batch of RVMs: phi (B, N, M) designs, t (B, N) targets, rows (B, N) bool.

    ``rows`` selects the training rows of each batch element (CV folds share one design).
    Same initialisation, updates, pruning (alpha >= ``threshold``) and stopping rule
    (sum |mu - mu_old| < ``tol``) as ``sklearn.linear_model.ARDRegression`` without
    intercept. Returns ``SblResult``.
    """
    phi = np.asarray(phi, float)
    t = np.asarray(t, float)
    bsz, n, m = phi.shape
    w = np.ones((bsz, n)) if rows is None else np.asarray(rows, float)
    pw = phi * w[:, :, None]
    gram = pw.transpose(0, 2, 1) @ phi
    h = (pw.transpose(0, 2, 1) @ t[:, :, None])[:, :, 0]
    tt = np.einsum('bn,bn,bn->b', t, w, t)
    cnt = w.sum(1)
    mean_t = np.einsum('bn,bn->b', w, t) / cnt
    var_t = tt / cnt - mean_t ** 2
    eps = np.finfo(float).eps
    beta = 1.0 / (var_t + eps)
    alpha = np.ones((bsz, m))
    keep = np.ones((bsz, m), bool)
    mu = np.zeros((bsz, m))
    n_iter = np.zeros(bsz, int)
    active = np.ones(bsz, bool)
    for it in range(max_iter):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        g, hh, kp, al, be = gram[idx], h[idx], keep[idx], alpha[idx], beta[idx]
        sig, mu_new = _posterior(g, hh, al, be, kp)
        sse = tt[idx] - 2 * np.sum(mu_new * hh, 1) \
            + np.sum(mu_new * (g @ mu_new[:, :, None])[:, :, 0], 1)
        diag = np.diagonal(sig, axis1=1, axis2=2)
        gamma = np.where(kp, 1.0 - al * diag, 0.0)
        al = np.where(kp, (gamma + 2 * HYPERPRIOR) / (mu_new ** 2 + 2 * HYPERPRIOR), al)
        be = (cnt[idx] - gamma.sum(1) + 2 * HYPERPRIOR) / (np.maximum(sse, 0) + 2 * HYPERPRIOR)
        kp = al < threshold
        mu_new = np.where(kp, mu_new, 0.0)
        done = np.abs(mu_new - mu[idx]).sum(1) < tol if it > 0 else np.zeros(len(idx), bool)
        done |= ~kp.any(1)
        alpha[idx], beta[idx], keep[idx], mu[idx] = al, be, kp, mu_new
        n_iter[idx] = it + 1
        active[idx[done]] = False
    sig, mu = _posterior(gram, h, alpha, beta, keep)
    mu = np.where(keep, mu, 0.0)
    return SblResult(mu, sig, alpha, beta, keep, n_iter)


@dataclass
class RvmSettings:
    """Grid and solver settings; inputs are normalised, so the grids are unit-free."""

    sigma2_grid: Tuple[float, ...] = (2.0 ** -5, 2.0 ** -3, 2.0 ** -1, 2.0)
    d_grid: Tuple[int, ...] = (1, 2, 3)
    lambda_grid: Tuple[float, ...] = (0.0, 0.5, 1.0)
    n_centres: int = 16
    #: windows are merged (consecutive, within a hold) into at most this many points
    max_points: int = 300
    max_folds: int = 6
    max_iter: int = 300
    #: the CV fits stop earlier: later iterations only drive pruned precisions to infinity
    cv_max_iter: int = 100
    tol: float = 1e-3
    #: prune a basis function when its weight precision exceeds this (normalised units)
    threshold: float = 1e4

    def grid(self):
        """Return the distinct (sigma2, d, lambda) triples (d unused at lambda 1 etc.)."""
        out = []
        for lam in self.lambda_grid:
            for s2 in (self.sigma2_grid if lam > 0 else (1.0,)):
                for d in (self.d_grid if lam < 1 else (1,)):
                    out.append((float(s2), int(d), float(lam)))
        return out


@dataclass
class AxisFit:
    """One axis' RVM in normalised units plus its normalisation and CV record."""

    centres: np.ndarray          # (m,) normalised candidate centres
    kernel: Tuple[float, int, float]
    mu: np.ndarray               # (M,) weights over the full candidate design
    sigma: np.ndarray            # (M, M)
    keep: np.ndarray             # (M,) bool
    beta: float
    x_range: Tuple[float, float]  # degC
    y_range: Tuple[float, float]  # target units
    cv_rmse: float               # normalised held-out RMS error of the chosen kernel
    cv_table: dict = field(default_factory=dict)
    has_scale: bool = False

    @property
    def relevance(self):
        """Return the number of relevance vectors (kept basis functions)."""
        return int(self.keep.sum())


def fold_ids(groups, max_folds):
    """Map group labels to at most ``max_folds`` CV folds (whole groups, round robin)."""
    ug, inv = np.unique(np.asarray(groups), return_inverse=True)
    if len(ug) <= max_folds:
        return inv
    return inv % max_folds


def fit_axes(x, y, groups, u=None, settings=None, x_range=None, kernels=None):
    """Fit one RVM per axis with per-axis kernel hyperparameters chosen by grouped CV.

    x: (N, 3) input temperature per axis, degC; y: (N, 3) targets; groups: (N,) CV groups
    (at least 2 distinct); u: optional (N, 3) pose factors (bias/scale separation).
    ``kernels`` (three (sigma2, d, lambda)) skips the search and only fits the weights.
    Returns a list of three ``AxisFit``.
    """
    s = settings or RvmSettings()
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    n = x.shape[0]
    folds = fold_ids(groups, s.max_folds)
    nf = int(folds.max()) + 1
    if nf < 2 and kernels is None:
        raise ValueError('RVM cross-validation needs at least two groups (legs, holds or '
                         'time blocks) of training data')
    grid = s.grid() if kernels is None else [tuple(k) for k in kernels]
    if x_range is None:
        x_range = np.stack([x.min(0), x.max(0)], 1)
    y_range = np.stack([y.min(0), y.max(0)], 1)
    xn = normalise(x, x_range[:, 0], x_range[:, 1])
    yn = normalise(y, y_range[:, 0], y_range[:, 1])
    # candidate centres: quantiles of the inputs snapped to a grid of n_centres points, so a
    # dwell at one temperature does not yield several nearly identical basis functions
    half = 0.5 * (s.n_centres - 1)
    cents = [np.unique(np.round((np.quantile(xn[:, a], np.linspace(0, 1, s.n_centres)) + 1.0)
                                * half)) / half - 1.0 for a in range(3)]
    # batch: (kernel, axis) designs; CV folds share a design and differ in rows
    designs = {}
    for a in range(3):
        ua = None if u is None else u[:, a]
        for j, (s2, d, lam) in enumerate(grid):
            designs[j, a] = design(xn[:, a], cents[a], s2, d, lam, ua)
    width = max(p.shape[1] for p in designs.values())
    keys = list(designs)

    def stack(sel_keys):
        out = np.zeros((len(sel_keys), n, width))
        for i, key in enumerate(sel_keys):
            p = designs[key]
            out[i, :, :p.shape[1]] = p
        return out

    if kernels is not None:   # fixed kernel per axis: no search
        keys = [(a, a) for a in range(3)]
        nf = 0
    # one batch: every (kernel, axis) design once per CV fold, the fold as a row mask
    batch = [(key, f) for f in range(nf) for key in keys]
    cv_sse = np.full((len(grid), 3), np.nan)
    if batch:
        phi = stack([key for key, _ in batch])
        targets = np.stack([yn[:, key[1]] for key, _ in batch])
        train = np.stack([folds != f for _, f in batch])
        res = sbl_fit(phi, targets, train, s.cv_max_iter, s.tol, s.threshold)
        err = (np.einsum('bnm,bm->bn', phi, res.mu) - targets) ** 2 * ~train
        cv_sse[:] = 0.0
        for i, ((j, a), _) in enumerate(batch):
            cv_sse[j, a] += float(err[i].sum())
    cv_rmse = np.sqrt(cv_sse / float(n))
    best = np.arange(3) if kernels is not None else np.argmin(cv_rmse, axis=0)
    final_keys = [(int(best[a]), a) for a in range(3)]
    phi = stack(final_keys)
    res = sbl_fit(phi, np.stack([yn[:, a] for a in range(3)]), None, s.max_iter, s.tol,
                  s.threshold)
    fits = []
    for a in range(3):
        m = designs[final_keys[a]].shape[1]
        table = {} if kernels is not None else {
            f's2={g[0]:g} d={g[1]} l={g[2]:g}': float(cv_rmse[j, a]) for j, g in enumerate(grid)}
        fits.append(AxisFit(cents[a], grid[best[a]], res.mu[a, :m], res.sigma[a, :m, :m],
                            res.keep[a, :m], float(res.beta[a]), tuple(x_range[a]),
                            tuple(y_range[a]), float(cv_rmse[best[a], a]), table,
                            u is not None))
    return fits


def aggregate(keys, t, n, cols, max_points):
    """Merge consecutive rows sharing ``keys`` into blocks so at most ``max_points`` remain.

    keys: (m,) block boundaries never cross a change of key (hold, leg); t: (m,) times
    (sort order); n: (m,) sample counts (weights); cols: dict of (m, ...) arrays averaged
    with weights n. Returns (block id per row, dict of block means, block weights).
    """
    order = np.lexsort((t, keys))
    m = len(t)
    per = max(1, int(np.ceil(m / max(max_points, 1))))
    kk = keys[order]
    start = np.r_[True, kk[1:] != kk[:-1]]
    run = np.cumsum(start) - 1
    pos = np.arange(m) - np.flatnonzero(start)[run]
    block_sorted = np.cumsum(np.r_[True, (start[1:] | (pos[1:] % per == 0))]) - 1
    block = np.empty(m, int)
    block[order] = block_sorted
    nb = int(block.max()) + 1
    wts = np.bincount(block, weights=n, minlength=nb)
    out = {}
    for name, v in cols.items():
        v = np.asarray(v, float)
        flat = v.reshape(m, -1)
        acc = np.stack([np.bincount(block, weights=flat[:, j] * n, minlength=nb)
                        for j in range(flat.shape[1])], 1)
        out[name] = (acc / wts[:, None]).reshape((nb,) + v.shape[1:])
    return block, out, wts


@dataclass
class Prepared:
    """Training points after aggregation (what the RVM sees), physical units."""

    x: np.ndarray               # (N, 3) input temperature per axis, degC
    y: np.ndarray               # (N, 3) targets
    groups: np.ndarray          # (N,) CV groups
    noise_var: np.ndarray       # (3,) median white-noise variance of a point
    u: Optional[np.ndarray] = None   # (N, 3) pose factors
    windows: int = 0


def prepare(windows, axis_temps, y, groups, signal='accel', u=None, max_points=300):
    """Merge windows into at most ``max_points`` training points (never across groups).

    y: (m, 3) per-window targets; ``signal`` names the variance field of the windows
    used for the white-noise level. Returns ``Prepared``.
    """
    groups = np.asarray(groups)
    var = getattr(windows, f'{signal}_var') / np.maximum(windows.n, 1)[:, None]
    cols = {'x': axis_temps, 'y': y, 'v': var * windows.n[:, None] ** 2}
    if u is not None:
        cols['u'] = u
    keys = np.unique(groups, return_inverse=True)[1]
    block, out, wts = aggregate(keys, windows.t0, windows.n.astype(float), cols, max_points)
    grp = np.zeros(len(wts), groups.dtype)
    grp[block] = groups
    # variance of a weighted block mean: sum n_i^2 var_i / (sum n_i)^2
    noise = out['v'] * wts[:, None] / wts[:, None] ** 2
    return Prepared(out['x'], out['y'], grp, np.median(noise, 0), out.get('u'), len(windows))


def _axis_model(fit, x_range):
    """Convert an AxisFit (full candidate design) to an RvmAxis with kept columns only."""
    nc = len(fit.centres)
    lo, hi = x_range
    to_deg = lo + (fit.centres + 1.0) * 0.5 * (hi - lo)
    kb = np.flatnonzero(fit.keep[1:nc + 1])
    cols = [0] + list(kb + 1)
    rv_s = w_s = None
    if fit.has_scale:
        ks = np.flatnonzero(fit.keep[nc + 2:])
        cols_s = [nc + 1] + list(ks + nc + 2)
        rv_s, w_s = to_deg[ks], fit.mu[cols_s]
        cols = cols + cols_s
    cov = fit.sigma[np.ix_(cols, cols)]
    return RvmAxis(to_deg[kb], fit.mu[[0] + list(kb + 1)], rv_s, w_s, cov)


def build_model(prep, fits, mode, sensor, offset_only=False, t_ref=None, k0=None, b0=None,
                s=None, gravity=9.80665):
    """Return the RvmModel for per-axis fits, with noise and misfit levels."""
    x_range = np.array([f.x_range for f in fits])
    y_range = np.array([f.y_range for f in fits])
    half = 0.5 * (y_range[:, 1] - y_range[:, 0])
    noise = half / np.sqrt([f.beta for f in fits])
    misfit = np.sqrt(np.maximum(noise ** 2 - prep.noise_var, 0.0))
    axes = [_axis_model(f, x_range[a]) for a, f in enumerate(fits)]
    kern = np.array([f.kernel for f in fits], float)
    return RvmModel(axes, x_range, y_range, kern, mode=mode, sensor=sensor,
                    offset_only=offset_only, t_ref=t_ref, k0=k0, b0=b0, s=s, noise_std=noise,
                    misfit_std=misfit, gravity=gravity)


def fit_report(prep, fits, seconds):
    """Return a plain-dict summary of a fit (kernel, relevance vectors, CV error)."""
    half = np.array([0.5 * (f.y_range[1] - f.y_range[0]) for f in fits])
    return {'training_points': int(prep.x.shape[0]), 'windows': prep.windows,
            'cv_groups': int(len(np.unique(prep.groups))),
            'kernel': [{'sigma2': f.kernel[0], 'd': f.kernel[1], 'lambda': f.kernel[2]}
                       for f in fits],
            'relevance_vectors': [f.relevance for f in fits],
            'cv_rms': [float(f.cv_rmse * h) for f, h in zip(fits, half)],
            'seconds': round(float(seconds), 3)}


def fit_rvm_offset(windows, axis_temps, signal, sensor, groups, offset_only=False,
                   t_ref=None, settings=None, kernels=None):
    """Fit an offset-mode RvmModel of ``signal`` ('accel'/'gyro') vs per-axis temperature.

    Single orientation (accel, ``offset_only``: drift relative to ``t_ref``) or gyro bias.
    Returns (model, report).
    """
    import time
    s = settings or RvmSettings()
    t_start = time.perf_counter()
    prep = prepare(windows, axis_temps, getattr(windows, signal), groups, signal,
                   max_points=s.max_points)
    fits = fit_axes(prep.x, prep.y, prep.groups, None, s, kernels=kernels)
    ref = np.asarray(t_ref, float) if t_ref is not None else prep.x.mean(0)
    model = build_model(prep, fits, 'offset', sensor, offset_only, ref)
    return model, fit_report(prep, fits, time.perf_counter() - t_start)


def fit_rvm_bias_scale(windows, axis_temps, up, groups, gravity, k0=None, b0=None, s=None,
                       settings=None, kernels=None):
    """Fit a bias_scale-mode accelerometer RvmModel from multi-position windows.

    ``up`` (m, 3) is the unit specific-force direction of each window in the sensor frame
    (the hold tilts of the field estimator): ``(S f)_i / g`` is each axis' pose factor
    u, so horizontal holds (u = 0) see only the bias, vertical ones bias +- scale.
    Returns (model, report).
    """
    import time
    st = settings or RvmSettings()
    t_start = time.perf_counter()
    k0 = np.ones(3) if k0 is None else np.asarray(k0, float)
    b0 = np.zeros(3) if b0 is None else np.asarray(b0, float)
    s = np.eye(3) if s is None else np.asarray(s, float)
    sf = gravity * np.asarray(up, float) @ s.T
    y = windows.accel - b0 - k0 * sf
    prep = prepare(windows, axis_temps, y, groups, 'accel', u=sf / gravity,
                   max_points=st.max_points)
    fits = fit_axes(prep.x, prep.y, prep.groups, prep.u, st, kernels=kernels)
    model = build_model(prep, fits, 'bias_scale', 'accel', k0=k0, b0=b0, s=s,
                        gravity=gravity, t_ref=prep.x.mean(0))
    return model, fit_report(prep, fits, time.perf_counter() - t_start)
