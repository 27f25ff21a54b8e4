"""The gyro's g-sensitivity learned from stops on slopes, judged on the newest of them.

Synthetic windows with a known truth (rad/s, m/s^2, s, degC): a level mounting pose with
a tilt of a few tenths of a degree, one stop in eight on a slope of 3-12 deg at a random
heading, a gyro bias cubic in temperature, the earth rate at 45 deg at a random heading,
and a gyro g-sensitivity G (0.01-0.04 deg/s/g per element, seed 002's class) or none.
"""

import numpy as np

from _level_holds import earth_rate, windows_of
from _robot_month import lifelong_month
from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.lifelong import g_sensitivity
from thermal_imu_calib.lifelong.pose import main_pose_mask

DAY = 86400.0
G0 = 9.80665
LAT = 45.0
G_TRUE = np.array([[6.9, 6.5, 3.8], [-3.6, 2.2, 6.8], [6.7, 3.2, -3.6]]) * 1e-5


def bias_of(temp):
    """True gyro bias (n, 3) at temperatures (n,) degC."""
    d = temp - 20.0
    return np.stack([1e-3 + 2e-5 * d + 3e-7 * d ** 2, -2e-3 - 1e-5 * d,
                     5e-4 + 4e-8 * d ** 3], 1)


def tilted(rng, deg):
    """Return the specific force (3,) of a pose tilted ``deg`` at a random heading."""
    a, az = np.radians(deg), rng.uniform(0, 2 * np.pi)
    return G0 * np.array([np.sin(a) * np.cos(az), np.sin(a) * np.sin(az), np.cos(a)])


def month(g_sens, days=12.0, holds=400, seed=0):
    """Return windows (4 per hold) of a robot's stops; ``g_sens`` (3, 3) or None."""
    rng = np.random.default_rng(seed)
    mount = tilted(rng, 0.3)
    rows = []
    for h, th in enumerate(np.sort(rng.uniform(0.0, days * DAY, holds))):
        f = tilted(rng, rng.uniform(3.0, 12.0)) if rng.random() < 0.125 else \
            mount + rng.normal(0, 0.01, 3)
        heading = rng.uniform(0, 2 * np.pi)
        w_true = earth_rate(heading, LAT)
        for j in range(4):
            t = th + 60.0 * j
            temp = 15.0 + 8.0 * np.sin(2 * np.pi * t / DAY) + rng.normal(0, 0.3)
            g = bias_of(np.array([temp]))[0] + w_true + rng.normal(0, 3e-6, 3)
            if g_sens is not None:
                g = g + g_sens @ f
            rows.append((h, t - 30.0, t + 30.0, temp, g, f + rng.normal(0, 2e-3, 3)))
    return windows_of(rows)


def level_fit(win):
    """Return (calibration of the main-pose windows, main-pose mask), as the loop fits."""
    in_pose = main_pose_mask(win, 2.0)
    opts = CalibrateOptions(model='offset', latitude=LAT,
                            inputs=[TemperatureInput('t', '/imu/temperature')])
    return calibrate_windows(win.select(in_pose), opts).calibration, in_pose


def test_a_g_sensitive_gyro_is_corrected_on_the_slopes():
    win = month(G_TRUE)
    cal, in_pose = level_fit(win)
    coupling = g_sensitivity.learn(cal, win, in_pose, G0, LAT)
    assert coupling.used, coupling.text
    assert coupling.heldout >= 3 and coupling.rms_with < 0.5 * coupling.rms_without
    # the fitted C is G across the level gravity (the slopes' force directions)
    e = g_sensitivity._across(np.median(win.accel[in_pose], 0))
    np.testing.assert_allclose(coupling.c @ e.T, G_TRUE @ e.T, rtol=0, atol=1e-5)
    new, note = g_sensitivity.attach(cal, coupling)
    assert new.gyro.kind == 'whole_unit_gyro' and 'g-sensitivity used' in note
    assert new.fit['g_sensitivity']['pairs'] == coupling.pairs
    # per window: the true rate is the raw gyro less the bias and G f (the earth rate is
    # left in the output); slopes 2x better at least, level windows as before
    true_rate = win.gyro - bias_of(win.temp[:, 0]) - win.accel @ G_TRUE.T
    err = {k: c.apply(win.accel, win.gyro, win.temp).gyro - true_rate
           for k, c in (('old', cal), ('new', new))}
    level = {k: e[in_pose] - np.median(e[in_pose], 0) for k, e in err.items()}
    slope = {k: e[~in_pose] - np.median(err[k][in_pose], 0) for k, e in err.items()}

    def rms(x):
        return np.sqrt(np.mean(np.sum(x ** 2, 1)))
    assert rms(slope['new']) < 0.5 * rms(slope['old']), (rms(slope['new']), rms(slope['old']))
    assert rms(level['new']) < 1.05 * rms(level['old'])
    # the file says what the model is and reads back to the same output
    back = type(new).from_yaml(new.to_yaml())
    np.testing.assert_allclose(back.apply(win.accel, win.gyro, win.temp).gyro,
                               new.apply(win.accel, win.gyro, win.temp).gyro, atol=1e-15)


def test_no_g_sensitivity_is_not_fitted_into_the_gyro():
    win = month(None, seed=1)
    cal, in_pose = level_fit(win)
    coupling = g_sensitivity.learn(cal, win, in_pose, G0, LAT)
    assert not coupling.used and 'not used' in coupling.text, coupling.text
    same, note = g_sensitivity.attach(cal, coupling)
    assert same is cal and note == coupling.text


def test_too_few_slopes_say_how_many_were_found():
    win = month(G_TRUE, days=1.0, holds=40, seed=2)
    cal, in_pose = level_fit(win)
    coupling = g_sensitivity.learn(cal, win, in_pose, G0, LAT)
    assert not coupling.used and 'not fitted' in coupling.text and 'needed' in coupling.text


def test_the_loop_logs_the_g_sensitivity_with_each_estimate(tmp_path):
    """With the option on, every judged estimate's logged text says what the stage found."""
    from thermal_imu_calib.lifelong.config import LifelongConfig
    life = lifelong_month(tmp_path / 'life', LifelongConfig(gyro_g_sensitivity=True))
    judged = [d for d in life.decisions() if d['action'] in ('swap', 'keep')]
    assert judged, life.decisions()
    for d in judged:
        assert d['g_sensitivity'].startswith('g-sensitivity ')
        assert d['g_sensitivity'] in d['text']
