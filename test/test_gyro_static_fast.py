"""The fast static gyro alternation agrees with the dense design it replaced (issue 13).

``gyro_static`` solves the static fit from per-axis blocks of the design, per-hold sums
and the block structure of the Jacobian. The reference below is the dense (3m x n_lin)
alternation as it was before (``reference_alternate``) and the dense Jacobian product;
every case must agree to rounding: the same free/fixed decisions, notes and outlier
holds, numbers to 1e-9 relative (or 1e-12 absolute, rad/s).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from thermal_imu_calib.collection.outliers import robust_scale
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation import gyro_static as gs
from thermal_imu_calib.estimation.gyro_static import EARTH_RATE, fit_gyro_static

RTOL, ATOL = 1e-9, 1e-12


def synth(seed, n_holds=12, per=40, bad_hold=None, latitude=45.0, omega1=None):
    """Return (windows, axis inputs) of still holds; ``bad_hold`` gets a 40-sigma offset."""
    rng = np.random.default_rng(seed)
    m = n_holds * per
    hold = np.repeat(np.arange(n_holds) * 3 + 1, per)            # ids not 0..h-1
    rots = Rotation.from_rotvec(rng.normal(0, 1.5, (n_holds, 3)))
    up = rots.inv().apply([0, 0, 1.0])
    lat = np.radians(latitude)
    w_e = rots.inv().apply(EARTH_RATE * np.array([0, np.cos(lat), np.sin(lat)]))
    om1_inv = np.linalg.inv(np.eye(3) if omega1 is None else omega1)
    inv = np.repeat(np.arange(n_holds), per)
    temp = 22 + 15 * (1 - np.exp(-np.linspace(0, 3.5, m)))[:, None] + rng.normal(0, 0.3, (m, 3))
    dx = temp - 30.0
    acc = 9.81 * up[inv] + rng.normal(0, 0.01, (m, 3))
    sigma = rng.uniform(1e-6, 4e-6, (m, 3))
    gyro = (rng.normal(0, 3e-3, 3) + rng.normal(0, 1e-4, 3) * dx + rng.normal(0, 2e-6, 3) * dx ** 2
            + acc @ rng.uniform(-7e-5, 7e-5, (3, 3)).T + w_e[inv] @ om1_inv.T
            + rng.normal(0, 1.0, (m, 3)) * sigma)
    if bad_hold is not None:
        gyro[inv == bad_hold] += 40 * sigma[inv == bad_hold]
    n = np.full(m, 400)
    w = Windows(hold=hold, t0=np.arange(m) * 5.0, t1=np.arange(m) * 5.0 + 5, n=n, accel=acc,
                gyro=gyro, accel_var=np.full((m, 3), 1e-4), gyro_var=sigma ** 2 * n[:, None],
                temp=temp, temp_rate=np.zeros((m, 3)))
    return w, temp


def reference_alternate(pb, free_lin, theta0, with_prior, weights_kind):
    """The dense alternation of gyro_static before issue 13 (one (3m, k) design a step)."""
    x, y, sig, inv, up, e1, e2 = pb.x, pb.y, pb.sig, pb.inv, pb.up, pb.e1, pb.e2
    om1, om1_inv, s_lat = pb.om1, pb.om1_inv, pb.s_lat
    m, nh = len(y), len(up)

    def earth(psi, mh):
        hdir = np.cos(psi)[inv, None] * e1[inv] + np.sin(psi)[inv, None] * e2[inv]
        return EARTH_RATE * (s_lat * up[inv] + mh * hdir) @ om1_inv.T

    idx = np.flatnonzero(free_lin)
    x_free, x_fixed = x[:, :, idx], x[:, :, ~free_lin]
    theta = theta0.copy()
    psi = np.zeros(nh)
    mh = pb.c_lat if pb.lat_known else 0.5
    wts = np.ones((m, 3))
    stages = ['linear'] if weights_kind == 'linear' else ['linear', 'soft_l1', 'cauchy']
    c = np.inf
    for stage in stages:
        if stage != 'linear':
            r_all = ((y - np.einsum('nik,k->ni', x, theta) - earth(psi, mh)) / sig).ravel()
            c = pb.k_robust * max(robust_scale(r_all), 1.0)
        for _ in range(60):
            yy = y - earth(psi, mh) - np.einsum('nik,k->ni', x_fixed, theta[~free_lin])
            r = (yy - np.einsum('nik,k->ni', x_free, theta[idx])) / sig
            if stage == 'soft_l1':
                wts = 1.0 / np.sqrt(1.0 + (r / c) ** 2)
            elif stage == 'cauchy':
                wts = 1.0 / (1.0 + (r / c) ** 2)
            sw = np.sqrt(wts) / sig
            a = (x_free * sw[:, :, None]).reshape(3 * m, len(idx))
            b = (yy * sw).ravel()
            if with_prior:
                sd = pb.std[idx]
                a = np.vstack([a, np.diag(1.0 / sd)])
                b = np.r_[b, pb.mean[idx] / sd]
            new = gs._normal_solve(a, b)
            step = np.max(np.abs(new - theta[idx]) / pb.std[idx]) if len(idx) else 0.0
            theta[idx] = new
            rr = (y - np.einsum('nik,k->ni', x, theta)) @ om1.T - EARTH_RATE * s_lat * up[inv]
            ww = np.mean(wts / sig ** 2, axis=1)
            dh = np.zeros((nh, 3))
            np.add.at(dh, inv, rr * ww[:, None])
            psi_new = np.arctan2(np.sum(dh * e2, 1), np.sum(dh * e1, 1))
            if not pb.lat_known:
                hd = np.cos(psi_new)[:, None] * e1 + np.sin(psi_new)[:, None] * e2
                wsum = np.zeros(nh)
                np.add.at(wsum, inv, ww)
                mh = float(np.clip(np.sum(dh * hd) / (EARTH_RATE * wsum.sum()), 0.0, 1.0))
            dpsi = float(np.max(np.abs(np.angle(np.exp(1j * (psi_new - psi))))))
            psi = psi_new
            if step < 1e-6 and dpsi < 1e-4:
                break
    r = (y - np.einsum('nik,k->ni', x, theta) - earth(psi, mh)) / sig
    return theta, psi, mh, r, wts, c


def dense_jacobian(pb, psi, mh, size):
    """Whitened Jacobian (3m, size) of r = (y - pred) / sigma (linear, psi[, mh]), dense."""
    m, _, n_lin = pb.x.shape
    nsig = -pb.sig
    jac = np.zeros((m, 3, size))
    jac[:, :, :n_lin] = pb.x / nsig[:, :, None]
    dpsi, dmh = pb.nuisance_rates(psi, mh)
    jac[np.arange(m), :, n_lin + pb.inv] = dpsi / nsig
    if dmh is not None:
        jac[:, :, size - 1] = dmh / nsig
    return jac.reshape(3 * m, size)


def reference_gram(pb, psi, mh, wts, size):
    """Return J^T diag(wts) J from the dense Jacobian."""
    jf = dense_jacobian(pb, psi, mh, size) * np.sqrt(wts).ravel()[:, None]
    return jf.T @ jf


def assert_same(a, b, name):
    """Numbers equal to rounding: 1e-9 relative or 1e-12 absolute."""
    np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=RTOL,
                               atol=ATOL, err_msg=name)


def problem(monkeypatch, w, x, **kw):
    """Return the _StaticProblem fit_gyro_static builds and the free mask it decided."""
    seen = []
    real = gs._alternate

    def spy(pb, *args):
        seen.append((pb, args))
        return real(pb, *args)
    monkeypatch.setattr(gs, '_alternate', spy)
    fit_gyro_static(w, x, w.accel, np.full(3, 30.0), **kw)
    monkeypatch.setattr(gs, '_alternate', real)
    return seen[0][0], seen[1][1][0]


OMEGA1 = np.eye(3) + np.array([[0.01, -0.004, 0.002], [0.003, -0.02, 0.001],
                               [-0.002, 0.005, 0.015]])


@pytest.mark.parametrize('latitude', [45.0, None])
@pytest.mark.parametrize('omega1', [None, OMEGA1])
def test_alternation_matches_dense_reference(monkeypatch, latitude, omega1):
    w, x = synth(1, bad_hold=4, omega1=omega1)
    pb, free = problem(monkeypatch, w, x, latitude=latitude, omega1=omega1, order=2)
    n_lin = len(free)
    rng = np.random.default_rng(2)
    some_fixed = free.copy()
    some_fixed[[0, 7, n_lin - 2]] = False           # beta[x], cw1[y], G[2,1] at given values
    theta0 = rng.normal(0, 1e-5, n_lin)
    cases = [(free, True, 'linear'), (free, False, 'robust'), (some_fixed, True, 'robust'),
             (some_fixed, False, 'linear'), (np.zeros(n_lin, bool), False, 'robust')]
    for mask, with_prior, kind in cases:
        fast = gs._alternate(pb, mask, theta0, with_prior, kind)
        ref = reference_alternate(pb, mask, theta0, with_prior, kind)
        for name, a, b in zip(('theta', 'psi', 'mh', 'r', 'wts', 'c'), fast, ref):
            if name == 'r':                       # whitened: compare in rad/s
                a, b = a * pb.sig, b * pb.sig
            if name == 'psi':
                a = np.angle(np.exp(1j * (a - b)))
                b = np.zeros_like(a)
            np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-9 if name == 'psi' else ATOL,
                                       err_msg=f'{name} ({mask.sum()} free, {kind})')
        assert np.all(theta0[~mask] == fast[0][~mask])
    # the robust stages did down-weight the offset hold
    wts = gs._alternate(pb, free, theta0, False, 'robust')[4]
    assert np.median(wts[w.hold == 13]) < 0.2 < np.median(wts[w.hold != 13])


def test_singular_step_falls_back_to_least_squares(monkeypatch):
    w, x = synth(3)
    x = np.full_like(x, 30.0)                  # inputs at the reference: cw columns are zero
    pb, free = problem(monkeypatch, w, x, latitude=45.0, order=2)
    assert not np.any(free[6:12])              # decided undetermined by fit_gyro_static
    mask = free.copy()
    mask[6:12] = True                          # forced free: exactly singular normal matrix
    theta0 = np.zeros(len(free))
    for kind in ('linear', 'robust'):
        fast = gs._alternate(pb, mask, theta0, False, kind)
        ref = reference_alternate(pb, mask, theta0, False, kind)
        # the minimum-norm solution leaves the zero columns at rounding noise (~1e-12)
        assert np.max(np.abs(fast[0][6:12])) < 1e-10 and np.max(np.abs(ref[0][6:12])) < 1e-10
        assert_same(fast[0][free], ref[0][free], 'theta')
        assert_same(fast[3] * pb.sig, ref[3] * pb.sig, 'residual')
        assert_same(np.angle(np.exp(1j * (fast[1] - ref[1]))), 0.0, 'psi')


@pytest.mark.parametrize('latitude', [45.0, None])
def test_gram_matches_dense_jacobian(monkeypatch, latitude):
    w, x = synth(4)
    pb, _ = problem(monkeypatch, w, x, latitude=latitude, omega1=OMEGA1, order=1)
    rng = np.random.default_rng(5)
    size = pb.x.shape[2] + len(pb.up) + (latitude is None)
    psi, wts = rng.uniform(-np.pi, np.pi, len(pb.up)), rng.uniform(0.1, 1, (len(pb.y), 3))
    g, ref = pb.gram(psi, 0.7, wts, size), reference_gram(pb, psi, 0.7, wts, size)
    np.testing.assert_allclose(g, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))


def test_hold_medians_match_numpy():
    rng = np.random.default_rng(6)
    inv = rng.integers(0, 7, 301)
    v = np.abs(rng.normal(size=(301, 3)))
    med = gs._hold_medians(v, inv, 7)
    assert np.array_equal(med, [np.median(v[inv == j]) for j in range(7)])


@pytest.mark.parametrize('latitude,order,inputs,omega1,robust,shuffle', [
    (45.0, 2, True, None, True, False), (None, 2, True, OMEGA1, True, True),
    (-30.0, 1, True, OMEGA1, False, False), (None, 0, False, None, False, True),
    (45.0, 2, False, OMEGA1, True, False)])
def test_fit_matches_dense_reference(monkeypatch, latitude, order, inputs, omega1, robust,
                                     shuffle):
    w, x = synth(7, bad_hold=10, latitude=45.0 if latitude is None else latitude,
                 omega1=omega1)
    if shuffle:                                 # holds not contiguous
        perm = np.random.default_rng(8).permutation(len(w))
        w, x = w.select(perm), x[perm]
    args = (w, x if inputs else None, w.accel, np.full(3, 30.0))
    kw = dict(latitude=latitude, omega1=omega1, order=order, robust=robust)
    fast = fit_gyro_static(*args, **kw)
    monkeypatch.setattr(gs, '_alternate', reference_alternate)
    monkeypatch.setattr(gs._StaticProblem, 'gram', reference_gram)
    ref = fit_gyro_static(*args, **kw)
    assert fast.notes == ref.notes and fast.outlier_holds == ref.outlier_holds
    assert fast.fixed == ref.fixed and fast.estimated.keys() == ref.estimated.keys()
    assert all(np.array_equal(fast.estimated[k], ref.estimated[k]) for k in ref.estimated)
    assert fast.ratios.keys() == ref.ratios.keys()
    assert_same(list(fast.ratios.values()), list(ref.ratios.values()), 'ratios')
    for name in ('beta', 'offset', 'g', 'horizontal_fraction', 'residual_rms'):
        assert_same(getattr(fast, name), getattr(ref, name), name)
    assert_same(np.angle(np.exp(1j * (fast.heading - ref.heading))), 0.0, 'heading')
    for name in ref.std:
        assert_same(fast.std[name], ref.std[name], f'std {name}')
    if robust and inputs:
        assert ref.outlier_holds == [31]         # the offset hold (id 3 * 10 + 1)
