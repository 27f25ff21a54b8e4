"""RVM (seed 003): evidence updates vs scikit-learn, kernel, fits, file format, speed."""


import numpy as np
import pytest
from sklearn.linear_model import ARDRegression

from _thermal_data import G, make_windows, options, sim_windows
from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows
from thermal_imu_calib.estimation.offset_fit import fit_offset_model
from thermal_imu_calib.estimation.rvm_fit import (denormalise, design, fit_rvm_bias_scale,
                                                  fit_rvm_offset, normalise, sbl_fit)
from thermal_imu_calib.estimation.thermal_lag import cv_groups
from thermal_imu_calib.models.rvm import kernel


def test_sbl_equals_ardregression():
    """Same updates as ARDRegression (no intercept): weights, noise, pruning, eq. 31 std."""
    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(-1, 1, 120))
    y = np.sin(2 * x) + 0.3 * x ** 2 + 0.02 * rng.standard_normal(120)
    centres = np.quantile(x, np.linspace(0, 1, 12))
    kept = []
    for s2, d, lam in ((0.25, 2, 0.5), (0.0625, 1, 0.9), (1.0, 3, 0.2)):
        phi = design(x, centres, s2, d, lam)
        ref = ARDRegression(fit_intercept=False, max_iter=300, tol=1e-3,
                            threshold_lambda=1e4).fit(phi, y)
        ours = sbl_fit(phi[None], y[None], max_iter=300, tol=1e-3, threshold=1e4)
        assert ours.n_iter[0] == ref.n_iter_
        np.testing.assert_allclose(ours.mu[0], ref.coef_, atol=1e-9)
        assert ours.beta[0] == pytest.approx(ref.alpha_, rel=1e-9)
        np.testing.assert_array_equal(ours.keep[0], ref.lambda_ < 1e4)
        kept.append(int(ours.keep[0].sum()))
        _, std = ref.predict(phi, return_std=True)
        var = 1 / ours.beta[0] + np.einsum('ni,ij,nj->n', phi, ours.sigma[0], phi)
        np.testing.assert_allclose(np.sqrt(var), std, rtol=1e-9)
    assert min(kept) < 13                          # sparse: relevance vectors only
    # batched with row masks = separate fits on the selected rows
    phi = design(x, centres, 0.25, 2, 0.5)
    rows = np.arange(120) % 3 != 0
    both = sbl_fit(np.stack([phi, phi]), np.stack([y, y]), np.stack([rows, ~rows]))
    sub = ARDRegression(fit_intercept=False).fit(phi[rows], y[rows])
    np.testing.assert_allclose(both.mu[0], sub.coef_, atol=1e-9)


def test_kernel_eq33_and_normalisation_eq34():
    k = kernel(np.array([0.5]), np.array([-0.25]), 0.5, 2, 0.3)
    expect = 0.3 * np.exp(-0.75 ** 2 / (2 * 0.5)) + 0.7 * (0.5 * -0.25 + 1) ** 2
    assert k[0, 0] == pytest.approx(expect, rel=1e-12)
    assert kernel(np.array([0.2]), np.array([0.2]), 0.1, 3, 1.0)[0, 0] == 1.0
    t = np.array([10.0, 30.0, 50.0])
    np.testing.assert_allclose(normalise(t, 10, 50), [-1, 0, 1])
    np.testing.assert_allclose(denormalise(normalise(t, 10, 50), 10, 50), t)


def _nonpoly_drift(temp):
    """Offset (m/s^2) with a kink and a bump: hard for a cubic, easy for kernels."""
    return np.stack([2e-3 * np.tanh((temp - 30) / 3), 1e-3 * np.exp(-((temp - 22) / 4) ** 2),
                     5e-4 * (temp - 30)], 1)


def _cycle_windows(rng, n_legs=4):
    t = np.arange(0, n_legs * 2400, 5.0)
    phase = (t / 2400) % 2
    temp = 10 + 40 * np.where(phase < 1, phase, 2 - phase)
    acc = _nonpoly_drift(temp) + [0.05, -0.1, 9.8]
    gyr = _nonpoly_drift(temp) * 0.1
    return make_windows(t, temp, acc, gyr, sigma_a=5e-3, sigma_g=5e-4, rng=rng)


def test_rvm_offset_fit_beats_a_cubic_on_a_nonpolynomial_drift():
    w = _cycle_windows(np.random.default_rng(3))
    groups, kind = cv_groups(w)
    assert kind == 'temperature legs'
    ta = w.temp[:, [0, 0, 0]]
    model, rep = fit_rvm_offset(w, ta, 'accel', 'accel', groups, offset_only=True,
                                t_ref=[30.0] * 3)
    poly, _ = fit_offset_model(w, ta, np.full(3, 30.0), 'accel', 'accel', False, groups=groups)
    grid = np.repeat(np.linspace(11, 49, 200)[:, None], 3, 1)
    truth = _nonpoly_drift(grid[:, 0]) - _nonpoly_drift(np.array([30.0]))
    err_rvm = np.abs(model.bias_scale(grid)[0] - truth).max(0)
    err_poly = np.abs(poly.offset(grid) - truth).max(0)
    noise = 5e-3 / np.sqrt(500)
    assert err_rvm[0] < 0.25 * err_poly[0] and err_rvm[1] < 0.5 * err_poly[1]
    assert np.all(err_rvm < 8 * noise)
    assert rep['training_points'] <= 300 and rep['cv_groups'] == 4
    assert max(rep['relevance_vectors']) < 34                # of 2 x 17 candidates
    # predictive std: about the noise of a training point inside, growing outside
    inside = model.predict_std(np.full((1, 3), 30.0))[0]
    outside = model.predict_std(np.full((1, 3), 58.0))[0]
    assert np.all(inside < 3 * noise) and np.all(outside > 2 * inside)
    np.testing.assert_allclose(model.predictive_std(np.full((1, 3), 30.0))[0],
                               np.hypot(inside, model.noise_std))
    # eq. 27 noise of a training point: windows are merged ~6.4 to 1 (<= 300 points)
    per_point = len(w) / rep['training_points']
    assert np.all(model.noise_std == pytest.approx(noise / np.sqrt(per_point), rel=0.3))


def rvm_calibration():
    """Return an RVM accel + gyro calibration fitted on two simulated 10..50 degC legs."""
    w = _cycle_windows(np.random.default_rng(4), n_legs=2)
    groups, _ = cv_groups(w)
    acc, _ = fit_rvm_offset(w, w.temp[:, [0, 0, 0]], 'accel', 'accel', groups, True, [30.0] * 3)
    gyr, _ = fit_rvm_offset(w, w.temp[:, [0, 0, 0]], 'gyro', 'gyro', groups)
    return Calibration(accel=acc, gyro=gyr, inputs=[TemperatureInput('t0')],
                       valid_range=np.array([[10.0, 50.0]]), accel_noise_std=np.full(3, 5e-3),
                       gyro_noise_std=np.full(3, 5e-4))


def test_rvm_model_file_round_trip_and_imu_rate():
    cal = rvm_calibration()
    acc = cal.accel
    text = cal.to_yaml()
    back = Calibration.from_yaml(text)
    assert back.accel.kind == 'rvm' and back.accel.meta()['mode'] == 'offset'
    p = back.accel.params()
    assert p['x_min'].unit == 'degC' and p['y_min'].unit == 'm/s^2' and p['cov_x'].unit == '1'
    assert p['w_bias_x'].std is not None and p['w_bias_x'].std.shape == p['w_bias_x'].value.shape
    rng = np.random.default_rng(5)
    n = 200_000                                   # 1000 s at 200 Hz, distinct temperatures
    temps = np.linspace(12, 48, n)[:, None] + rng.normal(0, 1e-3, (n, 1))
    a = rng.normal(0, 1, (n, 3))
    r1 = cal.apply(a, a, temps)
    r2 = back.apply(a, a, temps)
    np.testing.assert_allclose(r1.accel, r2.accel, atol=1e-12)
    np.testing.assert_allclose(r1.gyro_std, r2.gyro_std, rtol=1e-9)
    # the 0.001-degC grid used for long chunks = exact evaluation on distinct values
    exact = acc._per_axis(temps[:5000:7, [0, 0, 0]], lambda ax, t: acc._axis_eval(ax, t)[:1])
    grid = acc._per_axis(temps[:5000, [0, 0, 0]], lambda ax, t: acc._axis_eval(ax, t)[:1])
    for e, g_ in zip(exact, grid):
        np.testing.assert_allclose(e[0], g_[0][::7], atol=1e-10)
    # compensated std = model std (+) white noise, the Imu covariance diagonal
    np.testing.assert_allclose(r1.accel_std[:5], np.hypot(acc.predict_std(temps[:5, [0, 0, 0]]),
                                                          5e-3))


def test_bias_and_scale_separated_by_pose():
    """Six faces: horizontal axes pin the bias, vertical ones bias +- scale (seed 003 s. 3)."""
    rng = np.random.default_rng(6)
    faces = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                     float)
    rows = []
    for rep in range(6):
        for j, up in enumerate(faces):
            for k in range(24):                   # 2 min holds of 5-s windows
                rows.append((rep * 6 + j, up, 12 + rep * 6 + j + k / 24.0))
    hold = np.array([r[0] for r in rows])
    up = np.array([r[1] for r in rows])
    temp = np.array([r[2] for r in rows])
    t = np.arange(len(rows)) * 5.0
    bias = np.stack([3e-2 * np.tanh((temp - 30) / 5), -2e-2 + 4e-4 * (temp - 30),
                     1e-2 * np.sin(temp / 5)], 1)
    dk = np.stack([2e-4 * (temp - 30), -3e-3 * np.exp(-((temp - 35) / 6) ** 2),
                   1e-5 * (temp - 30) ** 2], 1)
    acc = (1 + dk) * (G * up) + bias
    w = make_windows(t, temp, acc, np.zeros_like(acc), hold, sigma_a=2e-3, rng=rng)
    model, rep = fit_rvm_bias_scale(w, w.temp[:, [0, 0, 0]], up, hold % 5, G)
    assert model.mode == 'bias_scale' and rep['cv_groups'] == 5
    grid = np.repeat(np.linspace(14, 45, 50)[:, None], 3, 1)
    b_est, dk_est = model.bias_scale(grid)
    b_true = np.stack([3e-2 * np.tanh((grid[:, 0] - 30) / 5), -2e-2 + 4e-4 * (grid[:, 0] - 30),
                       1e-2 * np.sin(grid[:, 0] / 5)], 1)
    dk_true = np.stack([2e-4 * (grid[:, 0] - 30), -3e-3 * np.exp(-((grid[:, 0] - 35) / 6) ** 2),
                        1e-5 * (grid[:, 0] - 30) ** 2], 1)
    assert np.abs(b_est - b_true).max() < 1e-3         # of a 0.06 m/s^2 swing
    assert np.abs(dk_est - dk_true).max() < 1e-4       # of a 3e-3 swing
    f = model.correct(w.accel, w.temp[:, [0, 0, 0]])
    assert np.abs(np.linalg.norm(f, axis=1) - G).max() < 2e-3
    back = Calibration.from_yaml(Calibration(
        accel=model, inputs=[TemperatureInput('t0')],
        valid_range=np.array([[10.0, 50.0]])).to_yaml())
    np.testing.assert_allclose(back.accel.forward(G * up[:9], w.temp[:9, [0, 0, 0]]),
                               model.forward(G * up[:9], w.temp[:9, [0, 0, 0]]), atol=1e-12)


def test_rvm_through_calibrate_windows():
    w = sim_windows(sim.simulate('single-warmup', 3, hold_s=(1200.0, 1200.0)))
    o = options()
    o.model = 'rvm'
    res = calibrate_windows(w, o)
    cal = res.calibration
    assert cal.accel.kind == cal.gyro.kind == 'rvm' and cal.accel.offset_only
    assert res.report['model_choice'] == {'model': 'rvm', 'reason': 'requested'}
    out = cal.apply(w.accel, w.gyro, w.temp)
    assert np.ptp(out.gyro, 0).max() < 0.2 * np.ptp(w.gyro, 0).max()
    assert np.ptp(out.accel, 0).max() < 0.5 * np.ptp(w.accel, 0).max()
