"""Gyro ageing told apart from a seasonal temperature; the vertical earth rate of one pose.

Synthetic windows with a known truth (rad/s, s, degC): a gyro bias that is a cubic in
temperature plus a linear ageing in time, while the temperature rises with the season, so
a fit in temperature alone takes part of the ageing for a temperature slope.
"""

import json

import numpy as np
import pytest

from _level_holds import earth_rate
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.estimation.gyro_static import EARTH_RATE
from thermal_imu_calib.lifelong import ageing
from thermal_imu_calib.lifelong.store import HoldStore, StoreConfig
from thermal_imu_calib.calibration import TemperatureInput

DAY = 86400.0
RATE = np.array([2e-5, -1e-5, 0.5e-5])          # rad/s per day


def bias_of(temp):
    """True gyro bias (n, 3) at temperatures (n,) degC, without ageing."""
    d = temp - 20.0
    return np.stack([1e-3 + 2e-5 * d + 3e-7 * d ** 2, -2e-3 - 1e-5 * d,
                     5e-4 + 4e-7 * d ** 3 / 10], 1)


def season(days=14.0, holds=300, seed=0, lat_deg=None):
    """Return (windows, mid times s, now s): level holds, 4 windows each, heading random."""
    rng = np.random.default_rng(seed)
    t_hold = np.sort(rng.uniform(0.0, days * DAY, holds))
    rows = []
    for h, th in enumerate(t_hold):
        heading = rng.uniform(0, 2 * np.pi)
        w_true = earth_rate(heading, lat_deg)
        for j in range(4):
            t = th + 60.0 * j
            temp = 12.0 + 1.0 * t / DAY + 6.0 * np.sin(2 * np.pi * t / DAY) \
                + rng.normal(0, 0.3)
            g = bias_of(np.array([temp]))[0] + RATE * t / DAY + w_true \
                + rng.normal(0, 3e-6, 3)
            rows.append((h, t - 30.0, t + 30.0, temp, g))
    hold = np.array([r[0] for r in rows])
    t0, t1 = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
    temp = np.array([[r[3]] for r in rows])
    gyro = np.array([r[4] for r in rows])
    m = len(rows)
    accel = np.tile([0.0, 0.0, 9.80665], (m, 1)) + rng.normal(0, 1e-3, (m, 3))
    w = Windows(hold, t0, t1, np.full(m, 600), accel, gyro, np.full((m, 3), 1e-6),
                np.full((m, 3), 1e-8), temp, np.zeros((m, 1)))
    return w, 0.5 * (t0 + t1), float(t1.max())


def cubic_bias_at(windows, temp_at):
    """Least-squares cubic in temperature per axis, evaluated at ``temp_at`` (3,)."""
    x = windows.temp[:, 0]
    a = np.stack([np.ones_like(x), x, x ** 2, x ** 3], 1)
    coef = np.linalg.lstsq(a, windows.gyro, rcond=None)[0]
    return np.array([1.0, temp_at, temp_at ** 2, temp_at ** 3]) @ coef


def test_trend_finds_the_ageing_under_a_seasonal_temperature():
    win, times, now = season()
    found = ageing.trend(win, times, now)
    assert found.holds == 300 and found.span_days == pytest.approx(14.0, abs=0.2)
    assert np.all(found.resolved)
    assert np.all(np.abs(found.rate - RATE) < 3 * found.std + 1e-7), (found.rate, found.std)
    assert 'mdeg/s per day over 300 holds' in found.text()
    # the bias today at 20 degC: a fit in temperature alone is off by the aliased ageing,
    # the detrended fit is not
    truth = bias_of(np.array([20.0]))[0] + RATE * now / DAY
    plain = cubic_bias_at(win, 20.0)
    moved = cubic_bias_at(ageing.detrended(win, times, now, found), 20.0)
    assert np.linalg.norm(moved - truth) < 0.2 * np.linalg.norm(plain - truth), \
        (moved - truth, plain - truth)


def test_no_trend_without_ageing_or_with_few_holds():
    win, times, now = season(holds=300, seed=1)
    flat = Windows(**{**win.__dict__,
                      'gyro': win.gyro - RATE[None, :] * times[:, None] / DAY})
    found = ageing.trend(flat, times, now)
    # no ageing: resolved on at most one axis by chance at 2 sigma (here none)
    assert found.resolved.sum() == 0, (found.rate, found.std)
    assert ageing.detrended(flat, times, now, found).gyro == pytest.approx(flat.gyro)
    few = win.hold < ageing.MIN_HOLDS - 1
    assert ageing.trend(win.select(few), times[few], now) is None
    short = times < ageing.MIN_SPAN_DAYS * 0.9 * DAY      # many holds, too short a span
    assert ageing.trend(win.select(short), times[short], now) is None


def test_store_keeps_the_mean_time_of_compacted_bins(tmp_path):
    win, times, now = season(days=4.0, holds=60)
    st = HoldStore(str(tmp_path / 's'), 1, StoreConfig(max_recent_holds=20,
                                                       max_recent_windows=400))
    for h in win.hold_ids:
        st.add(win.select(win.hold == h))
    assert len(st.bins)
    w, t = st.fit_windows(now)
    assert len(t) == len(w) and np.all(t <= now) and np.all(t >= 0)
    # a bin's mean time is its windows' sample-weighted mean: inside what it covers,
    # older than its newest window
    nb = len(st.bins)
    assert np.all(t[:nb] < w.t1[:nb] + 1e-6) and np.ptp(t[:nb]) > 0
    # the trend from the store equals the one from the windows it holds, nearly
    assert ageing.trend(w, t, now).rate == pytest.approx(
        ageing.trend(win, times, now).rate, abs=2e-6)
    # a compacted.json written before the time sum loads (newest time as the mean)
    path = tmp_path / 's' / 'compacted.json'
    state = json.loads(path.read_text())
    del state['bins']['tsum']
    path.write_text(json.dumps(state))
    old = HoldStore(str(tmp_path / 's'), 1, st.config)
    w2, t2 = old.fit_windows(now)
    np.testing.assert_allclose(t2[:nb], w2.t1[:nb])


def test_one_pose_with_a_latitude_leaves_the_vertical_earth_rate_in_the_output():
    win, times, now = season(days=1.0, holds=80, lat_deg=45.0)
    win = Windows(**{**win.__dict__,                # no ageing: one day
                     'gyro': win.gyro - RATE[None, :] * times[:, None] / DAY})
    inputs = [TemperatureInput('t', '/imu/temperature')]
    vertical = EARTH_RATE * np.sin(np.radians(45.0))
    out = {}
    for lat in (None, 45.0):
        res = calibrate_windows(win, CalibrateOptions(model='offset', inputs=inputs,
                                                      latitude=lat))
        corrected = res.calibration.apply(win.accel, win.gyro, win.temp).gyro
        out[lat] = corrected.mean(0)
        if lat is not None:
            assert any('vertical earth rate' in n for n in res.calibration.notes)
    # without the latitude the bias takes the vertical earth rate away from the output;
    # with it the output keeps it (the horizontal part averages over the headings)
    assert abs(out[None][2]) < 0.1 * vertical
    assert out[45.0][2] == pytest.approx(vertical, rel=0.1)


def test_lifelong_estimates_judge_the_ageing_on_held_out_holds(tmp_path):
    """Over 2.5 days of a robot: every estimate with a trend logs it and its held-out figures.

    2.5 days give one estimate with a resolved ageing rate (21 s here); 3 days gave five
    (57 s), none of them used either.
    """
    from thermal_imu_calib.app.calibrate import CalibrateSettings
    from thermal_imu_calib.lifelong.feed import Feeder
    from thermal_imu_calib.lifelong.hints import HintGate, HintSource
    from thermal_imu_calib.lifelong.manager import Lifelong
    from thermal_imu_calib.sim.robot_month import robot_month
    m = robot_month(3, days=2.5)
    life = Lifelong(str(tmp_path / 'life'), CalibrateSettings(latitude=45.0), 1,
                    ['/imu/temperature'], 'imu_link')
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    for seg in m.segments():
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    judged = [d for d in life.decisions() if 'ageing' in d]
    assert judged, life.decisions()
    for d in judged:
        a = d['ageing']
        assert 'mdeg/s per day' in a['text']
        if 'heldout_gyro_rms' in a:          # a resolved rate: both fits were scored
            plain, aged = a['heldout_gyro_rms']
            assert a['used'] == (plain - aged > a['margin'])
            if a['used']:                    # the gate judged the fit it keeps
                assert d['figures']['gyro']['new_rms'] == pytest.approx(aged)
    assert any('heldout_gyro_rms' in d['ageing'] for d in judged)
    # the calibrations were fitted with the latitude: their notes say so
    assert any('vertical earth rate' in n for n in life.active.notes)


def test_swap_gate_with_a_latitude_scores_the_gyro_without_the_earth_rate():
    """Holds at random headings reading the earth rate only: no error with the latitude."""
    from thermal_imu_calib.lifelong import gate
    win, times, now = season(days=1.0, holds=40, lat_deg=45.0)
    truth = bias_of(win.temp[:, 0]) + RATE[None, :] * times[:, None] / DAY
    clean = Windows(**{**win.__dict__, 'gyro': win.gyro - truth})   # earth rate + noise
    plain = gate.hold_errors(None, clean, 9.80665)
    known = gate.hold_errors(None, clean, 9.80665, latitude=45.0)
    assert np.allclose(plain['gyro'], EARTH_RATE, rtol=0.1)
    assert np.all(known['gyro'] < 0.1 * EARTH_RATE)          # the noise of the means
    # a bias of a third of the earth rate: hidden under it without the latitude (the RMS
    # moves by less than the bias), seen with it
    delta = np.array([0.0, EARTH_RATE / 3, 0.0])
    off = Windows(**{**clean.__dict__, 'gyro': clean.gyro + delta})
    rms = {lat: gate.rms(gate.hold_errors(None, off, 9.80665, lat)['gyro'])
           - gate.rms(gate.hold_errors(None, clean, 9.80665, lat)['gyro'])
           for lat in (None, 45.0)}
    assert rms[45.0] > 0.5 * EARTH_RATE / 3 and rms[45.0] > 2 * rms[None], rms
