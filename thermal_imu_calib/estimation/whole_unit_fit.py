"""Seed 002 whole-unit accelerometer model from static poses of unknown orientation.

Residual (one per stationary window w, whitened by the window's standard error)::

    r_w = (|a(U_w, T_w)| - g) / sigma_w,    a = A0 + A1 V + A2 o V^2 + A3 o V^3,
                                            V = (U - c(T)) / (1 + k(T))

solved with ``scipy.optimize.least_squares`` (analytic Jacobian) and a robust loss
(``outliers.robust_least_squares``), so one bumped hold loses its weight instead of
dragging the fit.

Observability is decided from the data, never assumed. Every candidate parameter has a
prior (mean, standard deviation; ``Priors``, consumer-MEMS magnitudes by default or a
seed 000 lab calibration). With the whitened Jacobian J at a prior-regularised first
fit, scaled by the prior standard deviations, the posterior covariance of the candidates
is ``(J'J / s^2 + I)^-1`` (s: robust residual scale). A parameter is *determined* when its
posterior standard deviation is below ``ratio`` (default 0.5) of its prior one: the data
carry at least three times the prior's information. The least determined candidate is
fixed at its prior and the test repeated (backward elimination), so correlated pairs are
resolved one at a time; a polynomial term is fixed together with the higher orders of
the same axis. This is how, e.g., misalignment is refused for six clean faces (|a| is
flat to first order in a misalignment when gravity lies on an axis) and the 3rd-order
terms for 1-g data (indistinguishable from scale without inputs of several magnitudes).
The final fit frees only the determined parameters (no prior terms); the others are stored
at their prior with ``estimated`` False and the reason, in the file and in the notes.

Register: ``--model whole_unit`` (estimator ``whole_unit``); the gyroscope part is in
``gyro_fit``.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
from scipy.optimize import least_squares

from ..models.whole_unit import WholeUnitAccelModel
from .field_estimator import kkt_unit_tilt_batch
from .outliers import group_outliers, robust_least_squares, robust_scale

#: posterior/prior standard-deviation ratio below which a parameter counts as determined
DETERMINED_RATIO = 0.5
#: the accel frame convention of the field fit (A1 lower-triangular)
FRAME_CONVENTION = ('A1 lower-triangular: frame x = accelerometer x sensing axis, frame y in '
                    'the plane of the x and y sensing axes (seed 000 convention); a norm-only '
                    'fit cannot see a rotation of the whole triad')
CONVENTION = 'convention'
#: folds and parsimony tolerance of the leave-holds-out selection of optional terms
CV_FOLDS = 5
CV_TOLERANCE = 0.01
#: reason stored for a determined parameter that cross-validation drops
CV_REASON = ('determined, but leave-holds-out cross-validation does not support it: fixed at '
             'its prior')
#: residual forms of the accelerometer fit
RESIDUALS = ('norm', 'vector')


# ------------------------------------------------------------------------ parameter layout

def fit_free(resid, std, base, free, with_prior=False, robust=False, tight=True, **kwargs):
    """Least squares over the ``free`` parameters of ``base``, in units of their prior std.

    ``resid(p, want_jac=False)`` returns whitened residuals, or (residuals, (m, n) Jacobian)
    over all n parameters. Free parameters move as ``base + z * std``; with ``with_prior``
    the rows ``z`` (the prior, one sigma each) are appended. ``robust`` uses
    ``outliers.robust_least_squares``; ``tight`` sets xtol = ftol = gtol = 1e-12; other
    ``kwargs`` go to scipy. Returns (parameters, scipy/robust result).
    """
    idx = np.flatnonzero(free)
    sd = std[idx]

    def full(z):
        p = base.copy()
        p[idx] = base[idx] + z * sd
        return p

    def fun(z):
        r = resid(full(z))
        return np.r_[r, z] if with_prior else r

    def jac(z):
        j = resid(full(z), True)[1][:, idx] * sd[None, :]
        return np.vstack([j, np.eye(len(idx))]) if with_prior else j

    if tight:
        kwargs = dict(dict(xtol=1e-12, ftol=1e-12, gtol=1e-12), **kwargs)
    z0 = np.zeros(len(idx))
    solver = robust_least_squares if robust else least_squares
    res = solver(fun, z0, jac=jac, method='trf', **kwargs)
    return full(res.x), res


class Layout:
    """Named parameter blocks flattened into one vector, with priors and a free mask."""

    def __init__(self):
        self.names: List[str] = []
        self.shapes: Dict[str, tuple] = {}
        self.slices: Dict[str, slice] = {}
        self.size = 0
        self.mean = np.zeros(0)
        self.std = np.zeros(0)
        #: per element: None (candidate), CONVENTION, or a reason text when fixed
        self.reason: List[Optional[str]] = []

    def add(self, name, shape, mean, std, reason=None):
        """Append a block; ``reason`` fixes every element (e.g. CONVENTION)."""
        shape = tuple(shape)
        n = int(np.prod(shape)) if shape else 1
        self.names.append(name)
        self.shapes[name] = shape
        self.slices[name] = slice(self.size, self.size + n)
        self.size += n
        self.mean = np.r_[self.mean, np.broadcast_to(np.asarray(mean, float), shape).ravel()]
        self.std = np.r_[self.std, np.broadcast_to(np.asarray(std, float), shape).ravel()]
        self.reason += [reason] * n

    def get(self, p, name):
        """Return block ``name`` of vector p in its shape."""
        return p[self.slices[name]].reshape(self.shapes[name])

    def fix(self, name, index=None, reason=CONVENTION):
        """Fix elements of a block (all, or a flat index / list of flat indices)."""
        sl = self.slices[name]
        idx = range(sl.start, sl.stop) if index is None else \
            [sl.start + i for i in np.atleast_1d(index)]
        for i in idx:
            self.reason[i] = reason

    @property
    def candidates(self):
        """Return the bool mask of elements not fixed (yet)."""
        return np.array([r is None for r in self.reason], bool)

    def label(self, i):
        """Return a readable label of flat element i, e.g. 'A1[1,0]'."""
        for name in self.names:
            sl = self.slices[name]
            if sl.start <= i < sl.stop:
                k = i - sl.start
                shape = self.shapes[name]
                if len(shape) == 2:
                    return f'{name}[{k // shape[1]},{k % shape[1]}]'
                return f'{name}[{"xyz"[k]}]' if shape == (3,) else f'{name}[{k}]'
        raise IndexError(i)

    def block_of(self, i):
        """Return (name, flat index within the block) of element i."""
        for name in self.names:
            sl = self.slices[name]
            if sl.start <= i < sl.stop:
                return name, i - sl.start
        raise IndexError(i)

    def posterior_std(self, free, idx, sd):
        """Return the per-element standard deviation of a fit over the ``free`` elements.

        ``sd`` at the indices ``idx``, the prior std where fixed, 0 for the other free
        elements and for convention entries.
        """
        std = np.where(free, 0.0, self.std)
        std[idx] = sd
        conv = np.array([r is not None and r.startswith(CONVENTION) for r in self.reason])
        std[conv] = 0.0
        return std

    def masks(self, free):
        """Return name -> per-element 'estimated' bool array for a free mask."""
        return {n: free[self.slices[n]].reshape(self.shapes[n]).copy() for n in self.names}

    def reasons(self, free):
        """Return name -> reason text for blocks with fixed elements (one text per block)."""
        out = {}
        for n in self.names:
            sl = self.slices[n]
            rs = sorted({self.reason[i] for i in range(sl.start, sl.stop)
                         if not free[i] and self.reason[i]})
            if rs:
                out[n] = '; '.join(rs)
        return out


def posterior_ratio(jac, prior_std, noise_scale=1.0, prior_weight=None):
    """Return the posterior/prior standard-deviation ratio of each column of ``jac``.

    jac: (m, p) Jacobian of whitened residuals w.r.t. physical parameters; prior_std (p,).
    ``prior_weight`` (p,) scales the prior information (0 for nuisances without a prior).
    """
    js = jac * prior_std[None, :]
    info = js.T @ js / max(noise_scale, 1e-12) ** 2
    pw = np.ones(js.shape[1]) if prior_weight is None else np.asarray(prior_weight, float)
    info = info + np.diag(np.maximum(pw, 1e-9))
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(info)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def decide_determined(layout, jac, noise_scale, ratio=DETERMINED_RATIO, reason='',
                      chains=(), nuisance=None):
    """Backward elimination of undetermined candidates (see the module docstring).

    jac: (m, layout.size) whitened Jacobian. ``chains``: list of lists of flat indices in
    polynomial order; fixing one element fixes the later ones of its chain. ``nuisance``:
    bool mask of elements that always stay free (no prior). Returns (free mask,
    {flat index: posterior ratio}).
    """
    free = layout.candidates.copy()
    nuis = np.zeros(layout.size, bool) if nuisance is None else np.asarray(nuisance, bool)
    later = {}
    for chain in chains:
        for k, i in enumerate(chain):
            later[i] = list(chain[k + 1:])
    ratios = {}
    while True:
        idx = np.flatnonzero(free | nuis)
        if len(idx) == 0:
            break
        pw = np.where(nuis[idx], 1e-6, 1.0)
        r = posterior_ratio(jac[:, idx], layout.std[idx], noise_scale, pw)
        cand = ~nuis[idx]
        for i, v in zip(idx, r):
            ratios[int(i)] = float(v)
        if not np.any(cand):
            break
        worst = int(np.argmax(np.where(cand, r, -np.inf)))
        if r[worst] < ratio:
            break
        i = int(idx[worst])
        for j in [i] + later.get(i, []):
            if free[j]:
                free[j] = False
                layout.reason[j] = reason or 'not determined by the data: fixed at its prior'
    return free, ratios


# ------------------------------------------------------------------------ priors
@dataclass
class Priors:
    """Prior mean/std of the whole-unit parameters (SI; consumer-MEMS magnitudes by default).

    The seed 002 Table 2 ranges (MEMS accelerometers: misalignment 0.1-2 %, 2nd order
    2e-5..1e-4 /g, 3rd order 5e-6..2e-5 /g^2; g-sensitivity 0.01-0.04 deg/s/g) set the
    nonlinear and g-sensitivity scales.
    """

    accel_bias: float = 0.5            # m/s^2, A0
    accel_scale: float = 0.03          # 1, diagonal of A1 around 1
    accel_misalignment: float = 0.01   # rad, off-diagonal of A1
    accel_nonlin2: float = 1e-5        # 1/(m/s^2), A2 (1e-4 /g)
    accel_nonlin3: float = 2e-7        # 1/(m/s^2)^2, A3 (2e-5 /g^2)
    accel_offset_tc: tuple = (3e-3, 5e-5, 1e-6)     # m/s^2/degC^j, j = 1, 2, 3
    accel_scale_tc: tuple = (2e-4, 5e-6, 1e-7)      # 1/degC^j
    gyro_bias: float = 0.05            # rad/s
    gyro_offset_tc: tuple = (5e-4, 1e-5, 3e-7)      # rad/s/degC^j
    gyro_scale: float = 0.03           # 1, diagonal of Omega1
    gyro_misalignment: float = 0.01    # rad, off-diagonal of Omega1
    gyro_nonlin2: float = 2e-3         # 1/(rad/s)
    gyro_nonlin3: float = 2e-4         # 1/(rad/s)^2
    g_sensitivity: float = 1e-4        # rad/s/(m/s^2) (~0.06 deg/s/g)
    #: mean values from a lab calibration: dict name -> array (A0, A1, ct1, kt1, ...)
    accel_mean: dict = field(default_factory=dict)


def prior_from_field_model(pm):
    """Return whole-unit prior means from a seed 000 FieldPolynomialModel (lab k0, b0, S)."""
    k0 = pm.k0 + pm.thermal[:, 0]
    b0 = pm.b0 + pm.thermal[:, 3]
    a1 = np.linalg.inv(pm.s) @ np.diag(1.0 / k0)
    return {'ct0': b0, 'A1': a1, 'ct1': pm.thermal[:, 4], 'ct2': pm.thermal[:, 5],
            'kt1': pm.thermal[:, 1] / k0, 'kt2': pm.thermal[:, 2] / k0}


# ------------------------------------------------------------------------ accel fit
def accel_layout(priors, offset_order, scale_order, has_temperature):
    """Return the Layout of the accel field fit (conventions already fixed)."""
    pm = priors.accel_mean
    lay = Layout()
    lay.add('A0', (3,), 0.0, 0.0, CONVENTION + ': A0 = 0, the bias is carried by ct0 (raw '
            'domain, subtracted before the scale-factor terms as in seed 000; ct0 and A0 '
            'are exactly redundant without scale temperature terms)')
    a1_std = np.full((3, 3), priors.accel_misalignment)
    np.fill_diagonal(a1_std, priors.accel_scale)
    lay.add('A1', (3, 3), pm.get('A1', np.eye(3)), a1_std)
    lay.fix('A1', [1, 2, 5], CONVENTION + ': ' + FRAME_CONVENTION)
    lay.add('A2', (3,), pm.get('A2', 0.0), priors.accel_nonlin2)
    lay.add('A3', (3,), pm.get('A3', 0.0), priors.accel_nonlin3)
    lay.add('ct0', (3,), pm.get('ct0', 0.0), priors.accel_bias)
    tc = 'no temperature input' if not has_temperature else None
    for j in range(1, offset_order + 1):
        lay.add(f'ct{j}', (3,), pm.get(f'ct{j}', 0.0), priors.accel_offset_tc[j - 1], tc)
    for j in range(1, scale_order + 1):
        lay.add(f'kt{j}', (3,), pm.get(f'kt{j}', 0.0), priors.accel_scale_tc[j - 1], tc)
    return lay


def _unpack(lay, p, no, ns):
    offset = np.stack([lay.get(p, f'ct{j}') for j in range(no + 1)])
    scale = (np.stack([lay.get(p, f'kt{j}') for j in range(1, ns + 1)]) if ns
             else np.zeros((0, 3)))
    return offset, scale, lay.get(p, 'A0'), lay.get(p, 'A1'), lay.get(p, 'A2'), \
        lay.get(p, 'A3')


def _accel_and_jac(lay, p, raw, dt, no, ns, want_jac=False):
    """Return corrected a (m, 3) and, optionally, da/dp (m, 3, layout.size)."""
    offset, scale, m0, m1, m2, m3 = _unpack(lay, p, no, ns)
    c = np.zeros_like(dt)
    for row in offset[::-1]:
        c = c * dt + row
    k = np.zeros_like(dt)
    for row in scale[::-1]:
        k = (k + row) * dt
    k = 1.0 + k
    v = (raw - c) / k
    a = m0 + v @ m1.T + m2 * v * v + m3 * v ** 3
    if not want_jac:
        return a, None
    m = raw.shape[0]
    eye = np.eye(3)
    jac = np.zeros((m, 3, lay.size))
    jac[:, :, lay.slices['A0']] = eye
    jac[:, :, lay.slices['A1']] = np.einsum('ij,nk->nijk', eye, v).reshape(m, 3, 9)
    jac[:, :, lay.slices['A2']] = np.einsum('ij,nj->nij', eye, v * v)
    jac[:, :, lay.slices['A3']] = np.einsum('ij,nj->nij', eye, v ** 3)
    d = m1[None] + np.einsum('ni,ij->nij', 2 * m2 * v + 3 * m3 * v * v, eye)   # da/dV
    for j in range(no + 1):
        jac[:, :, lay.slices[f'ct{j}']] = -d * (dt ** j / k)[:, None, :]
    for j in range(1, ns + 1):
        jac[:, :, lay.slices[f'kt{j}']] = -d * (v * dt ** j / k)[:, None, :]
    return a, jac


def _norm_residual(lay, p, raw, dt, sigma, gravity, no, ns, want_jac=False):
    """Whitened |a| - g per window and, optionally, its Jacobian w.r.t. the full vector."""
    a, da = _accel_and_jac(lay, p, raw, dt, no, ns, want_jac)
    na = np.linalg.norm(a, axis=1)
    r = (na - gravity) / sigma
    if not want_jac:
        return r, a
    u = a / na[:, None] / sigma[:, None]                     # d r / d a
    return r, np.einsum('ni,nip->np', u, da)


def _vector_residual(lay, p, raw, dt, weight, hold_idx, nh, gravity, no, ns, want_jac=False):
    """Whitened a - g c_h per window and axis, c_h eliminated (variable projection).

    c_h, the unit up direction of hold h, is the constrained least-squares optimum for the
    current parameters (Newton-KKT, seed 000 eqs. 20-27); the Jacobian is projected onto
    the complement of the tangent directions of c_h (Kaufman), so the hold directions
    are nuisances that never appear as parameters.
    """
    a, da = _accel_and_jac(lay, p, raw, dt, no, ns, want_jac)
    w2 = weight ** 2
    mm = np.zeros((nh, 3, 3))
    vv = np.zeros((nh, 3))
    np.add.at(mm, hold_idx, gravity ** 2 * np.einsum('ni,ij->nij', w2, np.eye(3)))
    np.add.at(vv, hold_idx, gravity * w2 * a)
    c0 = vv / np.linalg.norm(vv, axis=1, keepdims=True)
    c, _, _ = kkt_unit_tilt_batch(mm, vv, c0)
    r = weight * (a - gravity * c[hold_idx])
    if not want_jac:
        return r.ravel(), a
    j = weight[:, :, None] * da                                   # (m, 3, P)
    ref = np.eye(3)[np.argmin(np.abs(c), axis=1)]
    e1 = np.cross(c, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(c, e1)
    b = -gravity * weight[:, :, None] * np.stack([e1[hold_idx], e2[hold_idx]], axis=2)
    btb = np.zeros((nh, 2, 2))
    btj = np.zeros((nh, 2, lay.size))
    np.add.at(btb, hold_idx, np.einsum('nia,nib->nab', b, b))
    np.add.at(btj, hold_idx, np.einsum('nia,nip->nap', b, j))
    coef = np.linalg.solve(btb, btj)                              # (nh, 2, P)
    j = j - np.einsum('nia,nap->nip', b, coef[hold_idx])
    return r.ravel(), j.reshape(-1, lay.size)


@dataclass
class AccelFit:
    """Result of ``fit_whole_unit_accel``."""

    model: WholeUnitAccelModel
    residual_rms: float            # m/s^2, RMS of |a| - g over windows
    chi2_dof: float
    robust_scale: float            # whitened units
    outlier_holds: list
    determined: dict               # label -> posterior ratio (all candidates)
    fixed: dict                    # name -> reason
    notes: list
    nfev: int
    cv: dict = field(default_factory=dict)   # held-out mean squared whitened residual


def window_sigma(windows):
    """Return the (m,) standard error of |mean accel| per window (m/s^2)."""
    u = windows.accel / np.linalg.norm(windows.accel, axis=1, keepdims=True)
    var = np.sum(u * u * np.maximum(windows.accel_var, 1e-30), axis=1) / windows.n
    return np.sqrt(var)


def fit_whole_unit_accel(windows, axis_temps, gravity, t0, priors=None, order=2,
                         scale_order=None, ratio=DETERMINED_RATIO, robust=True,
                         sigma_floor=0.0, select=True, cv_tolerance=CV_TOLERANCE,
                         residual='norm'):
    """Estimate the seed 002 accelerometer model from stationary windows (norm residual).

    windows: estimation.segments.Windows; axis_temps: (m, 3) degC (None: no temperature);
    gravity: m/s^2; t0: (3,) degC reference. ``order``/``scale_order``: maximum offset and
    scale polynomial orders in dT (candidates; the data decide which are determined).
    ``sigma_floor`` (m/s^2) is added in quadrature to each window's standard error (model
    error allowance). ``select``: drop optional terms (nonlinearity, 2nd-order and scale
    temperature terms) that leave-holds-out cross-validation does not support.
    ``residual``: 'norm' (|a| - g per window, the default) or 'vector' (a - g c_h per window
    and axis with the hold direction c_h eliminated: also uses that the direction of a
    hold does not change while its temperature does). Returns an AccelFit.
    """
    priors = priors or Priors()
    has_t = axis_temps is not None
    scale_order = order if scale_order is None else scale_order
    no, ns = (order, scale_order) if has_t else (0, 0)
    raw = np.asarray(windows.accel, float)
    dt = (np.asarray(axis_temps, float) - np.asarray(t0, float)) if has_t else \
        np.zeros_like(raw)
    if residual not in RESIDUALS:
        raise ValueError(f'residual must be one of {RESIDUALS}, not {residual!r}')
    sigma = np.sqrt(window_sigma(windows) ** 2 + sigma_floor ** 2)
    weight = 1.0 / np.sqrt(np.maximum(windows.accel_var, 1e-30) / windows.n[:, None]
                           + sigma_floor ** 2)
    lay = accel_layout(priors, no, ns, has_t)
    chains = [[lay.slices[f'ct{j}'].start + i for j in range(no + 1)] for i in range(3)] + \
        [[lay.slices[f'kt{j}'].start + i for j in range(1, ns + 1)] for i in range(3)]
    per_window = 3 if residual == 'vector' else 1

    def resid(p, rows=None, want_jac=False):
        """Whitened residuals (and Jacobian) of the selected windows (None: all)."""
        sl = np.arange(len(raw)) if rows is None else np.flatnonzero(rows)
        if residual == 'norm':
            r, j = _norm_residual(lay, p, raw[sl], dt[sl], sigma[sl], gravity, no, ns,
                                  want_jac)
        else:
            _, hidx = np.unique(windows.hold[sl], return_inverse=True)
            r, j = _vector_residual(lay, p, raw[sl], dt[sl], weight[sl], hidx,
                                    int(hidx.max()) + 1, gravity, no, ns, want_jac)
        return (r, j) if want_jac else r

    def run(free, base, with_prior, loss_robust, rows=None):
        return fit_free(lambda p, want_jac=False: resid(p, rows, want_jac), lay.std, base,
                        free, with_prior, loss_robust, max_nfev=200,
                        **({'x_scale': 1.0} if loss_robust else {}))

    # 1. prior-regularised fit of every candidate: a point to judge observability at
    p1, res1 = run(lay.candidates, lay.mean, True, False)
    r1, jac1 = resid(p1, None, True)
    s = max(robust_scale(r1), 1.0)
    # 2. decide what the data determine
    free, ratios = decide_determined(lay, jac1, s, ratio, chains=chains)
    # 3. keep the optional terms only where held-out holds support them
    cv = {}
    if select:
        free, cv = _select_by_cv(lay, free, p1, run, resid, windows, ns, no, cv_tolerance)
    # 4. final fit of the determined parameters only, robust loss, no prior rows
    p0 = lay.mean.copy()
    p0[free] = p1[free]
    p, res = run(free, p0, False, robust)
    r, jac = resid(p, None, True)
    scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
    idx = np.flatnonzero(free)
    dof = max(len(r) - len(idx), 1)
    chi2 = float(np.sum(r * r) / dof)
    jf = jac[:, idx]
    w = np.ones(len(r))
    if robust:
        w = (np.abs(r) <= getattr(res, 'f_scale', np.inf)).astype(float)
    try:
        cov = np.linalg.inv((jf * w[:, None]).T @ jf) * max(scale, 1.0) ** 2
        sd = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sd = np.full(len(idx), np.nan)
    std = lay.posterior_std(free, idx, sd)
    offset, scl, m0, m1, m2, m3 = _unpack(lay, p, no, ns)
    est = lay.masks(free)
    fixed = lay.reasons(free)
    model = WholeUnitAccelModel(
        t0, offset, scl, m0, m1, m2, m3,
        std={n: lay.get(std, n) for n in lay.names}, estimated=est, fixed=fixed,
        convention=FRAME_CONVENTION)
    holds_bad = group_outliers(r, np.repeat(windows.hold, per_window),
                               max(scale, 1.0)) if robust else []
    notes = _notes(lay, free, ratios, holds_bad)
    resid = (np.linalg.norm(model.correct(raw, np.asarray(t0) + dt), axis=1) - gravity)
    return AccelFit(model, float(np.sqrt(np.mean(resid ** 2))), chi2, float(scale),
                    holds_bad, {lay.label(i): v for i, v in ratios.items()}, fixed, notes,
                    int(getattr(res, 'nfev', 0) + res1.nfev), cv)


def hold_folds(windows, k=CV_FOLDS):
    """Return a fold id per window: holds in time order dealt round-robin into k folds."""
    ids = windows.hold_ids
    order = np.argsort([windows.t0[windows.hold == h].min() for h in ids])
    fold_of = {int(ids[j]): r % k for r, j in enumerate(order)}
    return np.array([fold_of[int(h)] for h in windows.hold])


def _select_by_cv(lay, free, p1, run, resid, windows, ns, no, tol):
    """Backward selection of optional term groups by leave-holds-out cross-validation.

    A group (A2, A3, the scale temperature terms kt, the 2nd and higher order thermal
    terms) is dropped when the held-out mean squared whitened residual without it is not
    worse than with it by more than ``tol`` (relative): the simpler model wins ties.
    """
    n_holds = len(windows.hold_ids)
    if n_holds < 6:
        return free, {}
    folds = hold_folds(windows, min(CV_FOLDS, n_holds))
    idx_of = {n: np.arange(lay.slices[n].start, lay.slices[n].stop) for n in lay.names}
    groups = {'A2': idx_of['A2'], 'A3': idx_of['A3'],
              'kt': np.concatenate([idx_of[f'kt{j}'] for j in range(1, ns + 1)] or
                                   [np.zeros(0, int)]),
              'order>=2': np.concatenate([idx_of[f'ct{j}'] for j in range(2, no + 1)]
                                         + [idx_of[f'kt{j}'] for j in range(2, ns + 1)]
                                         or [np.zeros(0, int)])}
    groups = {g: i[free[i]] for g, i in groups.items() if np.any(free[i])}

    def cv_error(fr):
        base = lay.mean.copy()
        base[fr] = p1[fr]
        err = 0.0
        for f in np.unique(folds):
            test = folds == f
            p, _ = run(fr, base, False, False, rows=~test)
            r = resid(p, test)
            err += float(np.sum(r * r))
        return err / len(folds)

    current = free.copy()
    best = cv_error(current)
    scores = {'all determined': best}
    while groups:
        trials = {}
        for g, i in groups.items():
            fr = current.copy()
            fr[i] = False
            trials[g] = cv_error(fr)
            scores[f'without {g}'] = trials[g]
        g = min(trials, key=trials.get)
        if trials[g] > best * (1.0 + tol):
            break
        current[groups.pop(g)] = False
        for i in np.flatnonzero(free & ~current):
            if lay.reason[i] is None:
                lay.reason[i] = CV_REASON
        best = min(best, trials[g])
    return current, scores


def _notes(lay, free, ratios, holds_bad):
    """Human notes: which seed 002 parameters were fixed at their prior, and why."""
    notes = []
    groups = {}
    for i in range(lay.size):
        r = lay.reason[i]
        if free[i] or r is None or r.startswith(CONVENTION) or r == 'no temperature input':
            continue
        name, _ = lay.block_of(i)
        groups.setdefault((name, r == CV_REASON), []).append(lay.label(i))
    advice = {'A1': 'misalignment needs poses off the six faces (tilted / corner-up holds)',
              'A2': 'needs inputs of several magnitudes on each axis (1 g only spans '
                    '-g..+g; use tilted poses, or lab mode)',
              'A3': 'needs large inputs (a centrifuge, lab mode) to separate from scale',
              'ct0': 'hold each axis up and down', }
    for (name, by_cv), labels in groups.items():
        if by_cv:
            notes.append(f'accelerometer {", ".join(labels)}: determined, but held-out holds '
                         'do not support it (leave-holds-out cross-validation): fixed at the '
                         'prior')
            continue
        adv = advice.get(name, 'needs a wider temperature span seen in several poses'
                         if name.startswith(('ct', 'kt')) else '')
        notes.append(f'accelerometer {", ".join(labels)} not determined by the data: fixed at '
                     f'the prior ({adv})')
    if holds_bad:
        notes.append(f'holds {holds_bad} disagree with the others (bumped or moving?): '
                     'down-weighted by the robust loss')
    return notes


# ------------------------------------------------------------------------ both triads
@dataclass
class WholeUnitFit:
    """Accelerometer and gyroscope fits of one whole-unit calibration."""

    accel: AccelFit
    gyro: object                 # gyro_fit.GyroFit
    notes: list
    stats: dict


def fit_whole_unit(windows, gravity, axis_temps=None, t0=None, gyro_inputs=None, t0g=None,
                   latitude=None, transitions=None, priors=None, order=2,
                   accel_input=(0, 0, 0), gyro_input=(0, 0, 0), residual='norm',
                   gyro_input_unit='degC', accel_rows=None):
    """Fit both triads from stationary windows (and pose changes); no refusal logic.

    windows: Windows; gravity m/s^2; axis_temps / gyro_inputs: (m, 3) thermal inputs of the
    accel / gyro axes per window (None: temperature-independent); t0 / t0g their references
    (default: middle of the range); latitude (deg) for the earth rate; transitions from
    ``gyro_fit.MotionCollector``; ``accel_rows``: bool mask of the windows the accelerometer
    is fitted on (default all; the gyro always uses every window, its hold directions come
    from the fitted accelerometer). Returns WholeUnitFit (models in ``.accel.model`` and
    ``.gyro.model``).
    """
    from .gyro_fit import fit_gyro
    priors = priors or Priors()
    m = len(windows)
    if axis_temps is not None and t0 is None:
        t0 = np.round((axis_temps.min(0) + axis_temps.max(0)) / 2.0, 2)
    if gyro_inputs is not None and t0g is None:
        t0g = np.round((gyro_inputs.min(0) + gyro_inputs.max(0)) / 2.0, 2)
    t0 = np.zeros(3) if t0 is None else np.asarray(t0, float)
    t0g = np.zeros(3) if t0g is None else np.asarray(t0g, float)
    rows = np.ones(m, bool) if accel_rows is None else np.asarray(accel_rows, bool)
    fit = fit_whole_unit_accel(windows.select(rows),
                               None if axis_temps is None else axis_temps[rows], gravity, t0,
                               priors, order=order if axis_temps is not None else 0,
                               residual=residual)
    am = fit.model
    acc = am.correct(windows.accel, axis_temps if axis_temps is not None
                     else np.broadcast_to(am.t0, (m, 3)))
    gfit = fit_gyro(windows, gyro_inputs, acc, t0g, latitude=latitude,
                    transitions=transitions, accel_model=am, accel_input=accel_input,
                    gyro_input=gyro_input, priors=priors,
                    order=order if gyro_inputs is not None else 0, input_unit=gyro_input_unit)
    n_est, n_fix = am.count()
    g_est, g_fix = gfit.model.count()
    notes = [f'seed 002 whole-unit model: {n_est + g_est} of {n_est + n_fix + g_est + g_fix} '
             'coefficients (the 63 of seed 002 plus the scale temperature terms) estimated '
             'from the data, the rest fixed (see meta.estimated and meta.fixed of each model)'
             ] + fit.notes + gfit.notes
    stats = {'residual_rms': {'value': fit.residual_rms, 'unit': 'm/s^2'},
             'chi2_per_dof': fit.chi2_dof, 'robust_scale': fit.robust_scale,
             'outlier_holds': fit.outlier_holds, 'accel_residual': residual,
             'accel_estimated': n_est, 'accel_fixed': n_fix,
             'gyro_estimated': g_est, 'gyro_fixed': g_fix,
             'observability_ratio_limit': DETERMINED_RATIO,
             'accel_posterior_ratio': fit.determined, 'accel_cv': fit.cv, **gfit.stats}
    return WholeUnitFit(fit, gfit, notes, stats)


def fit_whole_unit_context(ctx, rows=None, transitions=None):
    """Run ``fit_whole_unit`` with the settings of a ``calibrate.Context``.

    ``rows``: bool mask of the windows to fit (default all; e.g. the training holds of a
    held-out comparison); ``transitions``: pose changes (None: static only). The options'
    ``whole_unit_priors`` are copied, never modified; a lab prior (seed 000 field model)
    sets the accelerometer prior means.
    """
    w, o, k = ctx.windows, ctx.options, ctx.k
    rows = np.ones(len(w), bool) if rows is None else np.asarray(rows, bool)
    user = o.whole_unit_priors
    priors = dataclasses.replace(user) if user is not None else Priors()
    if ctx.prior_model is not None:
        priors.accel_mean = prior_from_field_model(ctx.prior_model)
    t0g = ctx.t0 if k and list(ctx.gyro_input) == list(ctx.accel_input) else None
    acc_rows = getattr(ctx, 'accel_rows', None)
    return fit_whole_unit(w.select(rows), o.gravity, ctx.ta[rows] if k else None, ctx.t0,
                          ctx.tg[rows] if k else None, t0g, o.latitude,
                          transitions, priors, o.order if k else 0, ctx.accel_input,
                          ctx.gyro_input, o.whole_unit_residual, ctx.gyro_unit,
                          accel_rows=None if acc_rows is None else acc_rows[rows])


# ------------------------------------------------------------------------ estimator
def _register():
    """Register the ``whole_unit`` estimator (imported by calibrate.ESTIMATOR_MODULES)."""
    from .calibrate import CalibrationRefused, Estimate, register_estimator

    @register_estimator('whole_unit')
    def estimate_whole_unit(ctx):
        """Seed 002 whole-unit model: accel (norm fit) and gyro (static + rotations).

        Settings from CalibrateOptions: ``latitude`` (deg), ``transitions`` (pose changes
        from gyro_fit.MotionCollector), ``whole_unit_priors`` (Priors) and
        ``whole_unit_residual`` ('norm' or 'vector').
        """
        o = ctx.options
        if ctx.n_orientations < 4:
            raise CalibrationRefused(
                f'only {ctx.n_orientations} distinct orientations were held',
                'the whole-unit model needs at least the six faces (+x -x +y -y +z -z up), '
                'plus tilted poses for misalignment, each still for '
                f'{o.min_hold_s:.0f} s or more')
        res = fit_whole_unit_context(ctx, transitions=o.transitions)
        am = res.accel.model
        weak = [f'{a}' for i, a in enumerate('xyz')
                if not (am.estimated_mask('ct0')[i] and am.estimated_mask('A1')[i, i])]
        if weak:
            raise CalibrationRefused(
                f'bias or scale factor of axis {",".join(weak)} is not determined by the '
                f'holds collected ({ctx.coverage["holds"]} holds, faces missing: '
                f'{" ".join(ctx.coverage["missing"]) or "none"})',
                'hold every axis pointing up and pointing down, still, ideally several '
                'times during the warm-up')
        return Estimate(accel=am, gyro=res.gyro.model, notes=res.notes, fit=res.stats,
                        report={'whole_unit': {'accel': res.accel.determined,
                                               'gyro': res.gyro.stats}})

    return estimate_whole_unit


estimate_whole_unit = _register()
