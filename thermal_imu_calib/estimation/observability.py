"""Shared least-squares machinery: which parameters the data determine.

Every candidate parameter has a prior (mean, standard deviation; ``Priors``).
With the whitened Jacobian J at a prior-regularised first fit, scaled by the
prior standard deviations, the posterior covariance of the candidates is
``(J'J / s^2 + I)^-1`` (s: robust residual scale). A parameter is *determined*
when its posterior standard deviation is below ``ratio`` (default 0.5) of its
prior one: the data carry at least three times the prior's information. The
least determined candidate is fixed at its prior and the test repeated
(backward elimination), so correlated pairs are resolved one at a time
(``decide_determined``); ``Layout`` maps named parameters to the vector of
unknowns and ``fit_free`` solves with the others fixed. Used by the
whole-unit accelerometer fit and both gyro fits.
"""

from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
from scipy.optimize import least_squares

from ..collection.outliers import robust_least_squares


#: posterior/prior standard-deviation ratio below which a parameter counts as determined
DETERMINED_RATIO = 0.5
#: temperature span (degC) needed for each polynomial order of a temperature term (a term
#: whose effect over a smaller span is below what holds resolve is not estimated)
ORDER_SPAN = {1: 1.0, 2: 3.0}


CONVENTION = 'convention'


class FitNotConverged(ValueError):
    """A least-squares fit stopped before converging; ``advice`` says what to do."""

    def __init__(self, what, advice):
        super().__init__(f'{what}; {advice}')
        self.what, self.advice = what, advice


def converged(res):
    """Return True when a least-squares result met its tolerances at a finite point.

    ``scipy.optimize.least_squares`` (and ``outliers.robust_least_squares``) report
    ``success`` False when the evaluation budget (``max_nfev``) ran out first (status 0): the
    point returned is where the solver stopped, not a minimum, typically in the flat valley
    of parameters the rows do not determine. Callers must not use such a point as a fit.
    """
    return bool(getattr(res, 'success', False)) and bool(np.all(np.isfinite(res.x)))


#: entry of a term selection's scores counting its fold fits that did not converge
NOT_CONVERGED_KEY = 'fold fits stopped by their evaluation budget'


class StoppedFolds:
    """Count a cross-validation's fold fits that did not converge (``converged``)."""

    def __init__(self):
        self.stopped = self.fits = 0

    def add(self, res):
        """Count one fold fit's least-squares result."""
        self.stopped += not converged(res)
        self.fits += 1

    def record(self, scores):
        """Put 'N of M' under ``NOT_CONVERGED_KEY`` in ``scores`` when any stopped."""
        if self.stopped:
            scores[NOT_CONVERGED_KEY] = f'{self.stopped} of {self.fits}'


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
        return np.concatenate([r, z]) if with_prior else r

    def jac(z):
        j = resid(full(z), True)[1][:, idx] * sd[None, :]
        return np.concatenate([j, np.eye(len(idx))]) if with_prior else j

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
    return _ratio_of_information(js.T @ js, noise_scale, prior_weight)


def _ratio_of_information(info, noise_scale, prior_weight):
    """Return the posterior/prior std ratios from the prior-scaled normal matrix ``S J'J S``."""
    info = info / max(noise_scale, 1e-12) ** 2
    pw = np.ones(len(info)) if prior_weight is None else np.asarray(prior_weight, float)
    info = info + np.diag(np.maximum(pw, 1e-9))
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(info)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def decide_determined(layout, jac, noise_scale, ratio=DETERMINED_RATIO, reason='',
                      chains=(), nuisance=None, normal=None):
    """Backward elimination of undetermined candidates (see the module docstring).

    jac: (m, layout.size) whitened Jacobian, or None with ``normal``: its normal matrix
    J'J (layout.size, layout.size), e.g. built from a block structure (the static gyro
    fit), which spares forming a tall dense J. ``chains``: list of lists of flat indices in
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
        if normal is None:
            r = posterior_ratio(jac[:, idx], layout.std[idx], noise_scale, pw)
        else:
            sd = layout.std[idx]
            r = _ratio_of_information(normal[np.ix_(idx, idx)] * np.outer(sd, sd),
                                      noise_scale, pw)
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
