"""``placement_floor``: on one orientation's one-way history (a robot's first stops), a
sensor's thermal model must also be no worse than its output as it is when whole stops
are left out; else that sensor gets no thermal terms.

The synthetic stops: eight holds on a warming day, one mounting pose. The accelerometer's
horizontal levels differ from stop to stop by the floor's tilt (g sin(tilt), a few
mrad), with no temperature dependence at all; the gyro has a real linear one. The tilt
levels are not a function of temperature, so a model fitted to them predicts held-out
stops worse than leaving the output alone.
"""

import numpy as np

from thermal_imu_calib.app.calibrate import CalibrateSettings, calibrate_collected
from thermal_imu_calib.collection.collected import Collected
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.hysteresis import NO_THERMAL_SPEC
from thermal_imu_calib.selection.time_folds import placement_groups

G = 9.80665


def _stops(n_holds=8, per_hold=12, seed=4, both_ways=False):
    rng = np.random.default_rng(seed)
    holds = np.repeat(np.arange(n_holds), per_hold)
    m = len(holds)
    # 30-s windows, a 20-min drive between stops
    t0 = np.arange(m) * 30.0 + holds * 1200.0
    x = (t0 - t0[0]) / (t0[-1] - t0[0])
    temp = 10.0 + 30.0 * (np.sin(np.pi * x) if both_ways else x)      # degC
    tilt = rng.normal(0.0, 0.003, (n_holds, 2))                      # rad, per stop
    accel = np.zeros((m, 3))
    accel[:, :2] = G * tilt[holds] + rng.normal(0.0, 2e-4, (m, 2))
    accel[:, 2] = G + rng.normal(0.0, 2e-4, m)
    gyro = 1e-4 * (temp[:, None] - 25.0) * np.array([1.0, -0.5, 0.3]) \
        + rng.normal(0.0, 2e-6, (m, 3))
    var = np.full((m, 3), 1e-6)
    return Windows(hold=holds, t0=t0, t1=t0 + 30.0, n=np.full(m, 3000), accel=accel,
                   gyro=gyro, accel_var=var, gyro_var=var * 1e-4, temp=temp[:, None],
                   temp_rate=np.zeros((m, 1)))


def _choice(windows, **options):
    settings = CalibrateSettings(placement_folds=True, **options)
    result = calibrate_collected(settings, [Collected(windows, 'imu', 0, 0.0, ['t'], [])])
    fit = result.calibration.fit
    return fit['model_choice'], result.calibration


def test_placement_groups_hold_out_whole_stops_in_time_order():
    w = _stops(n_holds=14)
    folds = placement_groups(w)
    assert len(folds) == 6
    tested = np.zeros(len(w), int)
    for train, test, _ in folds:
        assert not np.isin(w.hold[train], w.hold[test]).any()
        held = np.unique(w.hold[test])
        assert np.array_equal(held, np.arange(held[0], held[-1] + 1))   # contiguous
        tested += test
    assert np.all(tested == 1)
    assert placement_groups(_stops(n_holds=1)) == []


def test_the_floor_leaves_the_tilted_accelerometer_alone_and_keeps_the_gyro_model():
    w = _stops()
    choice, cal = _choice(w, placement_floor=True)
    reason = choice['reason']
    assert 'placement floor (6 groups of whole holds held out)' in reason
    accel_part = reason[reason.index('accel: raw'):reason.index('gyro: raw')]
    assert 'worse than the output as it is' in accel_part
    assert f'accel {NO_THERMAL_SPEC.label()}' in reason, reason
    assert f'gyro {NO_THERMAL_SPEC.label()}' not in reason
    # the accelerometer's correction is a constant: the same on every stop
    corr = cal.accel.correct(w.accel, np.repeat(w.temp, 3, axis=1)) - w.accel
    assert np.ptp(corr, axis=0).max() < 1e-12
    # the gyro's removes the temperature slope
    gyr = cal.gyro.correct(w.gyro, np.repeat(w.temp, 3, axis=1))
    assert np.std(gyr, axis=0).max() < 0.2 * np.std(w.gyro, axis=0).min()


def test_without_the_floor_the_bands_alone_give_the_tilt_a_model():
    """The same stops without the floor: the two interior bands favour a quadratic in T
    for the accelerometer (the tilt levels of the stops in them), which is the harm the
    floor removes."""
    w = _stops()
    choice, cal = _choice(w)
    assert 'placement floor' not in choice['reason']
    assert f'accel {NO_THERMAL_SPEC.label()}' not in choice['reason']
    corr = cal.accel.correct(w.accel, np.repeat(w.temp, 3, axis=1)) - w.accel
    assert np.ptp(corr, axis=0).max() > 1e-3


def test_the_floor_on_the_history_path():
    """The temperature warms and cools again (the history path, ``time_folds``): the
    chosen spec is checked on held-out stops, and the accelerometer model the forward
    blocks chose from the tilt gives way to no thermal terms; the gyro keeps its model."""
    w = _stops(n_holds=10, seed=2, both_ways=True)
    without, _ = _choice(w)
    assert 'held-out blocks of the thermal history' in without['reason']
    assert f'chose {NO_THERMAL_SPEC.label()}' not in without['reason']
    choice, cal = _choice(w, placement_floor=True)
    reason = choice['reason']
    accel = reason[reason.index('accel (m/s^2)'):reason.index('gyro (rad/s)')]
    gyro = reason[reason.index('gyro (rad/s)'):]
    assert 'placement floor (6 groups of whole holds held out)' in accel
    assert 'so no thermal terms instead of' in accel
    assert 'placement floor' in gyro and 'so no thermal terms' not in gyro
    corr = cal.accel.correct(w.accel, np.repeat(w.temp, 3, axis=1)) - w.accel
    assert np.ptp(corr, axis=0).max() < 1e-12
    gyr = cal.gyro.correct(w.gyro, np.repeat(w.temp, 3, axis=1))
    assert np.std(gyr, axis=0).max() < 0.2 * np.std(w.gyro, axis=0).min()


def test_the_floor_on_the_family_kept_without_bands():
    """Too few windows for two temperature bands: the previous path's family stays
    (``select_single``, a score of both sensors). The floor refits it per sensor with whole
    stops held out; the accelerometer it harms is fitted with no thermal terms."""
    w = _stops(n_holds=6, per_hold=6, seed=3)
    without, cal0 = _choice(w)
    assert 'fewer than 2 held-out bands, kept' in without['reason']
    corr0 = cal0.accel.correct(w.accel, np.repeat(w.temp, 3, axis=1)) - w.accel
    assert np.ptp(corr0, axis=0).max() > 1e-3
    choice, cal = _choice(w, placement_floor=True)
    assert 'no thermal terms for the accel' in choice['reason']
    corr = cal.accel.correct(w.accel, np.repeat(w.temp, 3, axis=1)) - w.accel
    assert np.ptp(corr, axis=0).max() < 1e-12
    gyr = cal.gyro.correct(w.gyro, np.repeat(w.temp, 3, axis=1))
    assert np.std(gyr, axis=0).max() < 0.2 * np.std(w.gyro, axis=0).min()
