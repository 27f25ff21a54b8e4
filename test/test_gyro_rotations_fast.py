"""The fast pieces of the gyro fits against their plain versions.

``gyro_transitions._group_starts`` (the merged increment groups of every pose change, found
for all transitions at once) against the sample-by-sample loop it replaced, bit for bit, on
random increments and on the pose changes of the ``sim.scenarios`` sessions and the real
fixtures written as bags and collected as the CLI does (``collect_windows(motion=True)``);
the column-wise ``rotations.cross``/``sum_sq`` against numpy, bit for bit; held-out refits
(``estimate_only``) against the full fit; ``decide_determined`` from a normal matrix against
the one from the Jacobian.
"""

import os
import sys

import numpy as np
import pytest

from thermal_imu_calib import rotations, sim
from thermal_imu_calib.estimation import gyro_rotations as gr, gyro_transitions as gt
from thermal_imu_calib.estimation.observability import decide_determined, Layout
from thermal_imu_calib.app.collect import collect_windows

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'bench'))
import make_real_bags  # noqa: E402


def loop_starts(b):
    """Return the group starts of the loop ``_merge_commuting`` ran before (the reference)."""
    groups = [0]
    sx = sy = sz = ex = ey = ez = 0.0
    lim2 = gt.MERGE_COMMUTATOR ** 2
    for i, (x, y, z) in enumerate(np.asarray(b, float).tolist()):
        # commutator added by appending theta_i to the group: 1/2 S x theta_i
        cx, cy, cz = 0.5 * (sy * z - sz * y), 0.5 * (sz * x - sx * z), 0.5 * (sx * y - sy * x)
        nx, ny, nz = ex + cx, ey + cy, ez + cz
        if i and nx * nx + ny * ny + nz * nz > lim2:
            groups.append(i)
            sx, sy, sz, ex, ey, ez = x, y, z, 0.0, 0.0, 0.0
        else:
            sx, sy, sz, ex, ey, ez = sx + x, sy + y, sz + z, nx, ny, nz
    return np.array(groups)


def assert_groups_match(increments):
    """Assert ``_group_starts`` (all at once and one by one) equals the loop; return groups."""
    ref = [loop_starts(b) for b in increments]
    for window in (1, 7, 64):
        got = gt._group_starts(increments, window)
        assert len(got) == len(ref)
        for j, (r, g) in enumerate(zip(ref, got)):
            assert np.array_equal(r, g), (window, j)
    for b, r in zip(increments, ref):
        assert np.array_equal(gt._group_starts([b])[0], r)
    return sum(len(r) for r in ref)


def test_group_starts_equal_the_loop_on_random_increments():
    rng = np.random.default_rng(3)
    incs = []
    for n, scale, axis_mix in ((1, 1e-3, 1.0), (2, 1e-2, 1.0), (50, 1e-2, 1.0),
                               (700, 5e-3, 0.05), (300, 1e-5, 1.0), (900, 2e-2, 0.0)):
        axis = np.array([0.0, 0.0, 1.0]) + axis_mix * rng.normal(size=(n, 3))
        incs.append(scale * axis * rng.uniform(0.5, 1.5, size=(n, 1)))
    groups = assert_groups_match(incs)
    assert groups > 50                      # short and long groups were both exercised
    b = incs[3]
    merged = gt._merge_commuting([(b, b ** 2, b ** 3, 0 * b)])[0]
    starts = loop_starts(b)
    for x, y in zip(merged, (b, b ** 2, b ** 3, 0 * b)):
        assert np.array_equal(x, np.add.reduceat(y, starts, axis=0))


@pytest.fixture(scope='module')
def pose_changes(tmp_path_factory):
    """{log: [(n, 3) increments]} of the sim sessions and real fixtures (raw and de-biased)."""
    d = tmp_path_factory.mktemp('logs')
    make_real_bags.main(str(d))
    paths = sorted(str(d / f) for f in os.listdir(d) if f.endswith('.mcap'))
    for name in ('hand-held', 'imutk-procedure'):
        path = str(d / f'{name}.mcap')
        sim.write_scenario(path, name, 1)
        paths.append(path)
    out = {}
    for path in paths:
        col = collect_windows(path, motion=True, progress=False)
        bias = np.median(col.windows.gyro, axis=0) if len(col.windows) else np.zeros(3)
        incs = []
        for tr in col.transitions:
            if len(tr.t) >= 2:
                dt = np.diff(tr.t)
                incs += [gt._trapezoid(tr.gyro, dt), gt._trapezoid(tr.gyro - bias, dt)]
        out[os.path.basename(path)] = incs
    return out


def test_group_starts_equal_the_loop_on_real_and_simulated_pose_changes(pose_changes):
    with_motion = 0
    for name, incs in pose_changes.items():
        if incs:
            with_motion += 1
            assert assert_groups_match(incs) > len(incs), name
    assert with_motion >= 4          # ferraris, mpu6050 and both sim sessions have pose changes


def test_column_cross_and_norms_are_numpys_bit_for_bit():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(400, 3)) * np.exp(3 * rng.normal(size=(400, 3)))
    b = rng.normal(size=(400, 3))
    assert np.array_equal(rotations.cross(a, b), np.cross(a, b))
    assert np.array_equal(rotations.cross(a[:-1], a[1:]), np.cross(a[:-1], a[1:]))
    q = rng.normal(size=(7, 9, 4))
    assert np.array_equal(rotations.sum_sq(a), np.sum(a * a, axis=-1))
    assert np.array_equal(rotations._norm(q), np.linalg.norm(q, axis=-1, keepdims=True))


def test_estimate_only_refit_has_the_same_estimate():
    rng = np.random.default_rng(4)
    k, n = 10, 12
    b = rng.normal(size=(k, n, 3)) * 0.2
    truth = np.eye(3) + rng.normal(size=(3, 3)) * 0.01
    u_from = rng.normal(size=(k, 3))
    u_from /= np.linalg.norm(u_from, axis=1, keepdims=True)
    prep = gt.PreparedTransitions(b, b ** 2 * 0.1, b ** 3 * 0.01, u_from, u_from,
                                  np.full(k, 1e-3), np.zeros(k, bool), list(range(k)))
    # residual u_to - carried with u_to = u_from: the carried direction of Omega1 = truth
    prep.u_to = u_from - gr.rotation_residuals(prep, truth, 0.0, 0.0)
    full = gr.fit_gyro_rotations(prep, select=False)
    quick = gr.fit_gyro_rotations(prep, select=False, estimate_only=True)
    for name in ('omega1', 'omega2', 'omega3'):
        assert np.array_equal(getattr(full, name), getattr(quick, name)), name
    assert np.abs(full.omega1 - truth).max() < 1e-6
    assert len(quick.error_after_deg) == 0 and np.isnan(quick.std['Omega1']).all()


def test_decide_determined_from_the_normal_matrix_matches_the_jacobian():
    results = []
    for use_normal in (False, True):
        lay = Layout()
        lay.add('a', (4,), 0.0, 1.0)
        lay.add('c', (3,), 0.0, [1.0, 0.1, 0.01])
        lay.add('psi', (2,), 0.0, np.pi)
        jac = np.random.default_rng(6).normal(size=(40, lay.size))
        jac[:, 1] *= 1e-3                             # one weakly determined parameter
        jac[:, 5:7] *= 1e-2
        nuis = np.zeros(lay.size, bool)
        nuis[7:] = True
        kw = dict(chains=[[4, 5, 6]], nuisance=nuis)
        results.append(decide_determined(lay, None, 1.5, normal=jac.T @ jac, **kw)
                       if use_normal else decide_determined(lay, jac, 1.5, **kw))
    (free_j, ratios_j), (free_n, ratios_n) = results
    assert np.array_equal(free_j, free_n) and not free_j[1] and free_j.sum() >= 3
    assert ratios_j.keys() == ratios_n.keys()
    np.testing.assert_allclose(list(ratios_n.values()), list(ratios_j.values()), rtol=1e-9)
