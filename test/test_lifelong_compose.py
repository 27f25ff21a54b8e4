"""One sensor at a time: composed calibrations and the one-sensor swap of the lifelong gate.

Real numbers: windows from the stationary detector on the simulated robot month,
calibrations from ``app.calibrate.calibrate_collected`` (the CLI's calibrate) and the
month's true calibration.
"""

import copy
import dataclasses

import numpy as np
import pytest

from _robot_month import detector_windows
from thermal_imu_calib.app.calibrate import CalibrateSettings, calibrate_collected
from thermal_imu_calib.calibration import Calibration, CalibrationError
from thermal_imu_calib.collection.collected import Collected
from thermal_imu_calib.lifelong import compose, gate
from thermal_imu_calib.lifelong.manager import Lifelong, LifelongConfig, main_pose
from thermal_imu_calib.sim.robot_month import DAY, robot_month
from thermal_imu_calib.thermal_input import ThermalFilter

TOPIC = '/imu/temperature'


@pytest.fixture(scope='module')
def month():
    """Return (RobotMonth of 1.5 days, its windows, calibrations A and B of two halves)."""
    m = robot_month(3, days=1.5)
    win = detector_windows(m)
    ids = win.hold_ids
    cals = []
    for part in (ids[:25], ids[25:50]):
        w = main_pose(win.select(np.isin(win.hold, part)), 2.0)
        col = Collected(w, m.config.frame_id, 0, 0.0, [TOPIC], [])
        cals.append(calibrate_collected(CalibrateSettings(), [col]).calibration)
    return m, win, cals


def test_each_sensor_behaves_as_in_its_source(month):
    _, _, (a, b) = month
    assert not np.array_equal(a.valid_range, b.valid_range)   # two halves, two ranges
    c = compose.compose(a, b)
    lo = min(a.valid_range[0, 0], b.valid_range[0, 0]) - 5.0
    hi = max(a.valid_range[0, 1], b.valid_range[0, 1]) + 5.0
    temps = np.linspace(lo, hi, 61)[:, None]      # inside and outside both ranges
    rng = np.random.default_rng(0)
    acc = rng.normal(0, 0.05, (61, 3)) + [0.0, 0.0, 9.81]
    gyr = rng.normal(0, 0.01, (61, 3))
    got, ra, rb = (x.apply(acc, gyr, temps) for x in (c, a, b))
    np.testing.assert_array_equal(got.accel, ra.accel)     # a's accel, clamped to a's range
    gyro_b = b.gyro.correct(gyr, b.axis_temperatures(temps, 'gyro')[0],
                            aux={'accel': ra.accel})
    np.testing.assert_allclose(got.gyro, gyro_b, rtol=0, atol=1e-15)
    both = [min(a.valid_range[0, 0], b.valid_range[0, 0]),
            max(a.valid_range[0, 1], b.valid_range[0, 1])]
    assert np.array_equal(c.valid_range[0], both)
    # the file keeps each sensor's range; read back, it compensates the same
    text = c.to_yaml()
    assert 'sensor_range' in text
    # format 2, which a reader of format 1 only refuses (it would ignore the range)
    assert 'format: thermal_imu_calib/2' in text and 'format: thermal_imu_calib/1' in a.to_yaml()
    with pytest.raises(CalibrationError, match="is not 'thermal_imu_calib/1' or"):
        Calibration.from_yaml(text.replace('thermal_imu_calib/2', 'thermal_imu_calib/9'))
    back = Calibration.from_yaml(text)
    assert back.id == c.id
    again = back.apply(acc, gyr, temps)
    np.testing.assert_array_equal(again.accel, got.accel)
    np.testing.assert_array_equal(again.gyro, got.gyro)
    assert any('composed' in n for n in back.notes)
    assert back.fit['composed'] == {'accel_from': a.id, 'gyro_from': b.id}


def test_inside_the_valid_range_means_inside_both_sensors_ranges(month, tmp_path):
    """The lifelong loop's valid range of a composition is where neither model clamps."""
    m, _, (a, b) = month
    c = compose.compose(a, b)
    inner = compose.common_range(c)[0]
    assert inner[0] == max(a.valid_range[0, 0], b.valid_range[0, 0])
    assert inner[1] == min(a.valid_range[0, 1], b.valid_range[0, 1])
    assert np.array_equal(compose.common_range(a), a.valid_range)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], m.config.frame_id)
    life.active = c
    assert life.status()['valid_range'] == [float(inner[0]), float(inner[1])]


def test_what_does_not_compose_is_refused(month):
    _, _, (a, b) = month
    lagged = dataclasses.replace(b, temperature_filter=ThermalFilter(np.array([120.0])))
    assert 'filters' in compose.why_not(a, lagged)
    with pytest.raises(ValueError, match='do not compose: their temperature filters'):
        compose.compose(a, lagged)
    other = dataclasses.replace(b, inputs=[dataclasses.replace(b.inputs[0], topic='/x')])
    assert 'thermal inputs differ' in compose.why_not(a, other)
    assert compose.why_not(None, b) == 'no active calibration'


def test_a_sensor_range_outside_the_valid_range_is_refused(month):
    _, _, (a, b) = month
    d = compose.compose(a, b).to_dict()
    which = next(iter(d['temperature']['sensor_range']))
    d['temperature']['sensor_range'][which]['max'] = [d['temperature']['valid_range']['max'][0]
                                                      + 1.0]
    with pytest.raises(CalibrationError, match='sensor_range.* within valid_range'):
        Calibration.from_dict(d)


def _worse(cal, gyro=0.0, accel_slope=0.0):
    """Return ``cal`` with its gyro bias moved (rad/s) and an accel bias slope added."""
    out = copy.deepcopy(cal)
    coeffs = out.gyro.offset if hasattr(out.gyro, 'offset') else out.gyro.coeffs
    coeffs[0] += gyro                                  # the constant row
    out.accel.thermal[:, 4] += accel_slope
    out.valid_range = np.array([[-20.0, 60.0]])
    return out


def test_one_sensor_swap_keeps_the_other_sensor(month, tmp_path):
    """Better gyro, worse accelerometer: the gyro model alone replaces the active one."""
    m, win, _ = month
    truth = m.true_calibration(0.5 * DAY)
    active = _worse(truth, gyro=np.array([0.0, 0.0, 2e-3]))           # gyro off by 2 mrad/s
    new = _worse(truth, accel_slope=np.full(3, 3e-3))                  # accel 3 mm/s^2/degC
    holdout = win.select(np.isin(win.hold, win.hold_ids[-10:]))
    pose = main_pose(holdout, 2.0)
    s_act, s_new = (gate.score(c, holdout, truth.gravity, pose) for c in (active, new))
    swap, fig = gate.decide(s_act, s_new)
    assert fig['gyro']['verdict'] == 'better' and fig['accel']['verdict'] == 'worse'
    found, record = compose.one_sensor(active, new, fig, s_act, holdout, pose, None, 2.0)
    assert record['sensor'] == 'gyro' and record['used'], record
    cal, score, fig_c = found
    assert cal.gyro is new.gyro and cal.accel is active.accel
    assert fig_c['gyro']['verdict'] == 'better' and fig_c['accel']['verdict'] == 'same'
    assert score['accel_rms'] == pytest.approx(s_act['accel_rms'], rel=1e-12)
    # both better or neither: nothing composed
    both = {w: dict(fig[w], verdict='better') for w in ('gyro', 'accel')}
    assert compose.one_sensor(active, new, both, s_act, holdout, pose, None, 2.0) == (None, {})
    # the loop: a Lifelong whose estimate is better for the gyro only swaps the gyro alone
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], m.config.frame_id,
                    config=LifelongConfig(new_holds=1000))
    life.active = active
    decision = {}
    assert compose.one_sensor_swap(life.active, new, fig, s_act, holdout, pose, None,
                                   life.config, life.state, decision) is not None
    assert decision['one_sensor']['used']
    life.config.per_sensor = False
    assert compose.one_sensor_swap(life.active, new, fig, s_act, holdout, pose, None,
                                   life.config, life.state, {}) is None


def test_raw_kept_first_swap_leaves_the_other_sensor_raw(month):
    """raw_kept: with no active calibration, the raw output is the active one.

    An estimate better than raw for the gyro but worse for the accelerometer (judged by
    the whole vector) replaces the gyro's raw output alone; the calibration has no
    accelerometer model, and later compositions take it as it is.
    """
    m, win, _ = month
    truth = m.true_calibration(0.5 * DAY)
    new = _worse(truth, accel_slope=np.full(3, 0.02))        # accel 20 mm/s^2/degC off
    a = _worse(truth, gyro=np.array([0.0, 0.0, 1e-3]))
    holdout = win.select(np.isin(win.hold, win.hold_ids[-10:]))
    pose = main_pose(holdout, 2.0)
    s_raw, s_new = (gate.score(c, holdout, truth.gravity, pose, accel_score='vector')
                    for c in (None, new))
    _, fig = gate.decide(s_raw, s_new)
    assert fig['gyro']['verdict'] == 'better' and fig['accel']['verdict'] == 'worse', fig
    # the default: no active calibration, nothing composed (the whole estimate is judged)
    assert compose.one_sensor(None, new, fig, s_raw, holdout, pose, None, 2.0,
                              'vector') == (None, {})
    found, record = compose.one_sensor(None, new, fig, s_raw, holdout, pose, None, 2.0,
                                       'vector', raw_kept=True)
    assert record['used'] and 'the other sensor raw' in record['text'], record
    cal, score, fig_c = found
    assert cal.accel is None and cal.gyro is new.gyro
    assert fig_c['accel']['verdict'] == 'same'
    acc = win.accel[:5]
    np.testing.assert_array_equal(cal.apply(acc, win.gyro[:5], win.temp[:5]).accel, acc)
    # later: an estimate better for the accelerometer only composes with the gyro-only one
    both = compose.compose(a, cal, missing=True)
    assert both.accel is a.accel and both.gyro is new.gyro
    keep_raw = compose.compose(cal, a, missing=True)          # accel from the gyro-only one
    assert keep_raw.accel is None and keep_raw.gyro is a.gyro
    assert 'lacks a sensor model' in compose.why_not(cal, a)   # only with missing=True


def test_the_range_trigger_waits_for_what_the_last_estimate_did_not_fit(month, tmp_path):
    """A sensor kept with a narrow range does not make every few holds an estimate.

    Seed 3 of the month bench kept an accelerometer valid over 14.6-31.1 degC while the
    holds reached 39.5 degC: the range trigger fired every ``min_holds`` new holds, each
    estimate fitting the same temperatures (115 estimates instead of 67). It now also needs
    the collected span to pass what the last estimate fitted by ``range_extension_degc``.
    """
    m, win, _ = month
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], m.config.frame_id,
                    config=LifelongConfig(new_holds=1000))
    life.store.add(win)
    lo, hi = life.store.temperature_span()
    assert hi - lo > 8.0, (lo, hi)
    life.active = copy.deepcopy(m.true_calibration(0.5 * DAY))
    mid = 0.5 * (lo + hi)
    life.active.valid_range = np.array([[mid - 1.0, mid + 1.0]])
    assert life.due().startswith(f'collected {lo:.1f}..{hi:.1f} degC extends the valid range')
    life.state['fit_span'] = [lo, hi]                 # the last estimate fitted all of it
    assert life.due() == ''
    life.state['fit_span'] = [lo + 4.0, hi]           # 4 degC below what it fitted
    why = life.due()
    assert 'and what the last estimate fitted' in why and why.endswith('by 4.0 degC'), why
    life.estimate()                                   # an estimate records what it fitted
    fitted = life.state['fit_span']
    assert lo <= fitted[0] < fitted[1] <= hi
    assert life.due() == ''                           # nothing new since
