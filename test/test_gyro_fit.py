"""Gyroscope calibration without a turntable: integration, motion collector, static, rotations."""

import numpy as np
from scipy.spatial.transform import Rotation

from thermal_imu_calib.collection.motion import collect_motion, MotionCollector
from thermal_imu_calib.estimation.gyro_fit import fit_gyro
from thermal_imu_calib.estimation.gyro_static import EARTH_RATE, fit_gyro_static
from thermal_imu_calib.rotations import integrate_batch, integrate_rotation, quat_to_rotvec
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.collection.stationary import DetectorConfig
from thermal_imu_calib.io.columns import AlignedChunk, ImuColumns
from thermal_imu_calib.models.whole_unit import WholeUnitAccelModel

G = 9.80665
DET = DetectorConfig(block_s=0.2, window_s=1.0, min_hold_s=3.0, guard_s=0.3)


def stream(rng, m_gyro, bias, g_sens, n_poses=14, hold_s=8.0, move_s=2.0, rate=100.0,
           sigma_a=0.01, sigma_g=5e-4):
    """Return (t, accel, gyro) of hand-free pose changes between random orientations.

    Each pose change is a minimum-jerk rotation about one body axis (exact kinematics);
    raw gyro = M w + bias + G f + noise, raw accel = f + noise.
    """
    rots = [Rotation.identity()]
    for _ in range(n_poses - 1):
        rots.append(Rotation.from_rotvec(rng.normal(0, 1.2, 3)) * rots[-1])
    ts, fs, ws = [], [], []
    t = 0.0
    dt = 1.0 / rate
    for i, r in enumerate(rots):
        n = int(hold_s * rate)
        tt = t + np.arange(n) * dt
        f = r.inv().apply([0, 0, G])                 # specific force in the body frame
        ts.append(tt)
        fs.append(np.tile(f, (n, 1)))
        ws.append(np.zeros((n, 3)))
        t += n * dt
        if i + 1 < len(rots):
            rv = (r.inv() * rots[i + 1]).as_rotvec()  # body-frame rotation to the next pose
            n = int(move_s * rate)
            tau = np.arange(n) / n
            s = tau ** 3 * (10 - 15 * tau + 6 * tau ** 2)
            sdot = 30 * tau ** 2 * (1 - tau) ** 2 / move_s
            rr = r * Rotation.from_rotvec(np.outer(s, rv))
            ts.append(t + np.arange(n) * dt)
            fs.append(rr.inv().apply([0, 0, G]))
            ws.append(np.outer(sdot, rv))
            t += n * dt
    t, f, w = np.concatenate(ts), np.concatenate(fs), np.concatenate(ws)
    gyro = w @ m_gyro.T + bias + f @ g_sens.T + rng.normal(0, sigma_g, w.shape)
    accel = f + rng.normal(0, sigma_a, f.shape)
    return t, accel, gyro


def chunks(t, accel, gyro, size):
    """Yield AlignedChunk's without temperature."""
    for i in range(0, len(t), size):
        sl = slice(i, i + size)
        imu = ImuColumns((t[sl] * 1e9).astype(np.int64), accel[sl], gyro[sl])
        yield AlignedChunk(imu, np.zeros((len(imu), 0)), np.zeros((len(imu), 0)))


def truth(rng):
    """Return (M = raw-per-true scale/misalignment, bias, G) of a MEMS gyro."""
    m = np.eye(3) + np.diag(rng.uniform(-4e-3, 4e-3, 3))
    off = rng.uniform(-1.5e-3, 1.5e-3, (3, 3))
    np.fill_diagonal(off, 0.0)
    return m + off, rng.normal(0, 3e-3, 3), rng.uniform(-7e-5, 7e-5, (3, 3))


def test_quaternion_integration_matches_scipy():
    rng = np.random.default_rng(0)
    t = np.arange(400) * 0.005
    w = np.column_stack([np.sin(3 * t), np.cos(2 * t), 0.5 + t]) * 2.0
    inc = 0.5 * (w[1:] + w[:-1]) * 0.005
    ref = Rotation.identity()
    for v in inc:
        ref = ref * Rotation.from_rotvec(v)
    ours = quat_to_rotvec(integrate_batch(inc[None]))[0]
    assert np.allclose(Rotation.from_rotvec(ours).as_matrix(), ref.as_matrix(), atol=1e-12)
    # a constant rate about a fixed axis integrates exactly
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    assert np.allclose(integrate_rotation(t, np.tile(1.5 * axis, (len(t), 1))),
                       1.5 * axis * t[-1], atol=1e-12)


def test_collector_keeps_only_pose_changes_and_does_not_depend_on_chunking():
    rng = np.random.default_rng(1)
    m, b, g = truth(rng)
    t, a, w = stream(rng, m, b, g, n_poses=8, hold_s=30.0)
    win1, tr1, col = collect_motion(chunks(t, a, w, 997), DET, 0)
    win2, tr2, _ = collect_motion(chunks(t, a, w, 50_000), DET, 0)
    assert len(np.unique(win1.hold)) == 8 and len(tr1) == 7 == len(tr2)
    for x, y in zip(tr1, tr2):
        assert (x.hold_from, x.hold_to) == (y.hold_from, y.hold_to)
        assert np.array_equal(x.t, y.t) and np.array_equal(x.gyro, y.gyro)
    for x in tr1:
        # from the end of one hold to the start of the next: motion (2 s) plus guards only
        assert 2.0 <= x.duration < 2.0 + 2 * (DET.guard_s + 2 * DET.block_s) + 0.6
        lo = win1.t1[win1.hold == x.hold_from].max()
        hi = win1.t0[win1.hold == x.hold_to].min()
        assert x.t[0] == lo or abs(x.t[0] - lo) < 0.011
        assert abs(x.t[-1] - hi) < 0.011
    # memory: the kept transitions, not the 30 s holds
    assert col.memory_bytes() < 10 * 7 * 3.0 * 100 * 64


def test_collector_memory_stays_bounded_on_long_holds():
    rng = np.random.default_rng(2)
    m, b, g = truth(rng)
    t, a, w = stream(rng, m, b, g, n_poses=3, hold_s=600.0, move_s=2.0)
    col = MotionCollector(DET, 0, max_transition_s=20.0)
    peak = 0
    for ch in chunks(t, a, w, 500):
        col.update(ch.imu.t, ch.imu.accel, ch.imu.gyro)
        peak = max(peak, col.memory_bytes())
    col.finish()
    assert len(col.transitions) == 2
    # ring (lookback) + tape (frozen after the next still start) + 2 transitions, ~100 Hz
    bound = (col.lookback_s + 2 * 5.0 + 20.0) * 100 * 64 + 500 * 64
    assert peak < bound, (peak, bound)


def synth_static(rng, beta, c1, g_sens, latitude, n_holds=24, per=6, sigma=2e-6):
    """Stationary gyro windows: bias polynomial + G a + earth rate with random headings."""
    rows = []
    lat = np.radians(latitude)
    temps = 22 + 15 * (1 - np.exp(-np.linspace(0, 3.5, n_holds * per)))
    k = 0
    for h in range(n_holds):
        r = Rotation.from_rotvec(rng.normal(0, 1.5, 3))
        up = r.inv().apply([0, 0, 1.0])
        w_e = r.inv().apply(EARTH_RATE * np.array([0, np.cos(lat), np.sin(lat)]))
        for _ in range(per):
            y = beta + c1 * (temps[k] - 30.0) + G * up @ g_sens.T + w_e + \
                rng.normal(0, sigma, 3)
            rows.append((h, y, G * up, temps[k]))
            k += 1
    m = len(rows)
    w = Windows(hold=np.array([r[0] for r in rows]), t0=np.arange(m) * 5.0,
                t1=np.arange(m) * 5.0 + 5, n=np.full(m, 500),
                accel=np.array([r[2] for r in rows]), gyro=np.array([r[1] for r in rows]),
                accel_var=np.full((m, 3), 1e-4), gyro_var=np.full((m, 3), sigma ** 2 * 500),
                temp=np.array([[r[3]] for r in rows]), temp_rate=np.zeros((m, 1)))
    return w


def test_static_fit_removes_earth_rate_and_finds_bias_polynomial_and_g_sensitivity():
    rng = np.random.default_rng(3)
    beta, c1 = rng.normal(0, 3e-3, 3), rng.normal(0, 1e-4, 3)
    g_sens = rng.uniform(-7e-5, 7e-5, (3, 3))
    w = synth_static(rng, beta, c1, g_sens, 45.0)
    x = w.temp[:, [0, 0, 0]]
    st = fit_gyro_static(w, x, w.accel, np.full(3, 30.0), latitude=45.0, order=1)
    assert np.max(np.abs(st.beta - beta)) < 2e-6
    assert np.max(np.abs(st.offset[1] - c1)) < 3e-7
    assert np.max(np.abs(st.g - g_sens)) < 5e-7
    assert st.residual_rms < 4e-6 and any('latitude 45' in n for n in st.notes)
    # without latitude the vertical earth rate ends up in the diagonal of G (documented)
    st2 = fit_gyro_static(w, x, w.accel, np.full(3, 30.0), latitude=None, order=1)
    iso = EARTH_RATE * np.sin(np.radians(45.0)) / G
    assert np.allclose(np.diag(st2.g - g_sens), iso, atol=1e-6)
    assert 0.6 < st2.horizontal_fraction < 0.8                       # cos 45 deg
    assert any('no latitude' in n for n in st2.notes)


def test_scale_and_misalignment_from_pose_changes():
    rng = np.random.default_rng(4)
    m, b, g = truth(rng)
    t, a, w = stream(rng, m, b, g, n_poses=16)
    win, tr, _ = collect_motion(chunks(t, a, w, 20_000), DET, 0)
    accel = WholeUnitAccelModel(np.zeros(3), np.zeros((1, 3)))       # a perfect accelerometer
    fit = fit_gyro(win, None, win.accel, np.zeros(3), transitions=tr, accel_model=accel,
                   order=0)
    gm = fit.model
    assert fit.rotation.used == 15
    assert np.max(np.abs(gm.m1 - np.linalg.inv(m))) < 3e-4
    assert np.all(gm.estimated_mask('Omega1'))
    assert not np.any(gm.estimated_mask('Omega3'))
    assert np.max(np.abs(gm.offset[0] - b)) < 5e-5                    # raw-domain bias
    assert fit.stats['rotation_direction_error_deg']['after_rms'] < 0.2 * \
        fit.stats['rotation_direction_error_deg']['before_rms']
    # compensated rates integrate to the true rotations
    n = len(t)
    corr = gm.correct(w, np.zeros((n, 3)), aux={'accel': a})
    raw_err = np.abs(w - (w - b - a @ g.T) @ np.linalg.inv(m).T).max()
    true_w = (w - b - a @ g.T) @ np.linalg.inv(m).T
    assert np.abs(corr - true_w).max() < 0.02 * raw_err + 2e-3


def test_rotations_about_one_axis_leave_the_other_columns_at_the_prior():
    rng = np.random.default_rng(5)
    m, b, g = truth(rng)
    # only rotations about the body z axis, with z vertical: gravity never moves
    ts, acc, gyr = [], [], []
    t0 = 0.0
    for i in range(8):
        for phase, (dur, rate) in enumerate(((8.0, 0.0), (2.0, 1.5 * (-1) ** i))):
            tt = t0 + np.arange(int(dur * 100)) / 100
            wz = np.zeros((len(tt), 3))
            wz[:, 2] = rate * np.sin(np.pi * (tt - t0) / dur) ** 2 if rate else 0.0
            ts.append(tt)
            acc.append(np.tile([0, 0, G], (len(tt), 1)))
            gyr.append(wz)
            t0 = tt[-1] + 0.01
    t, a, w = np.concatenate(ts), np.concatenate(acc), np.concatenate(gyr)
    w = w @ m.T + b + rng.normal(0, 5e-4, w.shape)
    a = a + rng.normal(0, 0.01, a.shape)
    win, tr, _ = collect_motion(chunks(t, a, w, 20_000), DET, 0)
    accel = WholeUnitAccelModel(np.zeros(3), np.zeros((1, 3)))
    fit = fit_gyro(win, None, win.accel, np.zeros(3), transitions=tr, accel_model=accel,
                   order=0)
    est = fit.model.estimated_mask('Omega1')
    # the z scale is invisible to gravity matching (rotation about the vertical) and the x, y
    # columns are never excited; the z misalignment tilts gravity, so it is determined
    assert not est[2, 2] and not np.any(est[:, :2])
    assert est[0, 2] and est[1, 2]
    assert fit.model.m1[2, 2] == 1.0 and np.all(fit.model.m1[:, :2] == np.eye(3)[:, :2])
    assert np.max(np.abs(fit.model.m1[:2, 2] - np.linalg.inv(m)[:2, 2])) < 2e-4
    assert 'Omega1' in fit.model.fixed


def test_gyro_thermal_input_can_be_a_separate_proxy_signal():
    from thermal_imu_calib.calibration import TemperatureInput
    from thermal_imu_calib.estimation.calibrate import CalibrateOptions, calibrate_windows
    from test_whole_unit import directions, synth_windows, truth_accel
    rng = np.random.default_rng(6)
    w = synth_windows(rng, truth_accel(rng), directions(rng, tilted=4), reps=3)
    # a second input: the gyro's own thermal proxy, lagging the die temperature
    proxy = 25.0 + 0.7 * (w.temp[:, 0] - 22.0) + 0.3 * np.sin(np.arange(len(w)) / 9.0)
    w.temp = np.column_stack([w.temp[:, 0], proxy])
    w.temp_rate = np.zeros((len(w), 2))
    beta, c1 = np.array([2e-3, -1e-3, 5e-4]), np.array([1e-4, -2e-4, 5e-5])
    x0 = np.round((proxy.min() + proxy.max()) / 2, 2)
    w.gyro = beta + np.outer(proxy - x0, c1) + rng.normal(0, 1e-6, (len(w), 3))
    w.gyro_var = np.full((len(w), 3), 1e-12 * 1000)
    opts = CalibrateOptions(model='whole_unit', order=1,
                            inputs=[TemperatureInput('die', '/imu/temperature'),
                                    TemperatureInput('gyro_proxy', '/imu/gyro_temperature')],
                            accel_input=[0, 0, 0], gyro_input=[1, 1, 1])
    cal = calibrate_windows(w, opts).calibration      # no earth rate in these data
    assert cal.gyro_input == [1, 1, 1] and cal.accel_input == [0, 0, 0]
    assert np.allclose(cal.gyro.t0, x0)
    assert np.max(np.abs(cal.gyro.offset[1] - c1)) < 2e-6
    assert np.max(np.abs(cal.gyro.offset[0] - beta)) < 1e-5
    res = cal.apply(w.accel, w.gyro, w.temp)
    assert np.max(np.abs(res.gyro)) < 2e-5
