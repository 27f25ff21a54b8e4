"""A temperature that does not move is no temperature: the same calibration as without it.

Almost every IMU driver publishes a temperature. In a room it spans a few tenths of a degC
over a posing session: too little for any temperature term (``ORDER_SPAN[1]``, 1 degC). The
real MPU-6050 and Ferraris sessions (test/fixtures/real) are written with and without a
room temperature (24 degC, a slow wander of +-0.15 degC plus sensor noise) and calibrated
through the command line with default options: the accelerometer and gyro models must be
the same, and the summary and notes must say the input was treated as none.
"""

import os

import numpy as np
import pytest

from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main
from thermal_imu_calib.io.bag import write_columns
from thermal_imu_calib.io.columns import TemperatureColumns
from thermal_imu_calib.io.csv_logs import read_imucal_session, read_mpu6050_csv

FIX = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'fixtures', 'real')


def _mpu():
    return read_mpu6050_csv(os.path.join(FIX, 'mpu6050_tomisuarez',
                                         'example_data_calibration.csv.gz')).imu


def _ferraris():
    d = os.path.join(FIX, 'imucal_ferraris')
    return read_imucal_session(os.path.join(d, 'example_ferraris_session.csv.gz'),
                               os.path.join(d, 'example_ferraris_session_list.json')).imu


def room_temperature(stamp_ns, seed=0):
    """Return 1 Hz readings of a room at 24 degC: a +-0.15 degC wander plus 0.02 noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(stamp_ns[0], stamp_ns[-1] + 1, 10 ** 9, dtype=np.int64)
    s = (t - t[0]) * 1e-9
    value = 24.0 + 0.15 * np.sin(2 * np.pi * s / 300.0) + rng.normal(0, 0.02, len(t))
    return TemperatureColumns(t, value)


@pytest.mark.parametrize('imu', [_mpu, _ferraris], ids=['mpu6050', 'ferraris'])
def test_room_temperature_gives_the_calibration_without_it(tmp_path, imu, capsys):
    imu = imu()
    plain, warm = str(tmp_path / 'plain.mcap'), str(tmp_path / 'room.mcap')
    write_columns(plain, '/imu', imu)
    write_columns(warm, '/imu', imu, {'/imu/temperature': room_temperature(imu.stamp_ns)})
    cals = []
    for log in (plain, warm):
        out = log + '.yaml'
        assert main(['calibrate', log, '--imu-topic', '/imu', '--gravity', '9.81',
                     '-o', out]) == 0
        cals.append(Calibration.load(out))
    text = capsys.readouterr().out
    without, with_room = cals
    assert with_room.inputs == []         # temperature-independent: no input to feed
    assert 'treated as none' in text
    assert any('treated as no temperature input' in n for n in with_room.notes)
    assert without.accel.kind == with_room.accel.kind
    for a, b in ((without.accel, with_room.accel), (without.gyro, with_room.gyro)):
        pa, pb = a.params(), b.params()
        assert set(pa) == set(pb)
        for name in pa:
            np.testing.assert_allclose(np.asarray(pb[name].value, float),
                                       np.asarray(pa[name].value, float),
                                       rtol=1e-9, atol=1e-12, err_msg=name)
