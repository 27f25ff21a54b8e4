"""Cross-check the bulk CDR fast path against rosbags' reference (de)serializer."""

import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores

from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
IMU = 'sensor_msgs/msg/Imu'
TEMP = 'sensor_msgs/msg/Temperature'
# Every padding case: frame_id byte lengths 0..9 (+ NUL) and a multi-byte UTF-8 name.
FRAMES = ['x' * k for k in range(10)] + ['imu_\u00e9']


def _header(sec, nsec, frame):
    return T['std_msgs/msg/Header'](T['builtin_interfaces/msg/Time'](sec, nsec), frame)


def _random_imu(rng, frame):
    v3 = T['geometry_msgs/msg/Vector3']
    return T[IMU](
        _header(int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 10**9)), frame),
        T['geometry_msgs/msg/Quaternion'](*rng.normal(size=4)),
        rng.normal(size=9), v3(*rng.normal(size=3)), rng.normal(size=9),
        v3(*rng.normal(size=3)), rng.normal(size=9))


def _ser(msg, typename):
    return bytes(TS.serialize_cdr(msg, typename))


@pytest.fixture
def imu_batch():
    rng = np.random.default_rng(42)
    frames = [FRAMES[i % len(FRAMES)] for i in range(200)]
    rng.shuffle(frames)
    msgs = [_random_imu(rng, f) for f in frames]
    return msgs, [_ser(m, IMU) for m in msgs]


def _stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_decode_imu_matches_rosbags_for_every_padding(imu_batch):
    msgs, raws = imu_batch
    assert len({len(r) for r in raws}) >= 2  # several layouts in one batch
    cols = cdr.decode_imu(raws)
    assert len(cols) == len(msgs)
    assert cols.frame_id == ''  # mixed frames
    for i, raw in enumerate(raws):
        ref = TS.deserialize_cdr(raw, IMU)
        assert cols.stamp_ns[i] == _stamp_ns(ref)
        a, g = ref.linear_acceleration, ref.angular_velocity
        assert cols.accel[i].tolist() == [a.x, a.y, a.z]
        assert cols.gyro[i].tolist() == [g.x, g.y, g.z]
    full = cdr.decode_imu_full(raws)
    ref = TS.deserialize_cdr(raws[7], IMU)
    np.testing.assert_array_equal(full['linear_acceleration_covariance'][7],
                                  ref.linear_acceleration_covariance)
    o = ref.orientation
    assert full['orientation'][7].tolist() == [o.x, o.y, o.z, o.w]


def test_decode_imu_common_frame_and_empty():
    rng = np.random.default_rng(1)
    raws = [_ser(_random_imu(rng, 'imu_link'), IMU) for _ in range(5)]
    assert cdr.decode_imu(raws).frame_id == 'imu_link'
    empty = cdr.decode_imu([])
    assert len(empty) == 0 and empty.accel.shape == (0, 3)


@pytest.mark.parametrize('frame', FRAMES)
def test_encode_imu_is_byte_identical_to_rosbags(frame):
    rng = np.random.default_rng(len(frame))
    n = 4
    cols = ImuColumns(np.array([0, 1, 1_700_000_000_123_456_789, -1_500_000_000]),
                      rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), frame)
    acov = np.diag([1e-4, 2e-4, 3e-4])
    raws = cdr.encode_imu(cols, accel_cov=acov, gyro_cov=1e-6)
    v3 = T['geometry_msgs/msg/Vector3']
    for i, raw in enumerate(raws):
        sec, nsec = divmod(int(cols.stamp_ns[i]), 1_000_000_000)
        ocov = np.zeros(9)
        ocov[0] = -1.0
        ref = T[IMU](_header(sec, nsec, frame), T['geometry_msgs/msg/Quaternion'](0, 0, 0, 0),
                     ocov, v3(*cols.gyro[i]), np.diag([1e-6] * 3).reshape(9),
                     v3(*cols.accel[i]), acov.reshape(9))
        assert raw == _ser(ref, IMU)
    back = cdr.decode_imu(raws)
    np.testing.assert_array_equal(back.stamp_ns, cols.stamp_ns)
    assert back.frame_id == frame


def test_patch_imu_changes_only_accel_and_gyro(imu_batch):
    msgs, raws = imu_batch
    n = len(raws)
    rng = np.random.default_rng(7)
    accel, gyro = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    patched = cdr.patch_imu(raws, accel, gyro)
    assert [len(p) for p in patched] == [len(r) for r in raws]
    for i in range(n):
        ref = TS.deserialize_cdr(raws[i], IMU)
        new = TS.deserialize_cdr(patched[i], IMU)
        assert new.header == ref.header
        assert new.orientation == ref.orientation
        for name in ('orientation_covariance', 'angular_velocity_covariance',
                     'linear_acceleration_covariance'):
            np.testing.assert_array_equal(getattr(new, name), getattr(ref, name))
        a, g = new.linear_acceleration, new.angular_velocity
        assert [a.x, a.y, a.z] == accel[i].tolist()
        assert [g.x, g.y, g.z] == gyro[i].tolist()
        # Byte level: identical except within the two 24-byte vectors.
        diff = np.flatnonzero(np.frombuffer(raws[i], np.uint8)
                              != np.frombuffer(patched[i], np.uint8))
        body = len(raws[i]) - 296
        gyro_at, acc_at = body + 13 * 8, body + 25 * 8
        assert all(gyro_at <= d < gyro_at + 24 or acc_at <= d < acc_at + 24 for d in diff)
    # Originals untouched.
    assert raws[0] == _ser(msgs[0], IMU)


def test_patch_imu_covariance(imu_batch):
    _, raws = imu_batch
    out = cdr.patch_imu_covariance(raws[:10], accel_cov=[1.0, 2.0, 3.0])
    for raw, new in zip(raws[:10], out):
        ref, got = TS.deserialize_cdr(raw, IMU), TS.deserialize_cdr(new, IMU)
        np.testing.assert_array_equal(got.linear_acceleration_covariance,
                                      np.diag([1.0, 2.0, 3.0]).reshape(9))
        np.testing.assert_array_equal(got.angular_velocity_covariance,
                                      ref.angular_velocity_covariance)
        assert got.linear_acceleration == ref.linear_acceleration
    assert cdr.patch_imu_covariance(raws[:3]) == raws[:3]


@pytest.mark.parametrize('frame', FRAMES)
def test_temperature_roundtrip_matches_rosbags(frame):
    stamps = np.array([0, 999_999_999, 1_700_000_000_000_000_001])
    cols = TemperatureColumns(stamps, np.array([-40.0, 21.5, 85.25]), frame)
    raws = cdr.encode_temperature(cols, variance=[0.0, 0.01, 0.02])
    for i, raw in enumerate(raws):
        sec, nsec = divmod(int(stamps[i]), 1_000_000_000)
        ref = T[TEMP](_header(sec, nsec, frame), float(cols.temperature[i]), [0.0, 0.01, 0.02][i])
        assert raw == _ser(ref, TEMP)
    back = cdr.decode_temperature(raws)
    np.testing.assert_array_equal(back.stamp_ns, stamps)
    np.testing.assert_array_equal(back.temperature, cols.temperature)
    assert back.frame_id == frame


def test_decode_temperature_from_rosbags_mixed_frames():
    rng = np.random.default_rng(3)
    msgs = [T[TEMP](_header(int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9)), f),
                    float(rng.normal(30, 10)), 0.1) for f in FRAMES * 3]
    cols = cdr.decode_temperature([_ser(m, TEMP) for m in msgs])
    assert cols.stamp_ns.tolist() == [_stamp_ns(m) for m in msgs]
    assert cols.temperature.tolist() == [m.temperature for m in msgs]
    assert cols.frame_id == ''


def test_header_stamps_reads_any_stamped_message(imu_batch):
    msgs, raws = imu_batch
    assert cdr.header_stamps(raws).tolist() == [_stamp_ns(m) for m in msgs]


def test_big_endian_and_garbage_are_refused():
    rng = np.random.default_rng(0)
    msg = _random_imu(rng, 'imu')
    big = bytes(TS.serialize_cdr(msg, IMU, little_endian=False))
    with pytest.raises(ValueError, match='big-endian'):
        cdr.decode_imu([big])
    with pytest.raises(ValueError, match='too short'):
        cdr.decode_imu([_ser(msg, IMU)[:100]])
    with pytest.raises(ValueError, match='frame_id length'):
        raw = bytearray(_ser(msg, IMU))
        raw[12:16] = (200).to_bytes(4, 'little')
        cdr.decode_imu([bytes(raw)])
    with pytest.raises(ValueError, match=r'expected \(1, 3\)'):
        cdr.patch_imu([_ser(msg, IMU)], np.zeros(3), np.zeros((1, 3)))
