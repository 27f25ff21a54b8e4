"""Least squares with a random level per placement (a robot's stops), by REML.

On a robot every stop is a new placement: the floor tilts the accelerometer by a new
angle (g sin(tilt) on the axes across gravity, tens of mm/s^2) and the heading turns the
horizontal earth rate into the gyro (up to 7.3e-5 rad/s). Inside a stop the level is
fixed; between stops it scatters. An ordinary least-squares fit of a thermal offset
treats every window as independent, so a few stops whose levels happen to line up with
their temperatures read as a steep thermal slope with a small standard error (the windows
of one stop are not independent: they share its level).

This is the textbook random-intercept model (a linear mixed model, as ``lme4`` or
statsmodels' ``MixedLM`` fit it)::

    y = A c + Z u + e,    u ~ N(0, tau^2 I) (one level per placement),
                          e ~ N(0, sigma^2 W^-1) (W: the fit's window weights)

The coefficients ``c`` are its generalised least-squares estimate for the ratio
``lam = tau^2 / sigma^2`` that maximises the restricted likelihood (REML, sigma^2
profiled out). ``lam`` is estimated from the data, per axis: no threshold. With no scatter
between placements beyond the windows' it goes to 0 and the fit is the ordinary one; with
a large scatter the thermal terms come mostly from the variation inside placements, and
the levels between placements count as much as their scatter allows.

Everything is computed from per-placement sums (p the number of coefficients, H the
number of placements): O(n p^2) once, then O(H p^2) per ``lam``; a batch of ``lam``
values is evaluated at once (a log grid, then finer ones around its best point).
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

#: the ratio is searched over 10^-LOG_SPAN .. 10^LOG_SPAN times 1 / (mean weight sum per
#: placement), i.e. from "placements do not matter" to "only inside placements"
LOG_SPAN = 8.0
#: points of the coarse grid in log10(lam), and of each finer grid around the best point
#: of the one before (REFINE of them: the last resolves log10(lam) to about 2e-4)
GRID = 49
FINE = 25
REFINE = 3


class _Stats(NamedTuple):
    """Sufficient statistics of the weighted fit and of each placement (``_sums``)."""

    ata: np.ndarray     # (p, p) sum w a a^T
    aty: np.ndarray     # (p,) sum w a y
    yty: float          # sum w y^2
    g: np.ndarray       # (H, p) sum w a per placement
    q: np.ndarray       # (H,) sum w y per placement
    s: np.ndarray       # (H,) sum w per placement
    gg: np.ndarray      # (H, p * p) g g^T per placement, flattened
    gq: np.ndarray      # (H, p) g q per placement


def _sums(a, y, w, groups):
    """Return the ``_Stats`` of the weighted fit (once per fit, for every ``lam``)."""
    _, gi = np.unique(groups, return_inverse=True)
    gi = gi.ravel()
    h = int(gi.max()) + 1 if len(gi) else 0
    p = a.shape[1]
    wa = a * w[:, None]
    g = np.zeros((h, p))
    for j in range(p):              # bincount: the sums of np.add.at, in the same order
        g[:, j] = np.bincount(gi, weights=wa[:, j], minlength=h)
    q = np.bincount(gi, weights=w * y, minlength=h)
    return _Stats(ata=a.T @ wa, aty=wa.T @ y, yty=float(np.sum(w * y * y)), g=g, q=q,
                  s=np.bincount(gi, weights=w, minlength=h),
                  gg=(g[:, :, None] * g[:, None, :]).reshape(h, p * p), gq=g * q[:, None])


def _evaluate(lam, stats, n):
    """Return (-2 REML log-likelihood up to a constant, coef, M, r^T V^-1 r, dof) per lam.

    Matrix products (BLAS) over the batch of ``lam``; ``einsum`` with three or four operands
    loops in C without BLAS and took about 70 % of the random-level fits' time in a lifelong
    re-estimate (docs/speed.md).
    """
    ata, aty, yty, g, q, s = stats.ata, stats.aty, stats.yty, stats.g, stats.q, stats.s
    p = g.shape[1]
    f = lam[:, None] / (1.0 + lam[:, None] * s[None, :])    # (L, H)
    m = ata[None] - (f @ stats.gg).reshape(-1, p, p)
    b = aty[None] - f @ stats.gq                             # (L, p)
    ev, vec = np.linalg.eigh(m)
    tol = np.max(np.abs(ev), axis=1, keepdims=True) * 1e-12
    inv_ev = np.where(ev > tol, 1.0 / np.where(ev > tol, ev, 1.0), 0.0)
    vtb = np.matmul(b[:, None, :], vec)[:, 0]                # (L, p): V^T b
    coef = np.matmul(vec, (inv_ev * vtb)[:, :, None])[:, :, 0]      # pseudo-inverse
    rank = np.sum(ev > tol, axis=1)
    wrr = yty - 2 * (coef @ aty) + np.sum((coef @ ata) * coef, axis=1)
    gr = q[None] - coef @ g.T                                # (L, H) sum w r per placement
    quad = np.maximum(wrr - np.sum(f * gr ** 2, axis=1), 1e-300)
    logdet_m = np.sum(np.log(np.where(ev > tol, ev, 1.0)), axis=1)
    dof = np.maximum(n - rank, 1)
    crit = dof * np.log(quad) + np.sum(np.log1p(lam[:, None] * s[None]), axis=1) + logdet_m
    return crit, coef, m, quad, dof


def random_level_fit(a, y, w, groups):
    """Fit ``y ~ a @ c`` (weights ``w``) with a random level per group; REML.

    a: (n, p) design; y: (n,); w: (n,) window weights (inverse variances up to a common
    factor: the fit's ``hysteresis.fit_weights``, or 1 / var of each window mean);
    groups: (n,) placement ids (hold ids).

    Returns a ``LevelFit``: the coefficients, ``(A^T V^-1 A)^+`` with
    V = W^-1 + lam Z Z^T (times ``sigma2`` it is their covariance), ``sigma2`` (the REML
    residual variance in the weights' unit) and ``lam`` (tau^2 / sigma^2). With fewer than
    two placements, or no more windows than coefficients + 1, ``lam`` is 0: ordinary
    weighted least squares.
    """
    a = np.asarray(a, float)
    y = np.asarray(y, float)
    w = np.asarray(w, float)
    n, p = a.shape
    stats = _sums(a, y, w, groups)
    s = stats.s
    if len(s) < 2 or n <= p + 1:
        lams = np.zeros(1)
    else:
        scale = 1.0 / max(float(np.mean(s)), 1e-300)
        lams = scale * 10.0 ** np.linspace(-LOG_SPAN, LOG_SPAN, GRID)
        edge = False
        for _ in range(REFINE):       # each grid spans the previous one's best cell pair
            k = int(np.argmin(_evaluate(lams, stats, n)[0]))
            edge = edge or (k == 0 and lams[0] <= scale * 10.0 ** -LOG_SPAN)
            lo, hi = np.log10(lams[max(k - 1, 0)]), np.log10(lams[min(k + 1, len(lams) - 1)])
            lams = 10.0 ** np.linspace(lo, hi, FINE)
        if edge:                      # at the lower edge: "placements do not matter"
            lams = np.concatenate([[0.0], lams])
    crit, coef, m, quad, dof = _evaluate(lams, stats, n)
    k = int(np.argmin(crit))
    return LevelFit(coef[k], np.linalg.pinv(m[k]), float(quad[k] / dof[k]), float(lams[k]))


@dataclass
class LevelFit:
    """What ``random_level_fit`` returns (see there)."""

    coef: np.ndarray          # (p,)
    unscaled_cov: np.ndarray  # (p, p): (A^T V^-1 A)^+, times sigma2 the covariance
    sigma2: float             # residual variance, in 1 / weight units
    lam: float                # tau^2 / sigma^2: the placements' level variance ratio

    def std(self, sigma2=None):
        """Return (p,) standard errors, with ``sigma2`` (default: the fit's)."""
        s2 = self.sigma2 if sigma2 is None else sigma2
        return np.sqrt(np.maximum(np.diag(self.unscaled_cov), 0.0) * s2)


def held_out_level_fits(a, y, w, groups, levels):
    """Return (n_groups, p) coefficients, each fitted without one CV group.

    ``groups``: (n,) held-out groups; ``levels``: (n,) placement ids of the random levels.
    A training part the fit cannot take (``random_level_fit``'s fallback) is fitted by
    ordinary weighted least squares, as there.
    """
    ug, gi = np.unique(groups, return_inverse=True)
    gi = gi.ravel()
    out = np.empty((len(ug), a.shape[1]))
    for g in range(len(ug)):
        tr = gi != g
        out[g] = random_level_fit(a[tr], y[tr], w[tr], levels[tr]).coef
    return out
