"""Lab mode (seed 002 3.1): simulated chamber + turntable + centrifuge recover all 63."""

import numpy as np
import pytest

from thermal_imu_calib.estimation.lab import (LabError, paper_schedule, read_schedule,
                                              Schedule, Segment, SegmentAccumulator,
                                              simulate_lab_log, solve_lab, write_schedule)
from thermal_imu_calib.models.whole_unit import WholeUnitAccelModel, WholeUnitGyroModel

G = 9.80665
T0 = 35.0


def proxy(temp):
    """Return the gyro drive-mode resonance frequency (Hz) at a temperature (degC)."""
    return 12000.0 - 0.6 * temp


X0 = proxy(T0)


def truth(schedule, seed=3):
    """Return true models in the lab convention (V = 0 in the chamber pose)."""
    rng = np.random.default_rng(seed)
    ct = np.array([rng.normal(0, 0.2, 3), rng.normal(0, 2e-3, 3), rng.normal(0, 3e-5, 3)])
    cw = np.array([rng.normal(0, 0.02, 3), rng.normal(0, 5e-4, 3), rng.normal(0, 1.4e-5, 3)])
    a1 = np.eye(3) + rng.normal(0, 5e-3, (3, 3))
    o1 = np.eye(3) + rng.normal(0, 3e-3, (3, 3))
    c = rng.normal(0, 5e-5, (3, 3))
    a_ch, w_ch = schedule.segments[0].f, schedule.segments[0].w
    accel = WholeUnitAccelModel([T0] * 3, ct, None, a_ch, a1, rng.normal(0, 5e-6, 3),
                                rng.normal(0, 1e-7, 3))
    gyro = WholeUnitGyroModel([X0] * 3, cw, None, w_ch - c @ a_ch, o1,
                              rng.normal(0, 2e-3, 3), rng.normal(0, 1e-4, 3), c,
                              input_unit='Hz')
    return accel, gyro


def run(noise, chunk=50_000, seed=1):
    sched, setpoints = paper_schedule(G, earth_rate=[0.0, 5.2e-5, 5.2e-5])
    accel, gyro = truth(sched)
    t, a, w, x = simulate_lab_log(sched, setpoints, accel, gyro, 100.0, 0.02 * noise,
                                  1e-3 * noise, proxy, seed)
    acc = SegmentAccumulator(sched, 6)
    for i in range(0, len(t), chunk):
        acc.push(t[i:i + chunk], a[i:i + chunk], w[i:i + chunk], x[i:i + chunk])
    res = solve_lab(acc.means(), (0, 1, 2), (3, 4, 5), gyro_input_unit='Hz', t0=T0, x0=X0)
    return res, accel, gyro


def coefficient_errors(res, accel, gyro):
    """Yield (name, error, std) for all 63 seed 002 coefficients."""
    for est, tru, names in ((res.accel, accel, ('ct0', 'ct1', 'ct2', 'A0', 'A1', 'A2', 'A3')),
                            (res.gyro, gyro, ('cw0', 'cw1', 'cw2', 'Omega0', 'Omega1',
                                              'Omega2', 'Omega3', 'C'))):
        pe, pt = est.params(), tru.params()
        for n in names:
            yield n, pe[n].value - pt[n].value, pe[n].std, pt[n].value


def test_noise_free_lab_run_recovers_all_63_exactly():
    res, accel, gyro = run(0.0)
    count = 0
    for name, err, _, val in coefficient_errors(res, accel, gyro):
        count += err.size
        # exact up to the round-off of the turntable stage (rates to 8.7 rad/s, cubic terms)
        assert np.all(np.abs(err) <= 1e-5 * np.abs(val) + 1e-12), (name, err)
    assert count == 63
    assert res.accel.count() == (27, 0) and res.gyro.count() == (36, 0)
    assert res.notes[0].startswith('seed 002 lab mode: 63 coefficients')


def test_noisy_lab_run_is_within_its_stated_uncertainty():
    res, accel, gyro = run(1.0)
    worst = 0.0
    for name, err, std, _ in coefficient_errors(res, accel, gyro):
        z = np.abs(err) / std
        worst = max(worst, float(z.max()))
        assert np.all(z < 5.0), (name, z)
    assert worst > 0.5                      # the stds are not inflated
    # chunking does not matter
    res2, _, _ = run(1.0, chunk=7_777)
    assert np.allclose(res2.gyro.coupling, res.gyro.coupling, rtol=0, atol=1e-15)


def test_lab_stds_are_calibrated_pooled_over_seeds():
    # |z| < 5 and max |z| > 0.5 pass with stds inflated 4-5x; the pooled z-RMS over the
    # 63 coefficients of 3 independent noisy runs must be near 1
    z = np.concatenate([np.ravel(err / std) for seed in (2, 3, 4)
                        for _, err, std, _ in coefficient_errors(*run(1.0, seed=seed))])
    z_rms = float(np.sqrt(np.mean(z ** 2)))
    print(f'lab coefficients: pooled z-RMS {z_rms:.2f} over {z.size}')
    assert 0.6 <= z_rms <= 1.5, z_rms


def test_schedule_files_round_trip_and_bad_input_is_refused(tmp_path):
    sched, _ = paper_schedule(G)
    for name in ('s.csv', 's.yaml'):
        path = write_schedule(sched, str(tmp_path / name))
        back = read_schedule(path)
        assert len(back.segments) == len(sched.segments)
        a, b = back.segments[17], sched.segments[17]
        assert a.stage == b.stage and a.group == b.group and np.allclose(a.w, b.w)
    bad = tmp_path / 'bad.csv'
    bad.write_text('stage,t_start,t_end,f_x,f_y,f_z,w_x,w_y,w_z\n'
                   'chamber,0,10,0,0,1,0,0,0\nturntable,10,20,0,0,9.8,0,0,400\n')
    with pytest.raises(LabError, match='not in m/s\\^2 and rad/s'):
        read_schedule(str(bad))
    only = Schedule([Segment('chamber', 0.0, 10.0, 0, np.array([0, 0, G]), np.zeros(3))])
    acc = SegmentAccumulator(only, 1)
    acc.push(np.arange(1000) * 0.01, np.zeros((1000, 3)), np.zeros((1000, 3)),
             np.full((1000, 1), 20.0))
    with pytest.raises(LabError, match='no turntable segments'):
        solve_lab(acc.means(), (0, 0, 0), (0, 0, 0))


def test_lab_log_with_schedule_file_end_to_end(tmp_path):
    from thermal_imu_calib.estimation.lab import accumulate_log
    from thermal_imu_calib.io.bag_writer import write_columns
    from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
    sched, setpoints = paper_schedule(G, temps=tuple(range(0, 75, 10)),
                                      rates_deg=tuple(range(0, 520, 50)),
                                      centrifuge_g=(0, 10, 20, 30), segment_s=3.0)
    accel, gyro = truth(sched)
    t, a, w, x = simulate_lab_log(sched, setpoints, accel, gyro, 100.0, proxy=proxy)
    t0_ns = 1_735_689_600 * 10 ** 9
    stamps = t0_ns + np.round(t * 1e9).astype(np.int64)
    topics = ['/lab/t_x', '/lab/t_y', '/lab/t_z', '/lab/f_x', '/lab/f_y', '/lab/f_z']
    temps = {tp: TemperatureColumns(stamps[::10], x[::10, j]) for j, tp in enumerate(topics)}
    log = str(tmp_path / 'lab.mcap')
    write_columns(log, '/imu/data_raw', ImuColumns(stamps, a, w), temps)
    path = write_schedule(sched, str(tmp_path / 'lab.yaml'))
    means, used = accumulate_log(log, read_schedule(path), temperature_topics=topics)
    assert used == topics and means.empty == 0
    res = solve_lab(means, (0, 1, 2), (3, 4, 5), gyro_input_unit='Hz', t0=T0, x0=X0)
    for name, err, _, val in coefficient_errors(res, accel, gyro):
        assert np.all(np.abs(err) <= 1e-4 * np.abs(val) + 1e-9), (name, err)
