"""``placement_levels``: a random level per placement (a robot's stop), fitted by REML.

The core (``estimation.placement_levels``) is checked against a plain dense
implementation of the same restricted likelihood (every matrix built, scipy's bounded
minimiser), against ordinary least squares where placements do not matter, and on the
case it is for: a few stops whose floor tilts happen to line up with their temperatures.
Then through ``calibrate``: the synthetic warming stops of ``test_placement_floor`` (the
horizontal levels are tilt only, no temperature dependence at all).
"""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from thermal_imu_calib.estimation.offset_fit import weighted_polyfit
from thermal_imu_calib.estimation.placement_levels import (held_out_level_fits,
                                                           random_level_fit,
                                                           random_level_fits)

from test_placement_floor import _choice, _stops


def _placements(rng, n_place=12, level_std=0.02, slope=0.002, noise=0.003):
    per = rng.integers(3, 15, n_place)
    g = np.repeat(np.arange(n_place), per)
    n = len(g)
    temp = np.repeat(rng.uniform(0.0, 3.0, n_place), per) + rng.normal(0.0, 0.3, n)
    a = np.stack([np.ones(n), temp - 1.0, (temp - 1.0) ** 2], axis=1)
    y = a @ np.array([0.1, slope, 5e-4]) + rng.normal(0.0, level_std, n_place)[g] \
        + rng.normal(0.0, noise, n)
    return a, y, rng.uniform(0.5, 1.5, n), g


def _dense_reml(a, y, w, g):
    """The same restricted likelihood with every matrix built (the cross-check)."""
    n, p = a.shape
    z = (g[:, None] == np.unique(g)[None]).astype(float)

    def crit(log_lam):
        v = np.diag(1.0 / w) + 10.0 ** log_lam * z @ z.T
        vi = np.linalg.inv(v)
        m = a.T @ vi @ a
        c = np.linalg.solve(m, a.T @ vi @ y)
        r = y - a @ c
        return (n - p) * np.log(r @ vi @ r) + np.linalg.slogdet(v)[1] + \
            np.linalg.slogdet(m)[1], c
    res = minimize_scalar(lambda x: crit(x)[0], bounds=(-6.0, 8.0), method='bounded',
                          options={'xatol': 1e-9})
    return crit(res.x)[1], 10.0 ** res.x


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_the_fit_equals_a_dense_reml(seed):
    a, y, w, g = _placements(np.random.default_rng(seed))
    coef, lam = _dense_reml(a, y, w, g)
    fit = random_level_fit(a, y, w, g)
    assert fit.lam == pytest.approx(lam, rel=0.05)
    np.testing.assert_allclose(fit.coef, coef, rtol=2e-3, atol=1e-6)
    assert np.all(fit.std() > 0)


def test_without_scatter_between_placements_it_is_ordinary_least_squares():
    """No level scatter: REML mostly lands on lam = 0 (then exactly OLS), else near it."""
    at_zero = 0
    for seed in range(7, 15):
        a, y, w, g = _placements(np.random.default_rng(seed), level_std=0.0)
        fit = random_level_fit(a, y, w, g)
        sw = np.sqrt(w)
        ols = np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)[0]
        if fit.lam == 0.0:
            at_zero += 1
            np.testing.assert_allclose(fit.coef, ols, rtol=1e-9, atol=1e-12)
        assert np.all(np.abs(fit.coef - ols) <= 2.0 * fit.std())
    assert at_zero >= 4
    a, y, w, g = _placements(np.random.default_rng(7))
    one = random_level_fit(a, y, w, np.zeros(len(y), int))     # one placement: OLS
    assert one.lam == 0.0
    sw = np.sqrt(w)
    np.testing.assert_allclose(one.coef, np.linalg.lstsq(a * sw[:, None], y * sw,
                                                         rcond=None)[0], rtol=1e-9)


def test_levels_that_line_up_with_temperature_are_not_read_as_a_slope():
    """Five stops over 1 degC, tilt levels 15 mm/s^2 apart, a true 2 mm/s^2/degC."""
    rng = np.random.default_rng(11)
    err_ols, err_lv, covered = [], [], 0
    trials = 200
    for _ in range(trials):
        n_place, per = 5, 15
        g = np.repeat(np.arange(n_place), per)
        t = np.linspace(5.0, 6.1, n_place * per) + rng.normal(0.0, 0.02, n_place * per)
        y = 0.002 * (t - 5.5) + rng.normal(0.0, 0.015, n_place)[g] \
            + rng.normal(0.0, 5e-4, len(g))
        w = np.full(len(g), 1.0 / 5e-4)                     # 1 / std of a window mean
        c_ols, _ = weighted_polyfit(t - 5.5, y, w, 1)
        c_lv, s_lv = weighted_polyfit(t - 5.5, y, w, 1, levels=g)
        err_ols.append(c_ols[1] - 0.002)
        err_lv.append(c_lv[1] - 0.002)
        covered += abs(c_lv[1] - 0.002) <= 2.0 * s_lv[1]
    rms_ols = np.sqrt(np.mean(np.square(err_ols)))
    rms_lv = np.sqrt(np.mean(np.square(err_lv)))
    assert rms_lv < 0.5 * rms_ols
    assert covered >= 0.85 * trials          # its standard error is honest


def test_fits_done_together_are_each_the_fit_done_alone():
    """Three axes' fits at once (a thermal fit's) equal each fit alone, bit for bit."""
    rng = np.random.default_rng(7)
    a, y, w, g = _placements(rng, level_std=0.0)
    a3 = np.stack([a, a * np.array([1.0, 1.3, 0.7]),
                   np.column_stack([a[:, 0], a[:, 1] + 0.5, a[:, 2]])])
    # little scatter between placements, some, and much (three different lam)
    y3 = np.stack([y, y + rng.normal(0.0, 0.02, g.max() + 1)[g],
                   3.0 * y + rng.normal(0.0, 0.2, g.max() + 1)[g]])
    w3 = np.stack([w, w[::-1], np.ones_like(w)])
    together = random_level_fits(a3, y3, w3, g)
    for k, fit in enumerate(together):
        alone = random_level_fit(a3[k], y3[k], w3[k], g)
        assert fit.lam == alone.lam and fit.sigma2 == alone.sigma2
        assert np.array_equal(fit.coef, alone.coef)
        assert np.array_equal(fit.unscaled_cov, alone.unscaled_cov)
    # one placement: ordinary weighted least squares for every fit (lam 0)
    one = random_level_fits(a3, y3, w3, np.zeros(len(g)))
    assert [f.lam for f in one] == [0.0] * 3
    np.testing.assert_allclose(one[0].coef, np.linalg.lstsq(
        a * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0], rtol=1e-9)


def test_held_out_fits_leave_each_group_out():
    a, y, w, g = _placements(np.random.default_rng(5))
    groups = g % 4
    out = held_out_level_fits(a, y, w, groups, g)
    for k in range(4):
        tr = groups != k
        np.testing.assert_allclose(out[k], random_level_fit(a[tr], y[tr], w[tr], g[tr]).coef)


def test_held_out_fits_done_together_are_each_fold_fitted_alone():
    """The folds' fits at once (padded placements, their own rows) equal each fold's
    ``random_level_fit``, bit for bit: folds of whole placements and folds cutting them,
    folds left with one placement or too few rows (the ordinary fit), many seeds."""
    checked = fallback = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        a, y, w, g = _placements(rng, n_place=int(rng.integers(2, 14)),
                                 level_std=float(rng.choice([0.0, 0.005, 0.05])))
        for groups in (g // 3, rng.integers(0, 5, len(g)), np.arange(len(g)) * 4 // len(g),
                       (g > 0).astype(int)):
            out = held_out_level_fits(a, y, w, groups, g)
            for k, grp in enumerate(np.unique(groups)):
                tr = groups != grp
                alone = random_level_fit(a[tr], y[tr], w[tr], g[tr])
                assert np.array_equal(out[k], alone.coef), (seed, k)
                checked += 1
                fallback += alone.lam == 0.0 and (len(np.unique(g[tr])) < 2
                                                  or tr.sum() <= a.shape[1] + 1)
    assert checked > 500 and fallback > 20        # 562 and 53 on 2026-12-07


@pytest.mark.parametrize('seed', [4, 6])
def test_calibrate_does_not_read_floor_tilt_as_temperature(seed):
    """The horizontal axes have no thermal dependence; the gyro has a real one."""
    w = _stops(seed=seed)
    _, plain = _choice(w)
    _, levels = _choice(w, placement_levels=True)
    temps = np.linspace(w.temp.min(), w.temp.max(), 50)[:, None]

    def swing(cal):          # largest horizontal offset the model applies over the stops
        off = cal.accel.correct(np.zeros((50, 3)), temps)
        return float(np.max(np.ptp(off[:, :2], axis=0)))
    assert swing(levels) < 0.25 * swing(plain)
    assert swing(levels) < 5e-3               # m/s^2, against tilt levels of ~30 mm/s^2
    gyro = levels.gyro.correct(np.zeros((50, 3)), temps) - plain.gyro.correct(
        np.zeros((50, 3)), temps)
    assert np.max(np.abs(gyro)) < 1e-6        # rad/s: the real gyro slope is kept


def test_the_accelerometer_alone_leaves_the_gyro_fit_as_it_was():
    w = _stops(seed=6)
    _, plain = _choice(w)
    _, both = _choice(w, placement_levels=True)
    _, accel = _choice(w, placement_levels=True, placement_levels_sensors='accel')
    temps = np.linspace(w.temp.min(), w.temp.max(), 50)[:, None]
    zero = np.zeros((50, 3))
    np.testing.assert_allclose(accel.accel.correct(zero, temps),
                               both.accel.correct(zero, temps), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(accel.gyro.correct(zero, temps),
                               plain.gyro.correct(zero, temps), rtol=1e-9, atol=1e-15)


def test_lifelong_refuses_an_unknown_sensor_set():
    from thermal_imu_calib.lifelong.config import LifelongConfig
    with pytest.raises(ValueError, match="placement_levels_sensors 'mag' is not one of"):
        LifelongConfig(placement_levels_sensors='mag')


def test_calibrate_options_refuse_an_unknown_sensor_set_by_name():
    from thermal_imu_calib.estimation.options import CalibrateOptions
    options = CalibrateOptions(placement_levels=True, placement_levels_sensors='mag')
    with pytest.raises(ValueError, match="placement_levels_sensors 'mag' is not one of both"):
        options.levels('accel')


def test_the_file_and_the_report_say_which_fits_took_levels():
    """fit.placement_levels and a note name the sensors; the report refits them the same way."""
    import copy
    from thermal_imu_calib.report import validation
    w = _stops(seed=6)
    _, plain = _choice(w)
    _, accel = _choice(w, placement_levels=True, placement_levels_sensors='accel')
    assert 'placement_levels' not in plain.fit
    assert not any(n.startswith('placement levels') for n in plain.notes)
    assert accel.fit['placement_levels'] == ['accel']
    assert any(n.startswith('placement levels: the accel thermal fits') for n in accel.notes)
    assert validation.has_validation(accel)
    unlabelled = copy.copy(accel)
    unlabelled.fit = {k: v for k, v in accel.fit.items() if k != 'placement_levels'}

    def curves(cal):                # the held-out panels' lines: accel, then gyro
        fig = validation.heldout_residuals(cal, w)
        return [[np.asarray(ln.get_ydata()) for ln in ax.lines if ln.get_label() != 'raw']
                for ax in fig.axes[:2]]
    with_levels, without = curves(accel), curves(unlabelled)
    assert any(a.shape != b.shape or not np.allclose(a, b)
               for a, b in zip(with_levels[0], without[0]))      # accel: refitted with levels
    assert all(np.array_equal(a, b) for a, b in zip(with_levels[1], without[1]))  # gyro: not
