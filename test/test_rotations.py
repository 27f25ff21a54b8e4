"""Quaternion helpers and the rotation fit's Jacobian against scipy and finite differences.

The rotation fit (``gyro_rotations``) calls these thousands of times per calibration, so
they are written as a few array operations (``rotations``); here every one is checked
against ``scipy.spatial.transform.Rotation`` and the analytic Jacobians against central
differences. A robust fit must move in every stage, however close to zero its start is.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from thermal_imu_calib.collection.outliers import robust_least_squares
from thermal_imu_calib.estimation.gyro_rotations import fit_gyro_rotations, rotation_residuals
from thermal_imu_calib.estimation.gyro_transitions import PreparedTransitions
from thermal_imu_calib.rotations import (quat_from_rotvec, quat_mul, quat_rotate_inverse,
                                         quat_to_matrix, quat_to_rotvec, right_jacobian,
                                         right_jacobian_inverse)
from _stopped_fits import final_fit_stops


def _scipy(q):
    """Return a scipy Rotation of scalar-first quaternions."""
    return Rotation.from_quat(np.roll(q, -1, axis=-1))


def test_quaternion_helpers_match_scipy():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 5, 3))
    b = rng.normal(size=(6, 5, 3))
    qa, qb = quat_from_rotvec(a), quat_from_rotvec(b)
    ra = Rotation.from_rotvec(a.reshape(-1, 3))
    rb = Rotation.from_rotvec(b.reshape(-1, 3))
    assert np.allclose(quat_to_matrix(qa).reshape(-1, 3, 3), ra.as_matrix(), atol=1e-14)
    prod = quat_mul(qa, qb).reshape(-1, 4)
    assert np.allclose(_scipy(prod).as_matrix(), (ra * rb).as_matrix(), atol=1e-14)
    v = rng.normal(size=(6, 5, 3))
    assert np.allclose(quat_rotate_inverse(qa, v).reshape(-1, 3),
                       ra.inv().apply(v.reshape(-1, 3)), atol=1e-13)
    small = a / np.linalg.norm(a, axis=-1, keepdims=True) * 3.0     # angles below pi
    assert np.allclose(quat_to_rotvec(quat_from_rotvec(small)), small, atol=1e-12)
    # broadcasting: one quaternion times a batch
    assert np.allclose(quat_mul(qa[0, 0], qb), quat_mul(np.broadcast_to(qa[0, 0], qb.shape), qb))


def test_right_jacobian_and_its_inverse_are_first_order_exact():
    rng = np.random.default_rng(1)
    for angle in (1e-7, 1e-3, 0.2, 1.0, 2.5):
        v = rng.normal(size=3)
        v *= angle / np.linalg.norm(v)
        d = rng.normal(size=3) * 1e-6
        # exp(v + d) = exp(v) exp(J_r d) + O(d^2)
        lhs = Rotation.from_rotvec(v + d)
        rhs = Rotation.from_rotvec(v) * Rotation.from_rotvec(right_jacobian(v) @ d)
        assert (lhs.inv() * rhs).magnitude() < 1e-11
        # rotvec(exp(v) exp(d)) = v + J_r^-1 d + O(d^2)
        moved = (Rotation.from_rotvec(v) * Rotation.from_rotvec(d)).as_rotvec()
        assert np.allclose(moved, v + right_jacobian_inverse(v) @ d, atol=1e-11)
        assert np.allclose(right_jacobian(v) @ right_jacobian_inverse(v), np.eye(3),
                           atol=1e-12)


def _transitions(rng, k=8, n=12, closed=()):
    """Return PreparedTransitions of random rotations with large increments (0.1-0.5 rad)."""
    b = rng.normal(size=(k, n, 3)) * 0.2
    u_from = rng.normal(size=(k, 3))
    u_from /= np.linalg.norm(u_from, axis=1, keepdims=True)
    flags = np.zeros(k, bool)
    flags[list(closed)] = True
    return PreparedTransitions(b, b ** 2 * 0.1, b ** 3 * 0.01, u_from, u_from.copy(),
                               np.full(k, 1e-3), flags, list(range(k)),
                               rng.normal(size=(k, n, 3)) * 1e-4)


def test_rotation_residual_jacobian_matches_central_differences():
    rng = np.random.default_rng(2)
    prep = _transitions(rng, closed=(2, 5))
    om1 = np.eye(3) + rng.normal(size=(3, 3)) * 0.01
    om2, om3 = np.full(3, 1e-3), np.full(3, -2e-4)
    r, jac = rotation_residuals(prep, om1, om2, om3, want_jac=True)
    p = np.r_[om1.ravel(), om2, om3]

    def f(p):
        return rotation_residuals(prep, p[:9].reshape(3, 3), p[9:12], p[12:]).ravel()

    num = np.zeros((r.size, 15))
    for i in range(15):
        e = np.zeros(15)
        e[i] = 1e-7
        num[:, i] = (f(p + e) - f(p - e)) / 2e-7
    assert np.allclose(f(p), r.ravel())
    # open transitions and full turns (closure rotation vector) alike
    assert np.max(np.abs(jac.reshape(-1, 15) - num)) < 1e-6 * np.max(np.abs(num))


def test_rotation_fit_recovers_the_scale_from_large_increments():
    """Gauss-Newton with the exact Jacobian: a 3 % scale and 1 % misalignment, exactly."""
    rng = np.random.default_rng(3)
    prep = _transitions(rng, k=12, n=10)
    true = np.eye(3) + np.diag([0.03, -0.02, 0.01]) + np.array(
        [[0, 0.01, -0.005], [0.004, 0, 0.008], [-0.006, 0.002, 0]])
    # measured gravity after each pose change: u_from carried through the true rotation
    prep.u_to = prep.u_to - rotation_residuals(prep, true, np.zeros(3), np.zeros(3))
    fit = fit_gyro_rotations(prep, robust=True, select=False)
    assert np.max(np.abs(fit.omega1 - true)) < 1e-9
    assert np.max(fit.error_after_deg) < 1e-5          # arccos resolution near 0 deg


def test_a_rotation_fit_that_does_not_converge_leaves_the_terms_at_their_prior(monkeypatch):
    """The final fit's point is used only when the solver converged; else the prior, said."""
    import thermal_imu_calib.estimation.gyro_rotations as gr
    rng = np.random.default_rng(3)
    prep = _transitions(rng, k=12, n=10)
    true = np.eye(3) + np.diag([0.03, -0.02, 0.01])
    prep.u_to = prep.u_to - rotation_residuals(prep, true, np.zeros(3), np.zeros(3))
    final_fit_stops(gr, monkeypatch)
    fit = fit_gyro_rotations(prep, robust=True, select=False)
    assert np.array_equal(fit.omega1, np.eye(3))                   # the prior
    assert not np.any(fit.estimated['Omega1'])
    assert any('did not converge' in n and 'fixed at the prior' in n for n in fit.notes)
    assert gr.NOT_CONVERGED_REASON in fit.fixed['Omega1']


def test_term_selection_fold_fits_stopped_by_their_budget_are_counted_and_said(monkeypatch):
    """The leave-pose-changes-out fold fits that run out of evaluations are said in a note
    (the Omega2/Omega3 choice is uncertain), as the accelerometer's are; converged: none."""
    import thermal_imu_calib.estimation.gyro_rotations as gr
    rng = np.random.default_rng(3)
    prep = _transitions(rng, k=12, n=10)
    true = np.eye(3) + np.diag([0.03, -0.02, 0.01])
    prep.u_to = prep.u_to - rotation_residuals(prep, true, np.zeros(3), np.zeros(3))
    ratio = 0.9999     # Omega2 counts as determined here, so the selection runs
    fit = fit_gyro_rotations(prep, robust=True, ratio=ratio)
    assert np.all(fit.estimated['Omega2'])
    assert not [n for n in fit.notes if 'fold fits stopped' in n], fit.notes
    real = gr.fit_free
    budgets = []

    def folds_stop(resid, std, base, free, with_prior=False, robust=False, **kw):
        p, res = real(resid, std, base, free, with_prior, robust, **kw)
        if not with_prior and not robust:            # the selection's fold fits
            budgets.append(kw['max_nfev'])
            res.success = False
        return p, res
    monkeypatch.setattr(gr, 'fit_free', folds_stop)
    fit = fit_gyro_rotations(prep, robust=True, ratio=ratio)
    assert budgets and set(budgets) == {gr.FOLD_MAX_NFEV}
    said = [n for n in fit.notes if f'{len(budgets)} of {len(budgets)} fold fits stopped at '
            f'{gr.FOLD_MAX_NFEV} evaluations' in n]
    assert said and said[0].endswith('that choice is uncertain'), fit.notes


def test_every_robust_stage_moves_even_from_a_start_next_to_zero():
    """scipy sizes the first trust region by |x0|: a start of 1e-14 must not freeze a stage.

    Parametrised so that the plain least-squares solution is x = 1e-14: the robust answer
    must be the one reached from a far start, not the least-squares one.
    """
    rng = np.random.default_rng(4)
    x = np.linspace(0.0, 1.0, 80)
    y = 0.5 + 2.0 * x + rng.normal(0, 0.01, 80)
    y[30:34] += 1.0                                 # a bumped stretch the robust loss drops
    design = np.column_stack([np.ones_like(x), x])
    lin = np.linalg.lstsq(design, y, rcond=None)[0]

    def fun(z):
        return (y - design @ (z + lin - 1e-14)) / 0.01

    near = robust_least_squares(fun, np.full(2, 1e-14))
    far = robust_least_squares(fun, np.array([-3.0, 5.0]))
    assert np.allclose(near.x, far.x, atol=1e-8)
    assert np.max(np.abs(near.x + lin - 1e-14 - [0.5, 2.0])) < 0.02   # the clean line
    assert near.outliers[30:34].all()
