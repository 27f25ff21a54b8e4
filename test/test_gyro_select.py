"""Default gyro model of accelerometer-only estimators: bias polynomial vs seed 002 static."""

import dataclasses

import numpy as np
import pytest

from _thermal_data import options, sim_windows
from thermal_imu_calib import sim
from thermal_imu_calib.estimation import calibrate
from thermal_imu_calib.selection import gyro_select
from thermal_imu_calib.estimation.calibrate import calibrate_windows


@pytest.fixture(scope='module')
def demo():
    # the simulated MEMS gyro has g-sensitivity 0.01-0.04 deg/s/g per element
    return sim_windows(sim.simulate('demo', 1)), sim_windows(sim.simulate('demo-validation', 1))


def _still_error(cal, w):
    res = cal.apply(w.accel, w.gyro, w.temp)
    return float(np.sqrt(np.mean(gyro_select.still_rate_error(res.gyro) ** 2)))


def test_installed():
    choices = calibrate.model_choices()
    assert choices[0] == 'auto' and {'field', 'whole_unit', 'offset'} <= set(choices)
    assert calibrate.DEFAULT_GYRO[0] is gyro_select.default_gyro


def test_six_faces_pick_the_g_sensitive_gyro_model_and_it_holds_on_the_next_cold_start(demo):
    cal_w, val_w = demo
    o = options(1)
    o.model = 'field'
    o.latitude = 45.0
    res = calibrate_windows(cal_w, o)
    cal = res.calibration
    assert cal.accel.kind == 'field_polynomial' and cal.gyro.kind == 'whole_unit_gyro'
    choice = res.report['gyro_choice']
    s = choice['heldout_still_error_rad_s']
    assert choice['model'] == 'whole_unit_gyro'
    assert s['whole_unit'] < (1 - gyro_select.GYRO_MARGIN) * s['polynomial']
    assert any('chosen over the bias polynomial' in n for n in cal.notes)
    assert np.any(cal.gyro.estimated_mask('C'))
    # the bias polynomial on the same data, for comparison, on the validation cold start
    poly = calibrate._gyro_bias(calibrate.Context(
        cal_w, o, 1, cal_w.temp[:, [0, 0, 0]], cal_w.temp[:, [0, 0, 0]],
        cal.accel.t0, [0, 0, 0], [0, 0, 0], {}, 12, None))[0]
    cal_poly = dataclasses.replace(cal, gyro=poly)
    e_wu, e_poly = _still_error(cal, val_w), _still_error(cal_poly, val_w)
    print(f'validation still-gyro error: seed 002 {e_wu:.2e}, polynomial {e_poly:.2e} rad/s')
    assert e_wu < 0.3 * e_poly


def test_one_orientation_keeps_the_bias_polynomial():
    w = sim_windows(sim.simulate('single-warmup', 1, hold_s=(900.0, 900.0)))
    res = calibrate_windows(w, options(1))
    assert res.calibration.gyro.kind == 'offset_polynomial'
    assert 'gyro_choice' not in res.report
    assert any(n.startswith('gyroscope: bias polynomial') for n in res.calibration.notes)
