"""Tests of the recording simulator (thermal_imu_calib.sim)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.io.columns import ImuColumns
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.models.whole_unit import WholeUnitGyroModel


def _hold_mask(stamps, hold):
    return (stamps >= hold.stamp_start_ns) & (stamps < hold.stamp_end_ns)


def _moving_mask(stamps, schedule):
    moving = np.ones(stamps.shape, bool)
    for h in schedule:
        moving &= ~((stamps >= h.stamp_start_ns) & (stamps <= h.stamp_end_ns))
    return moving


def _truth(rec):
    parts = list(rec.truth_chunks())
    return (np.concatenate([p.stamp_ns for p in parts]),
            np.concatenate([p.specific_force for p in parts]),
            np.concatenate([p.angular_rate for p in parts]))


@pytest.fixture(scope='module')
def demo():
    rec = sim.simulate('demo', 11)
    return rec, rec.imu()


def test_scenario_names():
    assert set(sim.SCENARIOS) == {'nav-coldstart', 'nav-validation', 'nav-coldstart-short',
                                  'nav-coldstart-uniform',
                                  'nav-validation-short', 'mems-coldstart', 'mems-coldstart-poses',
                                  'mems-validation', 'single-warmup', 'demo', 'demo-validation',
                                  'chamber-cycle', 'lag-warmup',
                                  'hand-held', 'imutk-procedure', 'chamber-2hz'}
    for name, cfg in sim.SCENARIOS.items():
        assert cfg.name == name
    with pytest.raises(KeyError, match='unknown scenario'):
        sim.simulate('no-such-scenario', 0)


def test_accel_forward_matches_field_model():
    rng = np.random.default_rng(0)
    thermal = np.column_stack([rng.normal(0, 1e-3, 3), rng.normal(0, 1e-4, 3),
                               rng.normal(0, 1e-6, 3), rng.normal(0, 0.1, 3),
                               rng.normal(0, 1e-3, 3), rng.normal(0, 1e-5, 3)])
    s = np.eye(3) + np.tril(rng.normal(0, 1e-3, (3, 3)), -1)
    t0, k0, b0 = rng.uniform(20, 30, 3), 1 + rng.normal(0, 1e-3, 3), rng.normal(0, 0.01, 3)
    f = rng.normal(0, 9.8, (500, 3))
    temps = rng.uniform(-10, 60, (500, 3))
    ref = FieldPolynomialModel(t0, thermal, k0, b0, s).forward(f, temps)
    ours = sim.accel_forward(f, temps, t0, k0, b0, s, thermal)
    assert np.max(np.abs(ours - ref)) < 1e-12
    # both against seed 000 eq. (8) written out sample by sample (not from either code path)
    for n in range(0, 500, 97):
        for i in range(3):
            d = temps[n, i] - t0[i]
            dk0, k1, k2, db0, b1, b2 = thermal[i]
            fa = sum(s[i, j] * f[n, j] for j in range(3))
            by_hand = ((b0[i] + db0 + b1 * d + b2 * d * d)
                       + (k0[i] + dk0 + k1 * d + k2 * d * d) * fa)
            assert abs(ours[n, i] - by_hand) < 1e-12 * (1 + abs(by_hand))
    # and it is not trivially the identity
    assert np.max(np.abs(ours - f)) > 0.1

    coeffs = rng.normal(0, 1e-3, (3, 3))
    w = rng.normal(0, 1, (500, 3))
    ref_g = OffsetPolynomialModel(t0, coeffs, sensor='gyro').forward(w, temps)
    assert np.max(np.abs(sim.gyro_forward(w, temps, t0, coeffs) - ref_g)) < 1e-12
    # with scale/misalignment M and g-sensitivity G: the seed 002 model inverts it
    m = np.eye(3) + rng.normal(0, 2e-3, (3, 3))
    g = rng.normal(0, 5e-5, (3, 3))
    om1 = np.linalg.inv(m)
    wu = WholeUnitGyroModel(t0, coeffs, None, np.zeros(3), om1, None, None, -om1 @ g)
    raw = sim.gyro_forward(w, temps, t0, coeffs, m, g, f)
    assert np.max(np.abs(wu.correct(raw, temps, aux={'accel': f}) - w)) < 1e-12
    dev = sim.draw_device('mems', 0)
    assert not dev.gyro_ideal and sim.draw_device('nav', 0).gyro_ideal
    assert 1e-3 <= np.min(np.abs(np.diag(dev.gyro_m) - 1)) and np.max(np.abs(dev.gyro_g)) < 7e-5
    assert isinstance(sim.simulate('demo', 0).truth.gyro, WholeUnitGyroModel)


def test_truth_compensation_recovers_gravity(demo):
    rec, imu = demo
    # what a user has: the published, quantised temperature interpolated at the IMU stamps
    temps = np.column_stack([np.interp(imu.stamp_ns, tc.stamp_ns, tc.temperature)
                             for tc in rec.temperatures.values()])
    comp = rec.truth.apply(imu.accel, imu.gyro, temps)
    raw_err, comp_err = [], []
    _, _, w_true = _truth(rec)
    for h in rec.schedule:
        m = _hold_mask(imu.stamp_ns, h)
        sem = rec.accel_noise_std[0] / np.sqrt(m.sum())
        f = comp.accel[m].mean(0)
        comp_err.append(abs(np.linalg.norm(f) - rec.gravity))
        raw_err.append(abs(np.linalg.norm(imu.accel[m].mean(0)) - rec.gravity))
        # 5 sigma of the hold mean + the temperature quantisation (0.125 degC) effect
        assert comp_err[-1] < 5 * sem + 5e-4, h
        assert np.linalg.norm(f / np.linalg.norm(f) - h.up) < 10 * sem / rec.gravity + 1e-4
        gsem = rec.gyro_noise_std[0] / np.sqrt(m.sum())
        assert np.all(np.abs(comp.gyro[m].mean(0) - w_true[m].mean(0)) < 5 * gsem + 3e-5)
        # raw gyro carries the 0.5-3 mrad/s thermal bias
        assert np.max(np.abs(imu.gyro[m].mean(0) - w_true[m].mean(0))) > 4e-4
    # the uncompensated errors are far larger: the test is not vacuous
    assert np.median(raw_err) > 20 * np.median(comp_err)
    assert not np.any(comp.out_of_range)


def test_holds_stationary_and_pose_changes_move(demo):
    rec, imu = demo
    stamp, f_true, w_true = _truth(rec)
    assert np.array_equal(stamp, imu.stamp_ns)
    assert len(rec.schedule) == 12
    for h in rec.schedule:
        m = _hold_mask(stamp, h)
        assert m.sum() > 0.98 * h.duration * rec.imu_rate
        # stationary: constant specific force = gravity * up, only earth rate
        assert np.allclose(f_true[m], rec.gravity * h.up, atol=1e-9)
        assert np.allclose(np.linalg.norm(w_true[m], axis=1), sim.EARTH_RATE, rtol=1e-9)
        # not an exact face: tilted by the configured few degrees
        face = np.asarray(sim.FACES[h.face], float)
        tilt = np.degrees(np.arccos(np.clip(h.up @ face, -1, 1)))
        assert tilt == pytest.approx(h.tilt_deg, abs=1e-6)
        assert 0.5 <= h.tilt_deg <= 4.0
        assert np.std(imu.gyro[m], axis=0).max() < 1.5 * rec.gyro_noise_std.max()
    moving = _moving_mask(stamp, rec.schedule)
    assert 0.05 < moving.mean() < 0.2
    for a, b in zip(rec.schedule[:-1], rec.schedule[1:]):
        m = (stamp > a.stamp_end_ns) & (stamp < b.stamp_start_ns)
        assert 2.0 <= (b.t_start - a.t_end) <= 3.0
        # the gyro sees the rotation: integrated rate >= angle between the two poses
        angle = np.sum(np.linalg.norm(w_true[m], axis=1)) / rec.imu_rate
        between = np.arccos(np.clip(a.up @ b.up, -1, 1))
        assert angle > 0.99 * between - 0.02
        assert np.abs(imu.gyro[m]).max() > 100 * rec.gyro_noise_std.max()
        # gravity rotates and the hand adds translational acceleration
        assert np.ptp(np.linalg.norm(f_true[m], axis=1)) > 0.02
        # minimum-jerk profile: the rate starts and ends smoothly at zero
        rate = np.linalg.norm(w_true[m], axis=1)
        assert max(rate[0], rate[-1]) < 0.01 * rate.max()
        assert abs(np.argmax(rate) - m.sum() / 2) < 0.05 * m.sum()


def test_deterministic_per_seed_and_chunking():
    a = sim.simulate('demo', 5, repetitions=1)
    b = sim.simulate('demo', 5, repetitions=1)
    ia, ib = a.imu(), b.imu()
    assert np.array_equal(ia.stamp_ns, ib.stamp_ns)
    assert np.array_equal(ia.accel, ib.accel) and np.array_equal(ia.gyro, ib.gyro)
    for topic in a.temperatures:
        assert np.array_equal(a.temperatures[topic].temperature,
                              b.temperatures[topic].temperature)
    small = ImuColumns.concat(list(a.imu_chunks(chunk_size=777)))
    assert np.array_equal(small.accel, ia.accel) and np.array_equal(small.gyro, ia.gyro)
    c = sim.simulate('demo', 6, repetitions=1)
    assert not np.allclose(c.truth.accel.thermal, a.truth.accel.thermal)
    assert c.schedule[0].duration != a.schedule[0].duration
    assert all(isinstance(x, ImuColumns) and x.frame_id == 'imu_link'
               for x in a.imu_chunks(chunk_size=5000))


@pytest.mark.parametrize('pair', [('nav-coldstart', 'nav-validation'),
                                  ('mems-coldstart', 'mems-validation')])
def test_validation_is_same_device(pair):
    cal, val = (sim.simulate(n, 3) for n in pair)
    other = sim.simulate(pair[0], 4)
    for x in ('t0', 'k0', 'b0', 's', 'thermal'):
        assert np.array_equal(getattr(cal.truth.accel, x), getattr(val.truth.accel, x)), x
        assert np.array_equal(getattr(cal.prior.accel, x), getattr(val.prior.accel, x)), x
    assert cal.truth.gyro.to_dict() == val.truth.gyro.to_dict()
    assert not np.allclose(cal.truth.accel.thermal, other.truth.accel.thermal)
    # a different recording: own schedule, start temperature and stamps
    assert [h.duration for h in cal.schedule] != [h.duration for h in val.schedule]
    assert cal.start_ns != val.start_ns
    t_cal = np.concatenate([t.temperature for t in cal.temperatures.values()])
    t_val = np.concatenate([t.temperature for t in val.temperatures.values()])
    assert t_cal.min() != t_val.min()
    # ... covering about the same temperature range
    assert abs(t_cal.min() - t_val.min()) < 1.5 and abs(t_cal.max() - t_val.max()) < 1.5
    # long enough holds for 300-s averages
    assert min(h.duration for h in val.schedule) >= 330.0


def test_nav_scenario_is_seed_000_like():
    rec = sim.simulate('nav-coldstart', 0)
    th = rec.truth.accel.thermal
    assert np.all((th[:, 1] >= -60e-6) & (th[:, 1] <= -40e-6))
    assert np.all(np.abs(th[:, 2]) <= 0.25e-6) and np.all(np.abs(th[:, 0]) < 1e-5)
    assert np.all((np.abs(th[:, 3]) >= 1.5e-3) & (np.abs(th[:, 3]) <= 1.4e-2))
    assert np.all((np.abs(th[:, 4]) >= 1e-6) & (np.abs(th[:, 4]) <= 7.5e-5))
    assert np.all(np.abs(rec.prior.accel.thermal) == 0)
    s = rec.prior.accel.s
    assert np.all(np.triu(s, 1) == 0)
    off = np.abs(s[np.tril_indices(3, -1)])
    assert np.all((off >= 1e-5) & (off <= 1e-4))
    assert np.all(np.abs(rec.prior.accel.k0 - 1) < 2e-3)
    assert np.array_equal(rec.truth.accel.s, s)
    assert rec.accel_noise_std[0] == pytest.approx(5e-5 * 9.80665 * 10)
    assert list(rec.temperatures) == ['/imu/temperature/x', '/imu/temperature/y',
                                      '/imu/temperature/z']
    assert rec.truth.temperature_topics == list(rec.temperatures)
    assert rec.truth.accel_input == [0, 1, 2]
    assert [h.face for h in rec.schedule] == list(sim.SIX_FACES) * 5
    assert 120 * 60 < rec.duration < 170 * 60 and rec.n_samples > 700_000
    for tc in rec.temperatures.values():
        assert np.median(np.diff(tc.stamp_ns)) == pytest.approx(1e8, rel=1e-6)
        q = tc.temperature / 0.01
        assert np.allclose(q, np.round(q), atol=1e-6)
        assert 19.0 < tc.temperature[0] < 21.5 and tc.temperature[-1] > 32.0
        assert np.all(np.diff(tc.temperature[::100]) > -0.05)     # a warm-up


def test_noise_matches_density():
    for name, density in (('demo', 150e-6 * 9.80665), ('nav-coldstart', 5e-5 * 9.80665)):
        rec = sim.simulate(name, 2, repetitions=1, hold_s=(30.0, 30.0))
        imu = rec.imu()
        sigma = density * np.sqrt(rec.imu_rate)
        assert rec.accel_noise_std[0] == pytest.approx(sigma, rel=0.01)
        res_a, res_g = [], []
        for h in rec.schedule:
            m = _hold_mask(imu.stamp_ns, h)
            t = imu.t[m] - imu.t[m].mean()
            for sig, out in ((imu.accel[m], res_a), (imu.gyro[m], res_g)):
                fit = np.polynomial.polynomial.polyfit(t, sig, 2)
                out.append(sig - np.polynomial.polynomial.polyval(t, fit).T)
        std_a = np.concatenate(res_a).std(0)
        std_g = np.concatenate(res_g).std(0)
        assert np.allclose(std_a / rec.accel_noise_std, 1.0, atol=0.03), (name, std_a)
        assert np.allclose(std_g / rec.gyro_noise_std, 1.0, atol=0.03), (name, std_g)


@pytest.mark.parametrize('seed', [1, 2])
def test_chamber_cycle_has_lag_hysteresis(seed):
    rec = sim.simulate('chamber-cycle', seed)
    assert rec.truth.fit['simulation']['temperature_lag_s'] == 300.0
    assert rec.schedule_dict()['temperature']['lag_s'] == 300.0
    assert any('lag' in n for n in rec.truth.notes)
    t = np.arange(0, rec.duration, 10.0)
    st = rec.start_ns + (t * 1e9).astype(np.int64)
    read = rec.temperature_at(st, 'read')[:, 0]
    drive = rec.temperature_at(st, 'drive')[:, 0]
    assert read.min() == pytest.approx(10.0, abs=0.2) and read.max() == pytest.approx(50, abs=0.2)
    slope = np.gradient(read, t)
    heat = (slope > 0.01) & (np.abs(read - 30) < 1)
    cool = (slope < -0.01) & (np.abs(read - 30) < 1)
    assert heat.any() and cool.any()
    # at the same sensor reading the error-driving temperature differs between legs
    assert drive[cool].mean() - drive[heat].mean() > 6.0
    # so the truth polynomial evaluated at the reading leaves opposite residuals
    f = np.tile(rec.gravity * rec.schedule[0].up, (t.size, 1))
    dev = rec.device
    raw = sim.accel_forward(f, np.repeat(drive[:, None], 3, 1), dev.t0, dev.k0, dev.b0, dev.s,
                            dev.thermal)
    res = rec.truth.apply(raw, np.zeros_like(raw), read[:, None]).accel - f
    axis = np.argmax(np.abs(res[heat].mean(0) - res[cool].mean(0)))
    assert np.sign(res[heat, axis].mean()) == -np.sign(res[cool, axis].mean())
    assert abs(res[heat, axis].mean() - res[cool, axis].mean()) > 5e-3


def test_single_pose_scenarios():
    single = sim.simulate('single-warmup', 0)
    lag = sim.simulate('lag-warmup', 0)
    for rec in (single, lag):
        assert len(rec.schedule) == 1 and rec.schedule[0].duration >= 3600.0
        assert len(rec.temperatures) == 1
        tc = rec.temperatures['/imu/temperature']
        assert tc.temperature[-1] - tc.temperature[0] > 12.0
    st = lag.start_ns + np.arange(60, 3600, 60) * 10 ** 9
    read, drive = lag.temperature_at(st, 'read')[:, 0], lag.temperature_at(st, 'drive')[:, 0]
    assert np.all(drive < read) and (read - drive).max() > 1.0
    st = single.start_ns + np.arange(60, 3600, 60) * 10 ** 9
    assert np.array_equal(single.temperature_at(st, 'read'), single.temperature_at(st))


def test_write_scenario_round_trip(tmp_path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores

    rec = sim.simulate('demo', 9, repetitions=1)
    imu = rec.imu()
    for out, storage in ((tmp_path / 'demo.mcap', 'mcap'), (tmp_path / 'bag', 'sqlite3')):
        res = sim.write_scenario(out, 'demo', 9, storage=storage, repetitions=1)
        assert res['summary']['imu_samples'] == len(imu)
        stamps, acc, gyr, temps = [], [], [], {}
        with AnyReader([Path(res['bag'])],
                       default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
            for conn, t, raw in r.messages():
                m = r.deserialize(raw, conn.msgtype)
                st = m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                assert st == t
                if conn.topic == rec.imu_topic:
                    assert m.header.frame_id == 'imu_link'
                    stamps.append(st)
                    acc.append([m.linear_acceleration.x, m.linear_acceleration.y,
                                m.linear_acceleration.z])
                    gyr.append([m.angular_velocity.x, m.angular_velocity.y,
                                m.angular_velocity.z])
                else:
                    temps.setdefault(conn.topic, []).append((st, m.temperature))
        assert np.array_equal(stamps, imu.stamp_ns)
        assert np.array_equal(acc, imu.accel) and np.array_equal(gyr, imu.gyro)
        assert set(temps) == set(rec.temperatures)
        for topic, rows in temps.items():
            assert np.array_equal(np.array(rows)[:, 1], rec.temperatures[topic].temperature)
        truth = Calibration.load(res['truth'])
        prior = Calibration.load(res['prior'])
        assert np.allclose(truth.accel.thermal, rec.truth.accel.thermal, rtol=1e-15)
        assert truth.temperature_topics == list(temps)
        assert np.array_equal(prior.accel.thermal, np.zeros((3, 6)))
        with open(res['schedule']) as f:
            sched = yaml.safe_load(f)
        assert len(sched['holds']) == len(rec.schedule) == 6
        assert sched['holds'][2]['up'] == pytest.approx(rec.schedule[2].up.tolist())
        assert sched['imu_topic'] == rec.imu_topic
