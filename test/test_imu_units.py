"""The IMU unit watch (io/imu_units.py): what the compensator says of g, milli-g and deg/s."""

import numpy as np
import pytest

from thermal_imu_calib.gravity import STANDARD_GRAVITY
from thermal_imu_calib.io.imu_units import ACCEL_WINDOW, accel_unit_problem, UnitWatch

G = STANDARD_GRAVITY


def _stream(n, scale=1.0, turn=0.0, seed=0):
    """A robot driving about: |a| near g with bumps, gyro turns of ``turn`` (its unit)."""
    rng = np.random.default_rng(seed)
    up = np.array([0.05, -0.03, 1.0])
    accel = (G * up / np.linalg.norm(up) + rng.normal(0.0, 1.5, (n, 3))) * scale
    gyro = rng.normal(0.0, 0.02, (n, 3))
    gyro[n // 2:n // 2 + 20, 2] = turn
    return accel, gyro


@pytest.mark.parametrize('scale, unit', [(1 / G, 'in g'), (1000 / G, 'in milli-g'),
                                         (4096 / G, 'in raw counts')])
def test_an_accelerometer_not_in_m_per_s2_is_named(scale, unit):
    w = UnitWatch(G)
    a, g = _stream(3 * ACCEL_WINDOW, scale)
    w.push(a[:ACCEL_WINDOW - 1], g[:ACCEL_WINDOW - 1])
    assert w.accel_ratio is None and w.problems() == {}     # not yet a window's worth
    w.push(a[ACCEL_WINDOW - 1:], g[ACCEL_WINDOW - 1:])
    assert w.accel_ratio == pytest.approx(scale, rel=0.05)
    text = ', '.join(w.problems()['accel'])
    assert f'its values look {unit}' in text and 'publish the IMU in m/s^2' in text
    assert f'(median of {ACCEL_WINDOW} samples)' in text
    assert set(w.problems()) == {'accel'}


def test_si_units_with_motion_and_fast_turns_raise_nothing():
    w = UnitWatch(G)
    for i in range(10):
        a, g = _stream(200, turn=30.0, seed=i)     # 30 rad/s: a fast spin, still a gyro's
        a[::50] = np.nan                            # dropouts are not counted
        w.push(a, g)
    assert w.problems() == {} and 0.9 < w.accel_ratio < 1.3 and w.gyro_unit == 0


def test_a_gyro_in_deg_per_s_is_named_after_ten_samples():
    w = UnitWatch(G)
    a, g = _stream(100, turn=np.degrees(3.0))      # a 3 rad/s turn published in deg/s
    g[50:59, 2] = 150.0
    w.push(a[:59], g[:59])
    assert w.gyro_unit == 9 and w.problems() == {}
    w.push(a[59:], g[59:])
    assert w.gyro_unit == 20
    text = ', '.join(w.problems()['gyro'])
    assert 'the gyro values look in deg/s' in text and 'record or replay' not in text


def test_the_calibrate_refusal_and_the_watch_share_their_verdict():
    assert accel_unit_problem(G, G) is None
    assert accel_unit_problem(0.26 * G, G) is None and accel_unit_problem(3.9 * G, G) is None
    assert 'in g' in accel_unit_problem(1.0, G)[0]
    assert accel_unit_problem(1.0, G)[0].startswith('the accelerometer reads |a| = 1 at rest')


def test_a_driver_fixed_at_run_time_clears_the_accelerometer_verdict():
    w = UnitWatch(G)
    a, g = _stream(ACCEL_WINDOW, 1 / G)
    w.push(a, g)
    assert 'accel' in w.problems()
    a, g = _stream(ACCEL_WINDOW + 7, seed=1)
    w.push(a[:300], g[:300])
    assert 'accel' in w.problems()        # the window in progress does not count yet
    w.push(a[300:], g[300:])
    assert w.problems() == {} and 0.9 < w.accel_ratio < 1.3
