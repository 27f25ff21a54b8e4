"""PX4- and ArduPilot-style cubic baselines: data handling, recovery, estimators."""

import os
import warnings

import numpy as np
import pytest

from _thermal_data import BMI270, bmi270_windows, make_windows, options, sim_windows
from thermal_imu_calib import sim
from thermal_imu_calib.estimation.baselines import (ardupilot_bins, ardupilot_fit, px4_fit)
from thermal_imu_calib.estimation.calibrate import (calibrate_windows, CalibrationRefused,
                                                    model_choices)
from thermal_imu_calib.estimation.offset_fit import fit_offset_model
from thermal_imu_calib.estimation.thermal_lag import cv_groups

COEF = np.array([[0.0, 0.0, 0.0], [3e-3, -1e-3, 2e-3], [4e-5, 2e-5, -6e-5],
                 [-1e-6, 5e-7, 2e-6]])   # offset(dT) = sum c_j dT^j, m/s^2


def _cubic(dt):
    return np.stack([dt ** j for j in range(4)], 1) @ COEF


def _warmup(rng=None, sigma=1e-6):
    t = np.arange(0, 3600, 5.0)
    temp = 15 + 30 * (1 - np.exp(-t / 900))
    acc = _cubic(temp - 30.0) + np.array([0.1, -0.2, 9.8])
    gyr = _cubic(temp - 30.0) * 0.1 + 0.01
    return make_windows(t, temp, acc, gyr, sigma_a=sigma, sigma_g=sigma, rng=rng)


def test_px4_recovers_a_cubic_about_the_mid_temperature():
    w = _warmup()
    ta = w.temp[:, [0, 0, 0]]
    model, rep = px4_fit(w, ta, 'gyro', 'gyro')
    tref = 0.5 * (w.temp.min() + w.temp.max())
    assert rep['TREF_degC'] == pytest.approx([tref] * 3)
    # the same cubic written about TREF instead of 30 degC
    probe = np.linspace(w.temp.min(), w.temp.max(), 7)
    expect = 0.1 * _cubic(probe - 30.0) + 0.01
    np.testing.assert_allclose(model.offset(np.repeat(probe[:, None], 3, 1)), expect,
                               atol=5e-8)       # window noise 4.5e-8
    assert model.include_constant and np.all(model.coeff_std[1:] < 1e-7)
    acc, _ = px4_fit(w, ta, 'accel', 'accel')
    assert not acc.include_constant and np.all(acc.coeffs[0] == 0)
    drift = acc.correct(w.accel, ta)
    assert np.std(drift, axis=0).max() < 6e-8      # only the constant and noise are left


def test_px4_median_filter_rejects_one_bad_window():
    w = _warmup()
    w.gyro[300, 1] += 0.5       # a bump (e.g. someone touched the board)
    ta = w.temp[:, [0, 0, 0]]
    with_median, _ = px4_fit(w, ta, 'gyro', 'gyro')
    without, _ = px4_fit(w, ta, 'gyro', 'gyro', median_kernel=1)
    clean = 0.1 * _cubic(w.temp[:, 0] - 30.0)[:, 1] + 0.01
    err_med = np.abs(with_median.offset(ta)[:, 1] - clean).max()
    err_raw = np.abs(without.offset(ta)[:, 1] - clean).max()
    assert err_med < 1e-6 < 1e-4 < err_raw


def test_ardupilot_bins_rise_only_and_restart_after_cooling():
    temps = np.array([20.0, 20.2, 20.6, 20.4, 21.1, 19.0, 19.3, 19.6])
    n = np.ones(8)
    y = np.arange(8.0)[:, None]
    tb, yb = ardupilot_bins(n, temps, y, step=0.5)
    # bin 1 closes at 20.6 (rows 0-2); 20.4 is below it: the learner restarts there, bin 2
    # closes at 21.1 (rows 3-4); 19.0 restarts again and 19.6 closes a bin of rows 5-7
    np.testing.assert_allclose(tb, [20.3, 20.75, 19.3])
    np.testing.assert_allclose(yb[:, 0], [1.0, 3.5, 6.0])


def test_ardupilot_fit_is_relative_to_35_degC_and_the_first_bin():
    w = _warmup()
    ta = w.temp[:, [0, 0, 0]]
    model, rep = ardupilot_fit(w, ta, 'accel', 'accel')
    assert rep['TREF_degC'] == 35.0 and np.all(model.t0 == 35.0)
    assert np.all(model.coeffs[0] == 0) and not model.include_constant
    # 15 -> 44.9 degC: at most 59 bins of 0.5 degC, fewer where a window overshoots the step
    assert 50 <= min(rep['bins_used']) <= max(rep['bins_used']) <= 59
    # the drift between two temperatures is reproduced to 1 %: a bin's mean is placed at
    # the middle of its start and end temperature, not at its mean temperature
    a, b = np.full((1, 3), 20.0), np.full((1, 3), 40.0)
    got = model.offset(b) - model.offset(a)
    expect = _cubic(np.array([10.0])) - _cubic(np.array([-10.0]))
    np.testing.assert_allclose(got, expect, rtol=1e-2)
    assert not np.allclose(got, expect, rtol=1e-3)
    flat = make_windows(np.arange(0, 600, 5.0), np.full(120, 30.0),
                        np.zeros((120, 3)), np.zeros((120, 3)))
    with pytest.raises(ValueError, match='rise by 2 degC'):
        ardupilot_fit(flat, flat.temp[:, [0, 0, 0]], 'gyro', 'gyro')


def test_baseline_estimators_through_calibrate():
    assert {'px4', 'ardupilot'} <= set(model_choices())
    w = sim_windows(sim.simulate('single-warmup', 2, hold_s=(1200.0, 1200.0)))
    for name in ('px4', 'ardupilot'):
        o = options()
        o.model = name
        res = calibrate_windows(w, o)
        cal = res.calibration
        assert cal.accel.kind == cal.gyro.kind == 'offset_polynomial' and cal.accel.order == 3
        out = cal.apply(w.accel, w.gyro, w.temp)
        # drift removed: the gyro spread over the warm-up shrinks at least 5x
        assert np.ptp(out.gyro, 0).max() < 0.2 * np.ptp(w.gyro, 0).max()
        assert all(p.std is not None for p in cal.gyro.params().values() if p.unit != 'degC')
    flat = make_windows(np.arange(0, 600, 5.0), np.full(120, 30.0),
                        np.tile([0, 0, 9.8], (120, 1)), np.zeros((120, 3)))
    o = options()
    o.model = 'ardupilot'
    with pytest.raises(CalibrationRefused, match='rise by 2 degC'):
        calibrate_windows(flat, o)


def _csv_means():
    """Return (mean degC per soak, mean gyro deg/s (3,) per soak) by np.genfromtxt alone."""
    temps, gyro = [], []
    for name in ('BMI_270_cold_test_.csv', 'BMI_270_hot_test.csv'):
        with warnings.catch_warnings():     # the serial garbage lines are reported
            warnings.simplefilter('ignore')
            a = np.genfromtxt(os.path.join(BMI270, name), delimiter=',', usecols=range(7),
                              invalid_raise=False, encoding='latin-1', skip_header=1)
        a = a[np.all(np.isfinite(a), axis=1)] if a.ndim == 2 else a
        temps.append(float(a[:, 0].mean()))
        gyro.append(a[:, 4:7].mean(0))
    return temps, gyro


def test_real_bmi270_gyro_bias_vs_temperature():
    """Two real soaks (13 and 47 degC): the bias line is learnt and predicts held-out halves.

    Two nearly isothermal points pin a line and nothing more; with half a soak left out
    both temperatures stay in the training data, so this checks the bias change only.
    """
    w = bmi270_windows()
    assert len(w) == 36 and set(np.unique(w.hold)) == {0, 1}
    temps = [float(w.temp[w.hold == h].mean()) for h in (0, 1)]
    # the same figures straight from the CSV files (numpy's own parser, whole files, no
    # windows): the loader and windowing must not change them beyond the dropped tail
    ref_t, ref_g = _csv_means()
    assert temps == pytest.approx(ref_t, abs=0.02)
    bias = [np.degrees(w.gyro[w.hold == h].mean(0)) * 1e3 for h in (0, 1)]   # mdeg/s
    slope = (bias[1] - bias[0]) / (temps[1] - temps[0])
    ref_slope = (ref_g[1] - ref_g[0]) * 1e3 / (ref_t[1] - ref_t[0])
    np.testing.assert_allclose(slope, ref_slope, atol=0.3)
    half = np.zeros(len(w), int)
    for h in (0, 1):
        idx = np.flatnonzero(w.hold == h)
        half[idx[len(idx) // 2:]] = 1
    groups = 2 * w.hold + half
    tg = w.temp[:, [0, 0, 0]]
    err = {'raw': [], 'offset': [], 'px4': []}
    for g in np.unique(groups):
        test = groups == g
        wt = w.select(~test)
        ours, _ = fit_offset_model(wt, tg[~test], np.full(3, 30.0), 'gyro', 'gyro', True,
                                   groups=cv_groups(wt)[0])   # time blocks here
        px4, _ = px4_fit(wt, tg[~test], 'gyro', 'gyro')
        err['raw'].append(w.gyro[test] - w.gyro[~test].mean(0))
        err['offset'].append(w.gyro[test] - ours.offset(tg[test]))
        err['px4'].append(w.gyro[test] - px4.offset(tg[test]))
    rms = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in err.items()}
    assert rms['offset'] < 0.25 * rms['raw']
    # a cubic through two clusters 0.3 degC wide bends between the held-out temperatures of
    # a cluster; the CV-chosen order (a line here) does not
    assert rms['offset'] < 0.5 * rms['px4']
