"""The gyro follower: the newest holds' miss of the active model taken off what is published.

``lifelong.follower`` (``LifelongConfig.gyro_follow``): an exponentially weighted mean of
the active model's gyro error on the store's newest holds (the known vertical earth rate
removed), put into the published calibration as ``gyro_ageing.offset`` (file format 5).
Real numbers: synthetic level holds with a known ageing (``test_lifelong_ageing.season``)
and the simulated robot month's detector windows. Units: rad/s, s, days.
"""

import numpy as np
import pytest

from test_gyro_ageing import INPUTS, with_term
from test_lifelong import _truth_active_on_20_holds
from test_lifelong_ageing import DAY, season
from thermal_imu_calib.app.calibrate import CalibrateSettings
from thermal_imu_calib.calibration import Calibration, CalibrationError
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.estimation.gyro_static import earth_rate_parts
from thermal_imu_calib.lifelong import files, follower, gate
from thermal_imu_calib.lifelong.manager import FOLLOWER_LOG, Lifelong, LifelongConfig

LAT = 45.0
OFFSET = np.array([3e-5, -2e-5, 1e-5])
TOPIC = '/imu/temperature'


@pytest.fixture(scope='module')
def ageing_holds():
    """16 days of level holds (50 a day, random headings at 45 deg) with a gyro ageing."""
    win, _, _ = season(days=16.0, holds=800, seed=4, lat_deg=LAT)
    ends = np.array([win.t1[win.hold == h].max() for h in win.hold_ids])
    past = win.hold_ids[ends < 14.0 * DAY]
    cal = calibrate_windows(win.select(np.isin(win.hold, past)),
                            CalibrateOptions(model='offset', inputs=INPUTS, latitude=LAT))
    return win, cal.calibration, win.hold_ids[ends >= 14.0 * DAY]


def test_the_file_carries_the_offset_in_format_5(ageing_holds):
    _, cal, _ = ageing_holds
    out = follower.with_offset(cal, OFFSET, 1000.0, 2.0)
    n = 4
    acc, gyr = np.tile([0.0, 0.0, 9.80665], (n, 1)), np.zeros((n, 3))
    temps = np.full((n, 1), 20.0)
    base = cal.apply(acc, gyr, temps).gyro
    # taken off with or without stamps (a zero rate), on a stream too; accel untouched
    np.testing.assert_allclose(out.apply(acc, gyr, temps).gyro, base - OFFSET, atol=1e-15)
    stamps = 1000.0 + np.arange(n) * DAY
    np.testing.assert_allclose(out.apply(acc, gyr, temps, stamps=stamps).gyro, base - OFFSET,
                               atol=1e-15)
    np.testing.assert_allclose(out.stream().apply(stamps, acc, gyr, temps).gyro,
                               base - OFFSET, atol=1e-15)
    text = out.to_yaml()
    assert 'format: thermal_imu_calib/5' in text and out.id != cal.id
    back = Calibration.from_yaml(text)
    np.testing.assert_allclose(back.gyro_ageing['offset'], OFFSET, rtol=1e-15)
    assert back.id == out.id
    # with an ageing rate too: the offset adds to the rate's drift
    aged = follower.with_offset(with_term(cal, epoch=1000.0), OFFSET, 0.0, 2.0)
    drift = with_term(cal, epoch=1000.0).apply(acc, gyr, temps, stamps=stamps).gyro
    np.testing.assert_allclose(aged.apply(acc, gyr, temps, stamps=stamps).gyro,
                               drift - OFFSET, atol=1e-15)
    # an older format with an offset was edited: refused, saying what to do
    with pytest.raises(CalibrationError, match='gyro_ageing.offset is a field of format'):
        Calibration.from_yaml(text.replace('thermal_imu_calib/5', 'thermal_imu_calib/4'))
    assert follower.with_offset(cal, None, 0.0, 2.0) is cal


def test_exports_say_the_offset_is_in_the_bias(ageing_holds):
    from thermal_imu_calib.formats import common, px4
    _, cal, _ = ageing_holds
    out = follower.with_offset(cal, OFFSET, 1000.0, 2.0)
    notes = px4.export(out, common.samples(out)).notes
    assert any('recent holds' in n for n in notes), notes


def test_the_follower_takes_off_the_ageing_since_the_fit_and_keeps_the_earth_rate(
        ageing_holds):
    """Two days after a fit on 14 days, its gyro errs by the ageing since (80 urad/s RMS);
    with the follower (each hold scored on the offset of the holds before it) 23 urad/s.

    The vertical earth rate stays in the output: the mean vertical error of the followed
    output is a few urad/s, not the 52 urad/s a follower without the latitude would take.
    """
    win, cal, later = ageing_holds
    plain, followed, vertical = [], [], []
    for h in later:
        w = win.select(win.hold == h)
        prior = win.select(win.t1 <= w.t0.min())
        off, rec = follower.follow(cal, prior, 9.80665, LAT, float(prior.t1.max()), 0.5, 2.0,
                                   5)
        assert off is not None and rec['effective'] > 20, rec
        out = follower.with_offset(cal, off, 0.0, 2.0)
        plain.append(gate.hold_errors(cal, w, 9.80665, LAT)['gyro'][0])
        e = gate.hold_errors(out, w, 9.80665, LAT)
        followed.append(e['gyro'][0])
        vertical.append(e['gyro_vec'][0, 2])       # level: z is up; the known part removed
    p, f = gate.rms(np.array(plain)), gate.rms(np.array(followed))
    assert p > 6e-5 and f < 0.4 * p, (p, f)
    assert abs(np.mean(vertical)) < 0.2 * earth_rate_parts(LAT)[0], np.mean(vertical)


def test_without_the_latitude_it_follows_in_the_model_convention(ageing_holds):
    """``follow_without_latitude``: a model fitted without the latitude holds the vertical
    earth rate in its bias; followed in that convention, its ageing since the fit is taken
    off as with the latitude, and the output at rest reads no vertical earth rate.

    Scored in the model's convention: the vertical earth rate (z, the holds are level)
    put back into both outputs, then the gate's error with the latitude.
    """
    win, _, later = ageing_holds
    ends = np.array([win.t1[win.hold == h].max() for h in win.hold_ids])
    past = win.hold_ids[ends < 14.0 * DAY]
    cal = calibrate_windows(win.select(np.isin(win.hold, past)),
                            CalibrateOptions(model='offset', inputs=INPUTS)).calibration
    up_rate = np.array([0.0, 0.0, earth_rate_parts(LAT)[0]])
    plain, followed, vertical = [], [], []
    for h in later:
        w = win.select(win.hold == h)
        prior = win.select(win.t1 <= w.t0.min())
        off, rec = follower.follow(cal, prior, 9.80665, None, float(prior.t1.max()), 0.5,
                                   2.0, 5, without_latitude=True)
        assert off is not None and rec['effective'] > 20, rec
        out = follower.with_offset(cal, off, 0.0, 2.0)
        vertical.append(gate.hold_errors(out, w, 9.80665)['gyro_vec'][0, 2])
        plain.append(gate.hold_errors(follower.with_offset(cal, -up_rate, 0.0, 2.0), w,
                                      9.80665, LAT)['gyro'][0])
        followed.append(gate.hold_errors(follower.with_offset(cal, off - up_rate, 0.0, 2.0),
                                         w, 9.80665, LAT)['gyro'][0])
    p, f = gate.rms(np.array(plain)), gate.rms(np.array(followed))
    assert p > 6e-5 and f < 0.4 * p, (p, f)
    assert abs(np.mean(vertical)) < 0.2 * up_rate[2], np.mean(vertical)
    # off (follow_without_latitude false): nothing without the latitude
    off, rec = follower.follow(cal, win, 9.80665, None, float(win.t1.max()), 0.5, 2.0, 5)
    assert off is None and 'no latitude' in rec['why']


def test_the_follower_waits_for_holds_and_needs_the_latitude(ageing_holds):
    win, cal, _ = ageing_holds
    first = win.select(np.isin(win.hold, win.hold_ids[:3]))
    now = float(first.t1.max())
    off, rec = follower.follow(cal, first, 9.80665, LAT, now, 0.5, 2.0, 5)
    assert off is None and rec['why'] == '3.0 effective holds, 5 needed', rec
    off, rec = follower.follow(cal, win, 9.80665, None, float(win.t1.max()), 0.5, 2.0, 5)
    assert off is None and 'no latitude' in rec['why']
    off, rec = follower.follow(cal, first, 9.80665, LAT, now + 3 * DAY, 0.5, 2.0, 5)
    assert off is None and rec['why'] == 'no hold within the horizon'


def test_the_loop_publishes_the_followed_model_and_judges_the_model(tmp_path, month_windows):
    """A gyro step under the alarm's limit: the published output follows it, the model
    the gate and the alarm judge stays the active one, the offsets are logged, and a
    restart publishes the same output (it is computed from the stored holds)."""
    arms, later = {}, len(month_windows[1].hold_ids) - 20
    for follow in (False, True):
        life, _, hold = _truth_active_on_20_holds(tmp_path / str(follow), month_windows, later,
                                                  latitude=LAT, gyro_follow=follow,
                                                  new_holds=1000)
        life._save_cal(life.active, 'active.yaml')     # what a swap leaves for a restart
        for i in range(later):
            life.add(hold(i, OFFSET))
        arms[follow] = life
    off, on = arms[False], arms[True]
    assert off.output is off.active and on.active.id == off.active.id
    assert on.output.id != on.active.id
    assert on.state == off.state and [t.t for t in on.track] == [t.t for t in off.track]
    rows = files.read_decisions(str(tmp_path / 'True' / FOLLOWER_LOG))
    assert not (tmp_path / 'False' / FOLLOWER_LOG).exists()
    assert rows[-1]['output'] == on.output.id and rows[-1]['active'] == on.active.id
    got = np.asarray(on.output.gyro_ageing['offset'])
    np.testing.assert_allclose(got, rows[-1]['offset_rad_s'], rtol=1e-12)
    st = on.status()
    assert st['published'] == on.output.id != st['active']
    assert st['gyro_follow_offset_rad_s'] == pytest.approx(np.linalg.norm(got))
    assert off.status()['gyro_follow_offset_rad_s'] == 0.0
    # most of the newest holds carry the step: the offset has moved towards it
    assert np.linalg.norm(got - OFFSET) < 0.5 * np.linalg.norm(OFFSET), got
    again = Lifelong(str(tmp_path / 'True'), CalibrateSettings(latitude=LAT), 1, [TOPIC],
                     'imu_link', config=LifelongConfig(gyro_follow=True))
    assert again.active.id == on.active.id and again.output.id == on.output.id
