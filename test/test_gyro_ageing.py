"""A gyro bias carried forward in time: ``Calibration.gyro_ageing``, its file and its use.

A lifelong estimate fitted with the gyro ageing removed holds the bias of the estimate's
time; with ``LifelongConfig.gyro_ageing_forward`` the file also carries the fitted rates,
and the compensation takes ``rate * (t - epoch)`` off the gyro on the IMU's stamps (at
most ``max_days`` either way). Units: rad/s, rad/s per day, s.
"""

import dataclasses

import numpy as np
import pytest

from test_lifelong_ageing import DAY, RATE, season
from thermal_imu_calib.calibration import Calibration, CalibrationError, TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.lifelong import compose, gate, variants
from thermal_imu_calib.lifelong.config import LifelongConfig

INPUTS = [TemperatureInput('t', '/imu/temperature')]


def fitted(windows):
    """The plain offset fit of ``windows`` (a calibrate result, as the loop's ``calibrate``)."""
    return calibrate_windows(windows, CalibrateOptions(model='offset', inputs=INPUTS))


def with_term(cal, rate=RATE, epoch=1000.0 * DAY, max_days=3.0):
    return dataclasses.replace(cal, gyro_ageing={'rate': np.asarray(rate, float),
                                                 'epoch': epoch, 'max_days': max_days})


@pytest.fixture(scope='module')
def plain_cal():
    win, _, _ = season(days=3.0, holds=60)
    return fitted(win).calibration


def test_apply_carries_the_bias_on_the_stamps_within_its_bound(plain_cal):
    cal = with_term(plain_cal)
    n, epoch = 5, cal.gyro_ageing['epoch']
    stamps = epoch + np.array([-5.0, -1.0, 0.0, 2.0, 10.0]) * DAY
    acc = np.tile([0.0, 0.0, 9.80665], (n, 1))
    gyr = np.zeros((n, 3))
    temps = np.full((n, 1), 20.0)
    base = plain_cal.apply(acc, gyr, temps).gyro
    out = cal.apply(acc, gyr, temps, stamps=stamps).gyro
    days = np.array([-3.0, -1.0, 0.0, 2.0, 3.0])          # bounded at max_days either way
    np.testing.assert_allclose(out, base - days[:, None] * RATE, atol=1e-15)
    # without stamps: the bias of the epoch, as a file without the term
    np.testing.assert_array_equal(cal.apply(acc, gyr, temps).gyro, base)
    # a stream passes the stamps; the accelerometer is untouched
    res = cal.stream().apply(stamps, acc, gyr, temps)
    np.testing.assert_allclose(res.gyro, out, atol=1e-15)
    np.testing.assert_array_equal(res.accel, plain_cal.apply(acc, gyr, temps).accel)


def test_the_file_says_format_4_and_reads_back(plain_cal, tmp_path):
    cal = with_term(plain_cal)
    text = cal.to_yaml()
    assert 'format: thermal_imu_calib/4' in text and 'rad/s/day' in text
    back = Calibration.from_yaml(text)
    assert back.gyro_ageing['rate'] == pytest.approx(RATE, rel=1e-12)
    assert back.gyro_ageing['epoch'] == cal.gyro_ageing['epoch']
    assert back.gyro_ageing['max_days'] == 3.0 and back.id == cal.id != plain_cal.id
    assert 'format: thermal_imu_calib/1' in plain_cal.to_yaml() and not \
        Calibration.from_yaml(plain_cal.to_yaml()).gyro_ageing
    # an older format with the term was edited: refused, saying what to do
    with pytest.raises(CalibrationError, match='gyro_ageing is a field of format'):
        Calibration.from_yaml(text.replace('thermal_imu_calib/4', 'thermal_imu_calib/3'))
    with pytest.raises(CalibrationError, match='max_days'):
        Calibration.from_yaml(text.replace('value: 3.0', 'value: -1.0'))
    # a file without a gyro model cannot carry one
    no_gyro = dataclasses.replace(cal, gyro=None)
    assert 'gyro_ageing' not in no_gyro.to_yaml()


def test_a_composed_calibration_takes_the_term_with_the_gyro(plain_cal):
    aged = with_term(plain_cal)
    assert compose.compose(plain_cal, aged).gyro_ageing['max_days'] == 3.0
    assert compose.compose(aged, plain_cal).gyro_ageing == {}


def test_an_estimate_kept_with_the_ageing_removed_carries_it_forward():
    """14 days of ageing under a seasonal temperature: the file carries the rates.

    Up to two days after the estimate, the calibration with the rates carried errs on new
    holds by a fraction of what the same calibration without them does (|RATE| is 23
    urad/s per day; here 6.6 against 27.8 urad/s RMS).
    """
    win, times, _ = season(days=16.0, holds=340, seed=4)
    t_hold = np.array([times[win.hold == h].min() for h in win.hold_ids])
    past = win.hold_ids[t_hold < 14.0 * DAY]
    later = win.select(~np.isin(win.hold, past))
    held_ids = past[-8:]
    fit_w = win.select(np.isin(win.hold, past[:-8]))
    fit_t = times[np.isin(win.hold, past[:-8])]
    holdout = win.select(np.isin(win.hold, held_ids))
    now = float(holdout.t1.max())
    plain = fitted(fit_w)
    s_plain = gate.score(plain.calibration, holdout, 9.80665, holdout)
    out = {}
    for forward in (False, True):
        decision = {}
        config = LifelongConfig(gyro_ageing_forward=forward)
        aged = variants.with_ageing(fitted, fit_w, fit_t, now, holdout, holdout, s_plain,
                                    decision, config, None)
        assert aged is not None and decision['ageing']['used'], decision
        cal = aged[0].calibration
        out[forward] = gate.rms(gate.hold_errors(cal, later, 9.80665)['gyro'])
        if forward:
            ag = cal.gyro_ageing
            assert ag['epoch'] == now and 13.0 < ag['max_days'] < 14.0
            np.testing.assert_allclose(ag['rate'], RATE, rtol=0.2, atol=2e-6)
            assert 'carried forward in the file' in decision['ageing']['text']
            assert any(n.startswith('gyro ageing: ') for n in cal.notes)
            # the gate's score is the file's (its stamps): the same held-out holds
            assert aged[1]['gyro_rms'] == pytest.approx(
                gate.score(cal, holdout, 9.80665, holdout)['gyro_rms'])
        else:
            assert cal.gyro_ageing == {}
    assert out[True] < 0.3 * out[False], out


def test_exports_say_the_bias_is_the_epoch_s(plain_cal):
    from thermal_imu_calib.formats import ardupilot, common, imu_tk, px4
    cal = with_term(plain_cal)
    smp = common.samples(cal)
    for out in (px4.export(cal, smp), ardupilot.export(cal, smp), imu_tk.export(cal, smp)):
        assert any('carries its bias forward in time' in n and 'at the epoch' in n
                   for n in out.notes), out.notes
    assert not any('forward in time' in n for n in px4.export(plain_cal, smp).notes)
