"""Offline ``compensate`` at temperature gaps: --max-gap, --temperature-timeout, the policies.

A short simulated cold start is written with a 20-s hole in its temperature topic; the
calibration is the simulator's true one. What each IMU message gets is derived here
independently from the stamps (``align.py``'s rule: inside a gap wider than --max-gap the
nearest reading is held and its age is the distance to it; a reading older than
--temperature-timeout is stale), then checked against the written log message by message.
Also a log with no temperature at all: calibrate notes it, compensate with a thermal
calibration refuses with the topic named.
"""

import dataclasses

import numpy as np
import pytest

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.columns import TemperatureColumns

HOLE_S = (40.0, 60.0)    # seconds after the start without temperature readings
TOPIC = '/imu/temperature'


def _with_hole(rec):
    tc = rec.temperatures[TOPIC]
    t = (tc.stamp_ns - rec.start_ns) * 1e-9
    keep = (t < HOLE_S[0]) | (t > HOLE_S[1])
    return dataclasses.replace(rec, temperatures={TOPIC: TemperatureColumns(
        tc.stamp_ns[keep], tc.temperature[keep], tc.frame_id)})


def _no_temperature(rec):
    return dataclasses.replace(rec, temperatures={})


@pytest.fixture(scope='module')
def gap_log(tmp_path_factory):
    d = tmp_path_factory.mktemp('gap')
    paths = sim.write_scenario(d / 'gap.mcap', 'demo', 1, repetitions=1,
                               transform=_with_hole)
    return d, paths


def _read(path, topic):
    with open_log(path) as r:
        chunks = [c.imu for c in r.stream(topic)]
    return (np.concatenate([c.stamp_ns for c in chunks]),
            np.concatenate([c.accel for c in chunks]), np.concatenate([c.gyro for c in chunks]))


def expected_age(imu_ns, temp_ns, max_gap_s):
    """Return the age (s) of the temperature each IMU stamp gets, by align.py's rule."""
    temp_ns = np.sort(temp_ns)
    j = np.searchsorted(temp_ns, imu_ns, side='right')     # temp_ns[j - 1] <= s
    prev = temp_ns[np.clip(j - 1, 0, None)]
    nxt = temp_ns[np.clip(j, None, len(temp_ns) - 1)]
    has_prev, has_next = j > 0, j < len(temp_ns)
    bracket = has_prev & has_next & ((nxt - prev) * 1e-9 <= max_gap_s)
    d_prev = np.where(has_prev, (imu_ns - prev) * 1e-9, np.inf)
    d_next = np.where(has_next, (nxt - imu_ns) * 1e-9, np.inf)
    return np.where(bracket | (d_prev == 0), 0.0, np.minimum(d_prev, d_next))


def _compensate(d, paths, name, *opts):
    out = d / f'{name}.mcap'
    assert main(['compensate', str(paths['bag']), '--calibration', str(paths['truth']),
                 '-o', str(out), *opts]) == 0
    return out


def test_drop_removes_exactly_the_stale_messages(gap_log):
    d, paths = gap_log
    raw_ns, raw_a, _ = _read(paths['bag'], '/imu/data_raw')
    # the temperature stamps the log holds (write_scenario wrote exactly these)
    temp_ns = _with_hole(sim.simulate('demo', 1, repetitions=1)).temperatures[TOPIC].stamp_ns
    age = expected_age(raw_ns, temp_ns, 5.0)
    stale = age > 2.0
    assert 1500 < stale.sum() < 2000          # ~16 s of the 20-s hole at 100 Hz
    out = _compensate(d, paths, 'drop', '--max-gap', '5', '--temperature-timeout', '2',
                      '--on-missing-temperature', 'drop')
    ns, _, _ = _read(out, '/imu/data_compensated')
    np.testing.assert_array_equal(np.sort(ns), raw_ns[~stale])
    # passthrough: every message, the stale ones unchanged, the others compensated
    out = _compensate(d, paths, 'pass', '--max-gap', '5', '--temperature-timeout', '2',
                      '--on-missing-temperature', 'passthrough')
    ns, acc, gyr = _read(out, '/imu/data_compensated')
    order = np.argsort(ns)
    ns, acc = ns[order], acc[order]
    np.testing.assert_array_equal(ns, raw_ns)
    same = np.all(acc == raw_a, axis=1)
    np.testing.assert_array_equal(same, stale)
    # hold_last (default): everything compensated, with the nearest reading held
    out = _compensate(d, paths, 'hold', '--max-gap', '5', '--temperature-timeout', '2')
    ns, acc, _ = _read(out, '/imu/data_compensated')
    assert len(ns) == len(raw_ns) and not np.any(np.all(acc == raw_a[np.argsort(ns)], axis=1))


def test_max_gap_wider_than_the_hole_interpolates_across_it(gap_log):
    d, paths = gap_log
    raw_ns, _, _ = _read(paths['bag'], '/imu/data_raw')
    out = _compensate(d, paths, 'wide', '--max-gap', '30', '--temperature-timeout', '2',
                      '--on-missing-temperature', 'drop')
    ns, _, _ = _read(out, '/imu/data_compensated')
    assert len(ns) == len(raw_ns)             # the 20-s hole is bridged: age 0, none stale


def test_a_log_without_temperature(tmp_path, capsys):
    paths = sim.write_scenario(tmp_path / 'cold.mcap', 'demo', 1, repetitions=1,
                               transform=_no_temperature)
    out = tmp_path / 'c.yaml'
    assert main(['calibrate', str(paths['bag']), '-o', str(out)]) == 0
    cal = Calibration.load(out)
    assert cal.inputs == [] and any('no temperature input' in n for n in cal.notes), cal.notes
    capsys.readouterr()
    code = main(['compensate', str(paths['bag']), '--calibration', str(paths['truth']),
                 '-o', str(tmp_path / 'x.mcap')])
    err = capsys.readouterr().err
    assert code == 2 and TOPIC in err, err
    assert not (tmp_path / 'x.mcap').exists()
