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
    """Sufficient statistics of B weighted fits and of each placement (``_sums``).

    The B fits share the rows and the placements (the three axes of one fit), or each has
    its own, padded at the end with empty placements (``held_out_level_fits``).
    """

    ata: np.ndarray     # (B, p, p) sum w a a^T
    aty: np.ndarray     # (B, p) sum w a y
    yty: np.ndarray     # (B,) sum w y^2
    g: np.ndarray       # (B, H, p) sum w a per placement
    q: np.ndarray       # (B, H) sum w y per placement
    s: np.ndarray       # (B, H) sum w per placement
    gg: np.ndarray      # (B, H, p * p) g g^T per placement, flattened
    gq: np.ndarray      # (B, H, p) g q per placement


#: the ``_Stats`` fields with one entry per placement (the rest are per fit)
_PER_PLACEMENT = ('g', 'q', 's', 'gg', 'gq')


def _sums(a, y, w, groups):
    """Return the ``_Stats`` of the B weighted fits (once per fit, for every ``lam``)."""
    _, gi = np.unique(groups, return_inverse=True)
    gi = gi.ravel()
    h = int(gi.max()) + 1 if len(gi) else 0
    nb, _, p = a.shape
    wa = a * w[:, :, None]
    g = np.zeros((nb, h, p))
    q = np.zeros((nb, h))
    s = np.zeros((nb, h))
    for b in range(nb):
        for j in range(p):          # bincount: the sums of np.add.at, in the same order
            g[b, :, j] = np.bincount(gi, weights=wa[b, :, j], minlength=h)
        q[b] = np.bincount(gi, weights=w[b] * y[b], minlength=h)
        s[b] = np.bincount(gi, weights=w[b], minlength=h)
    return _Stats(ata=np.matmul(a.transpose(0, 2, 1), wa),
                  aty=np.matmul(wa.transpose(0, 2, 1), y[:, :, None])[:, :, 0],
                  yty=np.sum(w * y * y, axis=1), g=g, q=q, s=s,
                  gg=(g[:, :, :, None] * g[:, :, None, :]).reshape(nb, h, p * p),
                  gq=g * q[:, :, None])


def _evaluate(lam, stats, n):
    """Return (-2 REML log-likelihood up to a constant, coef, M, r^T V^-1 r, dof) per lam.

    ``lam``: (B, L), a batch of ratios per fit; ``n``: (B,) rows of each fit; every result
    has (B, L) in front.
    Matrix products (BLAS) over the batch; ``einsum`` with three or four operands loops in
    C without BLAS and took about 70 % of the random-level fits' time in a lifelong
    re-estimate (docs/speed.md).
    """
    ata, aty, yty, g, q, s = stats.ata, stats.aty, stats.yty, stats.g, stats.q, stats.s
    nb, nl = lam.shape
    p = g.shape[2]
    f = lam[:, :, None] / (1.0 + lam[:, :, None] * s[:, None, :])      # (B, L, H)
    m = ata[:, None] - np.matmul(f, stats.gg).reshape(nb, nl, p, p)
    b = aty[:, None] - np.matmul(f, stats.gq)                            # (B, L, p)
    ev, vec = np.linalg.eigh(m)
    tol = np.max(np.abs(ev), axis=2, keepdims=True) * 1e-12
    inv_ev = np.where(ev > tol, 1.0 / np.where(ev > tol, ev, 1.0), 0.0)
    vtb = np.matmul(b[:, :, None, :], vec)[:, :, 0]                      # (B, L, p): V^T b
    coef = np.matmul(vec, (inv_ev * vtb)[..., None])[..., 0]            # pseudo-inverse
    rank = np.sum(ev > tol, axis=2)
    wrr = (yty[:, None] - 2 * np.matmul(coef, aty[:, :, None])[..., 0]
           + np.sum(np.matmul(coef, ata) * coef, axis=2))
    gr = q[:, None] - np.matmul(coef, g.transpose(0, 2, 1))              # (B, L, H)
    quad = np.maximum(wrr - np.sum(f * gr ** 2, axis=2), 1e-300)
    logdet_m = np.sum(np.log(np.where(ev > tol, ev, 1.0)), axis=2)
    dof = np.maximum(np.asarray(n)[:, None] - rank, 1)
    crit = (dof * np.log(quad) + np.sum(np.log1p(lam[:, :, None] * s[:, None]), axis=2)
            + logdet_m)
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
    return random_level_fits(a[None], np.asarray(y, float)[None], np.asarray(w, float)[None],
                             groups)[0]


def random_level_fits(a, y, w, groups):
    """Return B ``random_level_fit`` results of fits that share their rows' placements.

    a: (B, n, p); y, w: (B, n); groups: (n,). Each fit is the one ``random_level_fit``
    gives on its own (its own ``lam`` search); done together, numpy's per-call cost is
    paid once for the B fits (the three axes of a thermal fit).
    """
    a = np.ascontiguousarray(a, float)
    y = np.ascontiguousarray(y, float)
    w = np.ascontiguousarray(w, float)
    nb, n, p = a.shape
    stats = _sums(a, y, w, groups)
    return _search(stats, np.full(nb, n), np.full(nb, stats.s.shape[1]))


def _search(stats, n, h, cov=True):
    """REML ``lam`` search of B fits; return their ``LevelFit``.

    n: (B,) rows of each fit; h: (B,) its placements, the first ``h`` of ``stats``'s
    (the rest, if any, are empty: all their sums 0, which adds nothing to any term).
    ``cov`` False: ``LevelFit.unscaled_cov`` is None (held-out fits need the coefficients
    only).
    """
    nb = len(n)
    p = stats.g.shape[2]
    fallback = (h < 2) | (n <= p + 1)
    out = [None] * nb
    for part in (np.flatnonzero(fallback), np.flatnonzero(~fallback)):
        if not len(part):
            continue
        sub = _Stats(*(x[part] for x in stats)) if len(part) < nb else stats
        for b, fit in zip(part, _search_part(sub, n[part], h[part], fallback[part[0]],
                                             cov)):
            out[b] = fit
    return out


def _search_part(stats, n, h, fallback, cov):
    """``_search`` of fits that all fall back to ``lam`` 0 or all search it."""
    nb = len(n)
    s = stats.s
    if fallback:
        lams = np.zeros((nb, 1))
    else:
        scale = 1.0 / np.maximum(np.array([np.mean(s[b, :h[b]]) for b in range(nb)]), 1e-300)
        lams = scale[:, None] * 10.0 ** np.linspace(-LOG_SPAN, LOG_SPAN, GRID)
        lowest = lams[:, 0].copy()
        edge = np.zeros(nb, bool)
        rows = np.arange(nb)
        for _ in range(REFINE):       # each grid spans the previous one's best cell pair
            k = np.argmin(_evaluate(lams, stats, n)[0], axis=1)
            edge |= (k == 0) & (lams[:, 0] <= lowest)
            lo = np.log10(lams[rows, np.maximum(k - 1, 0)])
            hi = np.log10(lams[rows, np.minimum(k + 1, lams.shape[1] - 1)])
            lams = 10.0 ** np.linspace(lo, hi, FINE, axis=1)
        # at the lower edge, "placements do not matter": 0 is a candidate too (a fit not
        # at the edge gets its lowest ratio again, which changes nothing)
        lams = np.concatenate([np.where(edge, 0.0, lams[:, 0])[:, None], lams], axis=1)
    crit, coef, m, quad, dof = _evaluate(lams, stats, n)
    k = np.argmin(crit, axis=1)
    return [LevelFit(coef[b, k[b]], np.linalg.pinv(m[b, k[b]]) if cov else None,
                     float(quad[b, k[b]] / dof[b, k[b]]), float(lams[b, k[b]]))
            for b in range(nb)]


@dataclass
class LevelFit:
    """What ``random_level_fit`` returns (see there)."""

    coef: np.ndarray          # (p,)
    unscaled_cov: np.ndarray  # (p, p): (A^T V^-1 A)^+, times sigma2 the covariance
    #                           (None in ``held_out_level_fits``: coefficients only)
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
    ordinary weighted least squares, as there. The training parts are fitted together
    (``_search``): each one's sums over its own rows and placements, padded with empty
    placements to the largest count.
    """
    a = np.asarray(a, float)
    y = np.asarray(y, float)
    w = np.asarray(w, float)
    ug, gi = np.unique(groups, return_inverse=True)
    gi = gi.ravel()
    if not len(ug):
        return np.empty((0, a.shape[1]))
    parts = []
    for g in range(len(ug)):
        tr = gi != g
        parts.append(_sums(a[tr][None], y[tr][None], w[tr][None], levels[tr]))
    h = np.array([x.s.shape[1] for x in parts])
    n = len(gi) - np.bincount(gi, minlength=len(ug))
    hmax = int(h.max())
    fields = {}
    for name in _Stats._fields:
        first = getattr(parts[0], name)
        per_placement = name in _PER_PLACEMENT         # (1, H, ...): padded to hmax
        x = np.zeros((len(parts),) + ((hmax,) + first.shape[2:] if per_placement
                                      else first.shape[1:]))
        for b, part in enumerate(parts):
            if per_placement:
                x[b, :h[b]] = getattr(part, name)[0]
            else:
                x[b] = getattr(part, name)[0]
        fields[name] = x
    stats = _Stats(**fields)
    return np.array([fit.coef for fit in _search(stats, n, h, cov=False)])
