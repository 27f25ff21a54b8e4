"""Models, calibration file format and gravity."""

import numpy as np
import pytest

from thermal_imu_calib.calibration import Calibration, CalibrationError, TemperatureInput
from thermal_imu_calib.gravity import normal_gravity, resolve_gravity
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel


def _cal(rng):
    th = rng.normal(0, 1e-4, (3, 6))
    s = np.eye(3)
    s[1, 0], s[2, 0], s[2, 1] = 1e-4, -2e-4, 3e-4
    acc = FieldPolynomialModel([25.0, 26.0, 27.0], th, k0=[1.001, 0.999, 1.0],
                               b0=[0.01, -0.02, 0.03], s=s, thermal_std=np.abs(th) / 10)
    gyr = OffsetPolynomialModel([25.0] * 3, rng.normal(0, 1e-3, (3, 3)), sensor='gyro')
    return Calibration(accel=acc, gyro=gyr, inputs=[TemperatureInput('t', '/imu/temperature')],
                       valid_range=np.array([[15.0, 45.0]]), frame_id='imu_link',
                       accel_noise_std=np.full(3, 0.01), gyro_noise_std=np.full(3, 0.001),
                       notes=['a note'], fit={'holds': 3})


def test_field_model_inverts_forward():
    rng = np.random.default_rng(0)
    cal = _cal(rng)
    f = rng.normal(0, 9.8, (100, 3))
    temps = rng.uniform(15, 45, (100, 3))
    raw = cal.accel.forward(f, temps)
    np.testing.assert_allclose(cal.accel.correct(raw, temps), f, atol=1e-12)


def test_field_model_matches_paper_equation_8():
    # raw_i = b_i(T) + k_i(T) * (S f)_i written out by hand for one sample
    m = FieldPolynomialModel([20.0] * 3, np.arange(18).reshape(3, 6) * 1e-5,
                             k0=[1.0, 1.1, 0.9], b0=[0.1, 0.2, 0.3],
                             s=[[1, 0, 0], [0.01, 1, 0], [0.02, 0.03, 1]])
    f = np.array([[1.0, 2.0, 3.0]])
    T = 30.0
    dT = T - 20.0
    th = np.arange(18).reshape(3, 6) * 1e-5
    sf = np.array([[1, 0, 0], [0.01, 1, 0], [0.02, 0.03, 1]]) @ f[0]
    exp = [0.1 + 0.0 + th[0, 3] + th[0, 4] * dT + th[0, 5] * dT ** 2, 0.2 + th[1, 3]
           + th[1, 4] * dT + th[1, 5] * dT ** 2, 0.3 + th[2, 3] + th[2, 4] * dT
           + th[2, 5] * dT ** 2]
    k = [k0 + th[i, 0] + th[i, 1] * dT + th[i, 2] * dT ** 2
         for i, k0 in enumerate([1.0, 1.1, 0.9])]
    exp = np.array(exp) + np.array(k) * sf
    np.testing.assert_allclose(m.forward(f, np.full((1, 3), T))[0], exp, rtol=1e-14)


def test_file_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    cal = _cal(rng)
    p = cal.save(tmp_path / 'c.yaml')
    text = open(p).read()
    assert 'format: thermal_imu_calib/1' in text and 'unit: m/s^2/degC' in text
    back = Calibration.load(p)
    assert back.id == cal.id
    a = rng.normal(0, 9.8, (50, 3))
    g = rng.normal(0, 0.1, (50, 3))
    t = rng.uniform(10, 50, (50, 1))
    r1, r2 = cal.apply(a, g, t), back.apply(a, g, t)
    np.testing.assert_array_equal(r1.accel, r2.accel)
    np.testing.assert_array_equal(r1.gyro, r2.gyro)
    np.testing.assert_array_equal(r1.out_of_range, (t[:, 0] < 15) | (t[:, 0] > 45))
    # docs/uncertainty.md by hand: accel_std = sqrt(model_std(T)^2 + noise^2), the field
    # model_std the bias-equivalent error at 1 g, T clamped to the valid range [15, 45]
    sd, g0 = np.abs(cal.accel.thermal) / 10, 9.80665
    dt = np.clip(t, 15.0, 45.0) - np.array([25.0, 26.0, 27.0])
    model_var = ((sd[:, 0] * g0) ** 2 + (sd[:, 1] * dt * g0) ** 2 + (sd[:, 2] * dt ** 2 * g0) ** 2
                 + sd[:, 3] ** 2 + (sd[:, 4] * dt) ** 2 + (sd[:, 5] * dt ** 2) ** 2)
    np.testing.assert_allclose(r1.accel_std, np.sqrt(model_var + 0.01 ** 2), rtol=1e-12)
    assert np.all(r1.accel_std > 0.01)      # strictly: the model term is there
    # offset polynomial gyro without coefficient std: noise only
    np.testing.assert_allclose(r1.gyro_std, 0.001, rtol=1e-12)


def test_clamp_and_extrapolate():
    rng = np.random.default_rng(2)
    cal = _cal(rng)
    a = np.tile([0.0, 0.0, 9.8], (3, 1))
    g = np.zeros((3, 3))
    t = np.array([[45.0], [60.0], [80.0]])
    r = cal.apply(a, g, t)
    np.testing.assert_allclose(r.accel[1], r.accel[0])  # clamped at 45
    assert list(r.out_of_range) == [False, True, True]
    cal.out_of_range = 'extrapolate'
    r = cal.apply(a, g, t)
    assert not np.allclose(r.accel[1], r.accel[0])
    assert list(r.out_of_range) == [False, True, True]


def test_linear_continuation_beyond_the_range():
    """'linear_gyro': the gyro goes on with its slope over the last degC, no further than the
    range's width; the accel clamps."""
    rng = np.random.default_rng(5)
    cal = _cal(rng)
    a = np.tile([0.0, 0.0, 9.8], (5, 1))
    g = np.zeros((5, 3))
    t = np.array([[45.0], [47.0], [60.0], [15.0], [5.0]])
    clamped = cal.apply(a, g, t)
    cal.out_of_range = 'linear_gyro'
    assert (cal.range_policy('gyro'), cal.range_policy('accel')) == ('linear', 'clamp')
    r = cal.apply(a, g, t)
    np.testing.assert_array_equal(r.accel, clamped.accel)
    assert list(r.out_of_range) == [False, True, True, False, True]
    # by hand from the polynomial: the value at the edge and 1 degC inside it

    def gyro_at(temp):
        return cal.gyro.correct(g[:1], np.full((1, 3), temp))[0]
    for row, (edge, inner) in ((1, (45.0, 44.0)), (2, (45.0, 44.0)), (4, (15.0, 16.0))):
        excess = abs(t[row, 0] - edge)
        want = gyro_at(edge) + (gyro_at(edge) - gyro_at(inner)) * excess
        np.testing.assert_allclose(r.gyro[row], want, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(r.gyro[[0, 3]], clamped.gyro[[0, 3]])
    assert not np.allclose(r.gyro[2], clamped.gyro[2])
    # no further than the range's width (15..45 degC: 30), then held
    far = cal.apply(a[:3], g[:3], np.array([[80.0], [90.0], [-40.0]])).gyro
    slope_hi, slope_lo = gyro_at(45.0) - gyro_at(44.0), gyro_at(15.0) - gyro_at(16.0)
    np.testing.assert_allclose(far[0], gyro_at(45.0) + slope_hi * 30.0, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(far[1], far[0])
    np.testing.assert_allclose(far[2], gyro_at(15.0) + slope_lo * 30.0, rtol=0, atol=1e-15)
    # format 3 (an older reader refuses it instead of clamping); read back, the same output
    text = cal.to_yaml()
    assert 'format: thermal_imu_calib/3' in text and 'out_of_range: linear_gyro' in text
    back = Calibration.from_yaml(text)
    np.testing.assert_array_equal(back.apply(a, g, t).gyro, r.gyro)
    # 'linear': the accelerometer continues too
    cal.out_of_range = 'linear'
    r2 = cal.apply(a, g, t)
    np.testing.assert_array_equal(r2.gyro, r.gyro)
    np.testing.assert_array_equal(r2.accel[[0, 3]], clamped.accel[[0, 3]])
    assert not np.allclose(r2.accel[2], clamped.accel[2])


@pytest.mark.parametrize('edit, message', [
    (lambda d: d.update(format='other/9'), 'format'),
    (lambda d: d['temperature'].update(valid_range={'min': [300.0], 'max': [320.0]}),
     'Kelvin'),
    (lambda d: d['accel']['parameters'].pop('k1'), "missing parameter 'k1'"),
    (lambda d: d['accel']['parameters']['b0'].update(value=[100.0, 0, 0]), 'b0'),
    (lambda d: d['accel'].update(kind='nope'), 'unknown model kind'),
    (lambda d: d['temperature'].update(out_of_range='wrap'), 'out_of_range'),
    (lambda d: d['accel']['parameters']['k1'].update(value=[float('nan'), 0, 0]), 'non-finite'),
])
def test_bad_files_are_refused_with_reason(edit, message):
    d = _cal(np.random.default_rng(3)).to_dict()
    edit(d)
    with pytest.raises(CalibrationError, match=message):
        Calibration.from_dict(d, 'x.yaml')


def test_bad_yaml_and_missing_file(tmp_path):
    with pytest.raises(CalibrationError, match='not valid YAML'):
        Calibration.from_yaml('a: [1, 2', 'x')
    with pytest.raises(CalibrationError, match='does not exist'):
        Calibration.load(tmp_path / 'none.yaml')


def test_wrong_number_of_temperature_columns():
    cal = _cal(np.random.default_rng(4))
    with pytest.raises(CalibrationError, match='expects 1'):
        cal.apply(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 2)))


def test_normal_gravity_reference_values():
    # WGS84 (NIMA TR8350.2): equator 9.7803253359, pole 9.8321849378 m/s^2
    assert normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-9)
    s2 = 0.5  # Somigliana closed form at 45 deg, written out independently
    g45 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2)
    assert normal_gravity(45.0) == pytest.approx(g45, abs=1e-12)
    # free-air gradient about -3.086e-6 m/s^2 per metre
    assert normal_gravity(45.0, 1000.0) - normal_gravity(45.0) == pytest.approx(-3.086e-3,
                                                                                rel=2e-3)
    assert resolve_gravity()[0] == 9.80665
    with pytest.raises(ValueError, match='not g'):
        resolve_gravity(1.0)
