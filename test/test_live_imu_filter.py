"""``io.gate.LiveImuFilter``: the IMU rules of ``calibrate``'s gate for a live stream.

``calibrator_node`` and the lifelong ``Feeder`` drop what ``InputGate`` drops (invalid
values, stamps that do not increase) before detection; a jump back beyond ``JUMP_S`` is a
new timeline (a replay from the start), not a step back. Over DDS on a real recording:
``test_live_offline.py::test_live_calibration_equals_offline[bad_samples]``.
"""

import numpy as np

from thermal_imu_calib.io.columns import ImuColumns
from thermal_imu_calib.io.gate import InputGate, LiveImuFilter
from thermal_imu_calib.io.log_info import RawChunk

S = 1_000_000_000


def _imu(stamps_s, nan_rows=(), zero_rows=(), big_rows=()):
    st = np.array(stamps_s, np.int64) * S
    accel = np.tile([0.1, -0.2, 9.8], (len(st), 1))
    gyro = np.full((len(st), 3), 0.01)
    accel[list(nan_rows)] = np.nan
    accel[list(zero_rows)] = 0.0
    gyro[list(big_rows), 1] = 500.0                      # rad/s: no gyro gives that
    return ImuColumns(st, accel, gyro)


def _kept(imu, f=None):
    f = f or LiveImuFilter()
    return (f.push(imu).stamp_ns // S).tolist(), f.invalid, f.not_increasing


def test_duplicates_and_steps_back_are_dropped():
    assert _kept(_imu([100, 101, 102])) == ([100, 101, 102], 0, 0)
    assert _kept(_imu([100, 101, 101, 102, 100, 103])) == ([100, 101, 102, 103], 0, 2)


def test_a_jump_back_beyond_jump_s_is_a_new_timeline():
    # 103 -> 5: a replay from the start; its duplicated 6 goes; the NaN row is invalid
    assert _kept(_imu([100, 103, 5, 6, 6, 7, 200, 8], nan_rows=[6])) == (
        [100, 103, 5, 6, 7, 8], 1, 1)
    assert _kept(_imu([5, 4, 3, 50, 1, 2])) == ([5, 50, 1, 2], 0, 2)
    f = LiveImuFilter()                                   # across pushes, and reset()
    assert _kept(_imu([100, 101]), f)[0] == [100, 101]
    assert _kept(_imu([101, 99, 102]), f)[0] == [102]
    f.reset()
    assert _kept(_imu([95, 96]), f)[0] == [95, 96]


def test_the_same_rows_as_calibrates_gate():
    """On one stream without a jump, the filter keeps exactly the rows InputGate keeps."""
    rng = np.random.default_rng(7)
    st = np.cumsum(rng.choice([0, 1, 1, 1, -1], 400)) + 1000
    imu = _imu(st, nan_rows=rng.choice(400, 9), zero_rows=rng.choice(400, 5),
               big_rows=rng.choice(400, 7))
    gate = InputGate()
    out = gate.push(RawChunk(imu, imu.stamp_ns.copy(), {}))
    f = LiveImuFilter()
    kept = f.push(imu)
    np.testing.assert_array_equal(kept.stamp_ns, out.imu.stamp_ns)
    r = gate.report
    assert f.invalid == r.imu_nonfinite + r.imu_out_of_range + r.imu_zero
    assert f.not_increasing == r.imu_stamp_not_increasing > 0
