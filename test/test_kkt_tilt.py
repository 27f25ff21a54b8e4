"""Property tests of the unit-norm tilt solver (seed 000 eqs. 20-27).

The truth is independent of the solver: the global minimiser of c'Mc - 2v'c on |c| = 1
has the Lagrange multiplier mu = the smallest real eigenvalue of the 6x6 matrix
[[M, -I], [-vv', M]] (Gander, Golub and von Matt, 1989), and c = (M - mu I)^+ v. SLSQP from
several starts is a second, slower reference.
"""

import numpy as np
from scipy.optimize import minimize

from thermal_imu_calib.estimation.field_estimator import (
    _secular, kkt_unit_tilt, kkt_unit_tilt_batch)


def _cost(m_mat, v, c):
    return np.einsum('...i,...ij,...j->...', c, m_mat, c) - 2 * np.einsum('...i,...i', v, c)


def _ggvm(m_mat, v):
    """Global minimiser from the 6x6 eigenproblem (independent of the solver under test)."""
    b = np.block([[m_mat, -np.eye(3)], [-np.outer(v, v), m_mat]])
    ev = np.linalg.eigvals(b)
    real = np.abs(ev.imag) <= 1e-9 * np.abs(ev).max()
    mu = np.min(ev[real].real)
    c = np.linalg.lstsq(m_mat - mu * np.eye(3), v, rcond=1e-12)[0]
    r2 = c @ c
    if r2 < 1.0:    # the hard case: M - mu I is singular, complete |c| = 1 in its null space
        c = c + np.sqrt(1.0 - r2) * np.linalg.eigh(m_mat)[1][:, 0]
    return c / np.linalg.norm(c)


def _cases(rng, n):
    """Random and ill-conditioned problems built like the estimator builds them."""
    a = rng.normal(size=(n, 8, 3, 3))
    ill = rng.random(n) < 0.4                      # columns scaled over 6 decades
    a[ill] *= 10.0 ** rng.uniform(-3, 3, size=(ill.sum(), 1, 1, 3))
    rank1 = rng.random(n) < 0.05                   # nearly rank-deficient data
    a[rank1] = a[rank1][..., :1] * rng.normal(size=(rank1.sum(), 8, 1, 3)) + \
        1e-9 * a[rank1]
    y = rng.normal(size=(n, 8, 3)) * 10.0 ** rng.uniform(-2, 2, size=(n, 1, 1))
    w = rng.uniform(0.5, 2.0, (n, 8, 3))
    aw = a * w[..., None]
    m_mat = np.einsum('nmki,nmkj->nij', aw, aw)
    v = np.einsum('nmki,nmk->ni', aw, y * w)
    return m_mat, v


def _tol(m_mat, v):
    return 1e-9 * (np.abs(np.linalg.eigvalsh(m_mat)).max(-1) + np.linalg.norm(v, axis=-1))


def test_batch_is_global_minimum_on_thousands_of_cases():
    rng = np.random.default_rng(2026)
    m_mat, v = _cases(rng, 5000)
    c0 = rng.normal(size=(5000, 3))
    c, u, _ = kkt_unit_tilt_batch(m_mat, v, c0)
    assert np.all(np.abs(np.linalg.norm(c, axis=1) - 1) < 1e-12)
    truth = np.array([_ggvm(m, b) for m, b in zip(m_mat, v)])
    gap = _cost(m_mat, v, c) - _cost(m_mat, v, truth)
    assert np.all(gap <= _tol(m_mat, v)), np.sort(gap / _tol(m_mat, v))[-5:]
    # and the secular solution alone is the same global minimum
    sec = np.array([_secular(m, b)[0] for m, b in zip(m_mat[:1000], v[:1000])])
    gap = _cost(m_mat[:1000], v[:1000], sec) - _cost(m_mat[:1000], v[:1000], truth[:1000])
    assert np.all(np.abs(gap) <= _tol(m_mat[:1000], v[:1000]))


def test_newton_not_converged_is_never_accepted():
    """With too few Newton steps, every hold must still come back at the global minimum."""
    rng = np.random.default_rng(7)
    m_mat, v = _cases(rng, 500)
    c0 = rng.normal(size=(500, 3)) * 100            # starts far from the data
    for max_iter in (1, 2, 3):
        c, _, it = kkt_unit_tilt_batch(m_mat, v, c0, max_iter=max_iter)
        assert it == max_iter
        truth = np.array([_ggvm(m, b) for m, b in zip(m_mat, v)])
        gap = _cost(m_mat, v, c) - _cost(m_mat, v, truth)
        assert np.all(gap <= _tol(m_mat, v))


def test_hard_case():
    """v has no component on the smallest eigenvector: u = -lambda_min, c leaves the span."""
    m_mat = np.diag([1.0, 2.0, 3.0])
    for v in (np.array([0.0, 0.3, 0.2]), np.array([0.0, 0.0, 0.0]), np.array([1e-14, .1, 0])):
        c, u = _secular(m_mat, v)
        assert abs(np.linalg.norm(c) - 1) < 1e-12
        assert abs(_cost(m_mat, v, c) - _cost(m_mat, v, _ggvm(m_mat, v))) < 1e-9
        cb, _, _ = kkt_unit_tilt_batch(m_mat[None], v[None], np.array([[0.0, 1.0, 1.0]]))
        assert _cost(m_mat, v, cb[0]) <= _cost(m_mat, v, c) + 1e-9


def test_matches_scipy_slsqp_from_several_starts():
    rng = np.random.default_rng(11)
    starts = np.r_[np.eye(3), -np.eye(3), rng.normal(size=(4, 3))]
    for _ in range(60):   # 10 SLSQP starts each (thousands more against the closed form above)
        a_mats = rng.normal(size=(8, 3, 3)) * 10.0 ** rng.uniform(-2, 2, size=(1, 1, 3))
        y = rng.normal(size=(8, 3))
        w = rng.uniform(0.5, 2.0, (8, 3))
        c, _, _ = kkt_unit_tilt(a_mats, y, w, rng.normal(size=3))

        def f(c):
            return np.sum((w * (np.einsum('mij,j->mi', a_mats, c) - y)) ** 2)
        best = min((minimize(f, x0, method='SLSQP', options={'ftol': 1e-15, 'maxiter': 500},
                             constraints={'type': 'eq', 'fun': lambda c: c @ c - 1})
                    for x0 in starts), key=lambda r: r.fun)
        assert abs(np.linalg.norm(c) - 1) < 1e-12
        assert f(c) <= best.fun * (1 + 1e-9) + 1e-12
