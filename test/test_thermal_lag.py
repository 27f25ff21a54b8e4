"""Thermal lag: the lag filter, its file section and streaming, tau estimation, legs."""

import dataclasses

import numpy as np
import pytest
import yaml

from _thermal_data import make_windows, sim_windows
from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration, CalibrationError, TemperatureInput
from thermal_imu_calib.estimation.thermal_lag import (estimate_tau, legs, rate_fit,
                                                      tau_or_none)
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.app.compensate import compensate_log
from thermal_imu_calib.thermal_input import (CalibrationStream, lag_filter, lag_windows,
                                             ThermalFilter)


@pytest.fixture(scope='module')
def chamber():
    return sim_windows(sim.simulate('chamber-cycle', 0))


def _cal(tau=None):
    gyro = OffsetPolynomialModel([30.0] * 3, [[1e-3, -2e-3, 5e-4], [2e-4, 1e-4, -3e-4]],
                                 sensor='gyro')
    accel = OffsetPolynomialModel([30.0] * 3, [[0, 0, 0], [2e-3, -1e-3, 4e-3],
                                               [3e-5, 0, -2e-5]], include_constant=False)
    return Calibration(accel=accel, gyro=gyro, inputs=[TemperatureInput('t0')],
                       valid_range=np.array([[0.0, 80.0]]),
                       temperature_filter=None if tau is None else ThermalFilter([tau]))


def test_lag_filter_matches_simulator_and_chunking():
    rng = np.random.default_rng(1)
    dt = 0.25
    t = np.arange(0, 20000, dt)
    u = 20 + 10 * np.sin(t / 900) + rng.normal(0, 0.1, t.size)
    for tau in (0.1, 5.0, 300.0, 5000.0):
        ref = sim.first_order_lag(u, dt, tau)
        y, _ = lag_filter(t, u, tau)
        assert np.max(np.abs(y - ref)) < 1e-9
        parts, state = [], None
        for i in range(0, len(t), 7777):
            yi, state = lag_filter(t[i:i + 7777], u[i:i + 7777], tau, state)
            parts.append(yi)
        assert np.max(np.abs(np.concatenate(parts) - y)) < 1e-9
    # irregular, sparse samples of a smooth signal land on the dense result
    ts = np.sort(rng.uniform(0, 10000, 3000))
    ys, _ = lag_filter(ts, 20 + 10 * np.sin(ts / 900), 300.0)
    td = np.arange(0, 10000, 0.01)
    yd, _ = lag_filter(td, 20 + 10 * np.sin(td / 900), 300.0)
    late = ts > ts[0] + 3000   # the sparse run started later in equilibrium
    assert np.max(np.abs(ys - np.interp(ts, td, yd))[late]) < 2e-4
    # a step: after one time constant 63.2 % of the way
    t = np.arange(0, 1000, 0.01)
    y, _ = lag_filter(t, np.where(t > 0, 1.0, 0.0), 100.0)
    assert y[np.searchsorted(t, 100.0)] == pytest.approx(1 - np.exp(-1), abs=1e-3)


def test_window_lag_equals_sample_lag():
    """Window-level lagged temperature = mean of the IMU-rate lag (within 1 mdegC).

    Both start in equilibrium, the samples at t = 0 and the windows at the first window's
    mid time, so they agree once that start has decayed (5 time constants).
    """
    t = np.arange(0, 3600, 0.01)
    temp = 21 + 17 * (1 - np.exp(-t / 600))
    y, _ = lag_filter(t, temp, 240.0)
    edges = np.arange(0, 3600, 5.0)
    idx = np.searchsorted(t, edges)
    means = np.add.reduceat(temp, idx) / np.diff(np.r_[idx, len(t)])
    lag_means = np.add.reduceat(y, idx) / np.diff(np.r_[idx, len(t)])
    w = lag_windows(edges, edges + 5.0, means[:, None], [240.0])[:, 0]
    late = edges > 5 * 240.0
    assert np.max(np.abs(w - lag_means)[late]) < 1e-3
    assert np.max(np.abs(w - lag_means)) < 0.071  # the start: 2.5 s of a 0.03 degC/s ramp


def test_filter_file_section_and_errors():
    cal = _cal(250.0)
    back = Calibration.from_yaml(cal.to_yaml())
    np.testing.assert_array_equal(back.temperature_filter.tau_s, [250.0])
    sec = yaml.safe_load(cal.to_yaml())['temperature']['filter']
    assert (sec['kind'], sec['tau_s'], sec['unit']) == ('lag', [250.0], 's')
    assert back.id == cal.id
    assert Calibration.from_yaml(_cal().to_yaml()).temperature_filter is None
    d = cal.to_dict()
    d['temperature']['filter']['tau_s'] = [1.0, 2.0]
    with pytest.raises(CalibrationError, match='2 tau_s for 1 temperature inputs'):
        Calibration.from_dict(d)
    d['temperature']['filter']['tau_s'] = [-3.0]
    with pytest.raises(CalibrationError, match='must be finite, in 0..86400 s'):
        Calibration.from_dict(d)
    d['temperature']['filter'] = {'kind': 'lag', 'tau_s': [3.0], 'unit': 'min'}
    with pytest.raises(CalibrationError, match='unit .min. must be s'):
        Calibration.from_dict(d)
    with pytest.raises(ValueError, match='NaN'):
        ThermalFilter([10.0]).stream().push(np.arange(3.0), np.array([[1.0], [np.nan], [2]]))
    # the restart spread: optional (files before it load without it), per sensor, >= 0
    assert back.temperature_filter.restart_spread is None
    cal.temperature_filter = dataclasses.replace(cal.temperature_filter,
                                                 restart_spread={'gyro': [1e-4, 2e-4, 3e-4]})
    sec = yaml.safe_load(cal.to_yaml())['temperature']['filter']['restart_spread']
    assert sec['gyro'] == {'value': [1e-4, 2e-4, 3e-4], 'unit': 'rad/s'} and 'accel' not in sec
    back = Calibration.from_yaml(cal.to_yaml())
    np.testing.assert_array_equal(back.temperature_filter.restart_spread['gyro'],
                                  [1e-4, 2e-4, 3e-4])
    assert back.id == cal.id != _cal(250.0).id
    d = cal.to_dict()
    d['temperature']['filter']['restart_spread']['gyro']['value'] = [1e-4, -2e-4, 3e-4]
    with pytest.raises(CalibrationError, match='restart_spread.gyro.value .* negative'):
        Calibration.from_dict(d)
    d['temperature']['filter']['restart_spread'] = {'gyro': [1e-4, 2e-4]}
    with pytest.raises(CalibrationError, match='restart_spread.gyro .* expected 3'):
        Calibration.from_dict(d)


def test_stream_apply_chunks_and_equilibrium():
    cal = _cal(300.0)
    t = np.arange(0, 2000, 0.05)
    temp = (20 + 0.02 * t)[:, None]
    rng = np.random.default_rng(2)
    acc = rng.normal(0, 1, (len(t), 3))
    gyr = rng.normal(0, 1, (len(t), 3))
    one = cal.stream().apply(t, acc, gyr, temp)
    st = cal.stream()
    parts = [st.apply(t[i:i + 999], acc[i:i + 999], gyr[i:i + 999], temp[i:i + 999])
             for i in range(0, len(t), 999)]
    np.testing.assert_allclose(np.concatenate([p.accel for p in parts]), one.accel,
                               atol=1e-12)
    # the lagged input trails the reading by tau * rate at steady ramp: 300 s * 0.02 degC/s
    lagged = CalibrationStream(cal).model_temperatures(t, temp)
    assert temp[-1, 0] - lagged[-1, 0] == pytest.approx(6.0, abs=0.01)
    expect = cal.apply(acc, gyr, lagged)
    np.testing.assert_allclose(one.gyro, expect.gyro, atol=1e-12)
    # a restart spread widens the restarted stream's 1-sigma by spread * exp(-age / tau)
    assert one.gyro_std is None
    cal.temperature_filter = dataclasses.replace(cal.temperature_filter,
                                                 restart_spread={'gyro': [1e-3, 2e-3, 0.0]})
    wide = cal.stream().apply(t, acc, gyr, temp)
    np.testing.assert_allclose(wide.gyro_std, np.exp(-t / 300.0)[:, None] * [1e-3, 2e-3, 0.0],
                               rtol=1e-12, atol=0)
    np.testing.assert_array_equal(wide.gyro, one.gyro)
    assert wide.accel_std is None
    # without a filter the stream is apply itself; apply alone = thermal equilibrium
    plain = _cal()
    np.testing.assert_array_equal(plain.stream().apply(t, acc, gyr, temp).accel,
                                  plain.apply(acc, gyr, temp).accel)
    assert not np.allclose(cal.apply(acc, gyr, temp).accel, one.accel)


def test_compensate_log_carries_the_lag_state(tmp_path):
    """The offline path streams through one filter state: equals the one-shot result."""
    bag = str(tmp_path / 'warm.mcap')
    sim.write_scenario(bag, 'lag-warmup', 4, hold_s=(300.0, 300.0), tau_s=120.0)
    rec = sim.simulate('lag-warmup', 4, hold_s=(300.0, 300.0), tau_s=120.0)
    cal = _cal(150.0)
    cal.inputs = [TemperatureInput('t0', '/imu/temperature')]
    out = str(tmp_path / 'out.mcap')
    st = compensate_log(bag, out, cal, chunk_size=4000, progress=False)
    assert st['imu_out'] == rec.n_samples
    imu = rec.imu()
    tc = rec.temperatures['/imu/temperature']
    temp = np.interp(imu.stamp_ns.astype(float), tc.stamp_ns.astype(float), tc.temperature)
    expect = cal.stream().apply(imu.t, imu.accel, imu.gyro, temp[:, None])
    with open_log(out) as reader:
        got = [c.imu for c in reader.stream('/imu/data_compensated', [], 10 ** 6)]
    acc = np.concatenate([g.accel for g in got])
    stamps = np.concatenate([g.stamp_ns for g in got])
    order = np.argsort(stamps)
    np.testing.assert_array_equal(stamps[order], imu.stamp_ns)
    np.testing.assert_allclose(acc[order], expect.accel, atol=1e-9)


def test_legs_of_a_chamber_cycle(chamber):
    ids, info = legs(chamber)
    assert [i['direction'] for i in info] == ['heating', 'cooling', 'heating', 'cooling']
    assert all(i['t_max'] - i['t_min'] > 39 for i in info)
    assert len(np.unique(ids)) == 4 and np.all(np.diff(ids[np.argsort(chamber.t0)]) >= 0)


def test_tau_recovered_from_chamber_and_warmup(chamber):
    est = estimate_tau(chamber, [0, 0, 0], [0, 0, 0])
    assert est.groups == 'temperature legs'
    assert est.tau_s[0] == pytest.approx(300.0, rel=0.1)      # simulated: 300 s
    assert est.improvement > 0.8
    warm = sim_windows(sim.simulate('lag-warmup', 1))
    est = estimate_tau(warm, [0, 0, 0], [0, 0, 0])
    assert est.tau_s[0] == pytest.approx(240.0, rel=0.15)     # simulated: 240 s
    assert tau_or_none(est, 0.1) is not None
    none = sim_windows(sim.simulate('single-warmup', 1))
    est = estimate_tau(none, [0, 0, 0], [0, 0, 0])
    assert est.improvement < 0.05 and tau_or_none(est, 0.1) is None


def test_rate_term_cross_check(chamber):
    """Temperature + rate explains part of the hysteresis; c = -tau p'(T) to first order."""
    r = rate_fit(chamber, chamber.temp[:, [0, 0, 0]], 'accel')
    assert all(w < 0.8 * wo for w, wo in zip(r['heldout_with_rate'], r['heldout_no_rate']))
    # synthetic: offset = a * T_lag exactly; the rate coefficient is -a * tau
    t = np.arange(0, 7200, 5.0)
    temp = 30 + 10 * np.sin(2 * np.pi * t / 3600)
    lagged = lag_windows(t, t + 5.0, temp[:, None], [100.0])[:, 0]
    acc = np.outer(lagged, [0.01, 0.0, -0.02])
    w = make_windows(t, temp, acc, np.zeros_like(acc), sigma_a=1e-6)
    c = rate_fit(w, w.temp[:, [0, 0, 0]], 'accel', order=1)['rate_coefficient']
    assert c[0] == pytest.approx(-0.01 * 100.0, rel=0.1)   # first order in omega tau
    assert c[2] == pytest.approx(0.02 * 100.0, rel=0.1)
