"""Header-less temperatures (std_msgs/Float32, Float64) offline: decoding, stamps, calibrate.

A reading without a header takes the stamp of the IMU message logged before it
(``io/headerless``). So a log whose Float64 readings are logged at their original times
must give, exactly, what the same log gives with sensor_msgs/Temperature readings stamped
with those IMU stamps, through both readers (MCAP bulk, sqlite per message), at any chunk
size, and through ``calibrate`` end to end.
"""

import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores

from thermal_imu_calib import sim
from thermal_imu_calib.cli import main
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import TemperatureColumns
from thermal_imu_calib.io.headerless import (decode_values, decode_values_packed,
                                             encode_values, LiveImuClock, on_imu_clock)
from thermal_imu_calib.io.log_info import LogError

STORE = get_typestore(Stores.ROS2_JAZZY)
TEMP = '/imu/temperature'


@pytest.mark.parametrize('msgtype', ['std_msgs/msg/Float32', 'std_msgs/msg/Float64'])
def test_values_round_trip_against_rosbags(msgtype):
    values = np.array([21.5, -17.625, 74.0, 1e-3])
    ours = encode_values(values, msgtype)
    cls = STORE.types[msgtype]
    theirs = [bytes(STORE.serialize_cdr(cls(data=float(v)), msgtype)) for v in values]
    if msgtype.endswith('32'):
        theirs = [bytes(STORE.serialize_cdr(cls(data=np.float32(v)), msgtype)) for v in values]
    assert ours == theirs
    expect = values.astype(np.float32) if msgtype.endswith('32') else values
    np.testing.assert_array_equal(decode_values(theirs, msgtype), expect)
    buf = np.frombuffer(b'xx' + b''.join(theirs), np.uint8)
    size = len(theirs[0])
    np.testing.assert_array_equal(
        decode_values_packed(buf, 2 + size * np.arange(4), [size] * 4, msgtype), expect)
    assert [STORE.deserialize_cdr(r, msgtype).data for r in ours] == list(expect)


def test_malformed_payloads_are_named():
    with pytest.raises(ValueError, match='only 6 bytes.*really carries std_msgs/msg/Float64'):
        decode_values([b'\x00\x01\x00\x00\x00\x00'], 'std_msgs/msg/Float64')
    with pytest.raises(ValueError, match='message 1 is not little-endian CDR'):
        decode_values([b'\x00\x01\x00\x00' + bytes(4), b'\x00\x00\x00\x00' + bytes(4)],
                      'std_msgs/msg/Float32')


def test_a_reading_takes_the_stamp_of_the_imu_message_logged_before_it():
    imu = np.array([100, 200, 300])
    got = on_imu_clock([1.0, 2.0, 3.0, 4.0], [0, 1, 3, 3], imu, None)
    np.testing.assert_array_equal(got.stamp_ns, [100, 300, 300])   # none before: left out
    np.testing.assert_array_equal(got.temperature, [2.0, 3.0, 4.0])
    got = on_imu_clock([1.0, 2.0], [0, 2], imu, 50)                   # the chunk before's
    np.testing.assert_array_equal(got.stamp_ns, [50, 200])


def _logs(tmp_path, storage, msgtype):
    """Write the demo recording twice: Float readings at their times, and Temperature ones
    stamped with the IMU stamp logged before each (what the reader must give the Float)."""
    rec = sim.simulate('demo', 3, repetitions=1)
    tc = rec.temperatures[TEMP]
    values = tc.temperature.astype(np.float32) if msgtype.endswith('32') else tc.temperature
    stamps = np.concatenate([c.stamp_ns for c in rec.imu_chunks()])
    before = np.searchsorted(stamps, tc.stamp_ns, side='right')   # IMU first at a tie
    keep = before > 0
    snapped = TemperatureColumns(stamps[before[keep] - 1], values[keep].astype(float))
    ext = '.mcap' if storage == 'mcap' else ''
    bare, stamped = tmp_path / f'bare{ext}', tmp_path / f'stamped{ext}'
    write_columns(bare, '/imu/data_raw', rec.imu_chunks(),
                  {TEMP: TemperatureColumns(tc.stamp_ns, values.astype(float))},
                  storage=storage, msgtypes={TEMP: msgtype})
    write_columns(stamped, '/imu/data_raw', rec.imu_chunks(), {TEMP: snapped}, storage=storage)
    return bare, stamped, int(keep.sum())


def _stream(path, chunk_size):
    with open_log(path) as r:
        chunks = list(r.stream('/imu/data_raw', [TEMP], chunk_size=chunk_size))
    return (np.concatenate([c.temps[TEMP].stamp_ns for c in chunks]),
            np.concatenate([c.temps[TEMP].temperature for c in chunks]))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('msgtype', ['std_msgs/msg/Float32', 'std_msgs/msg/Float64'])
def test_a_log_reads_as_the_same_log_with_stamped_readings(tmp_path, storage, msgtype):
    bare, stamped, n = _logs(tmp_path, storage, msgtype)
    want = _stream(stamped, 20000)
    assert len(want[0]) == n > 100
    for size in (20000, 7, 1):       # the stamp of the chunk before carries over
        got = _stream(bare, size)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    with open_log(bare) as r:
        text = r.info().format()
    line = next(ln for ln in text.splitlines() if msgtype in ln)
    assert '10.00 Hz' in line and ' degC' in line, line      # the rate over log times


def test_calibrate_finds_and_uses_a_float32_imu_temperature(tmp_path, capsys):
    bare, stamped, _ = _logs(tmp_path, 'mcap', 'std_msgs/msg/Float32')
    outs = []
    for log in (bare, stamped):
        out = tmp_path / f'{log.stem}.yaml'
        assert main(['calibrate', str(log), '--gravity', '9.80665', '-o', str(out)]) == 0
        outs.append(out.read_text())
    text = capsys.readouterr()
    assert 'std_msgs/msg/Float32, no header' in text.out + text.err
    assert 'temperature_topic' in outs[0] or TEMP in outs[0]
    strip = [[ln for ln in o.splitlines() if 'created' not in ln and 'source' not in ln
              and '.mcap' not in ln] for o in outs]
    assert strip[0] == strip[1]
    accel = []                   # compensate: the same output sample for sample
    for log in (bare, stamped):
        out = tmp_path / f'{log.stem}.comp.mcap'
        assert main(['compensate', str(log), '--calibration', str(tmp_path / 'bare.yaml'),
                     '-o', str(out)]) == 0
        with open_log(out) as r:
            accel.append(np.concatenate([c.imu.accel for c in r.stream(
                '/imu/data_compensated')]))
    assert len(accel[0]) > 10000
    np.testing.assert_array_equal(accel[0], accel[1])


def test_several_headerless_temperatures_in_the_namespace_are_refused(tmp_path):
    rec = sim.simulate('demo', 3, repetitions=1)
    tc = rec.temperatures[TEMP]
    path = tmp_path / 'two.mcap'
    write_columns(path, '/imu/data_raw', rec.imu_chunks(), {TEMP: tc, '/imu/temp_board': tc},
                  msgtypes={TEMP: 'std_msgs/msg/Float64',
                            '/imu/temp_board': 'std_msgs/msg/Float32'})
    from thermal_imu_calib.io.topics import resolve_topics
    refused = 'several header-less.*/imu/temp_board, /imu/temperature.*--temperature-topic'
    with open_log(path) as r, pytest.raises(LogError, match=refused):
        resolve_topics(r, '/imu/data_raw', None)
    with open_log(path) as r:
        assert resolve_topics(r, '/imu/data_raw', ['/imu/temp_board'])[1] == [
            '/imu/temp_board']


def test_live_readings_are_stamped_in_publish_order_whatever_the_callback_order():
    clock = LiveImuClock(1, history=3)
    clock.add_reading(0, 5, 20.0)            # published before any IMU message: left out
    clock.add_imu([10, 20], [1000, 2000])
    clock.add_reading(0, 25, 21.0)           # after every IMU seen: waits
    clock.add_reading(0, 15, 22.0)           # taken late, published between them
    got = clock.take(0)
    assert got.temperature.tolist() == [22.0] and got.stamp_ns.tolist() == [1000]
    assert clock.left_out == 1
    clock.add_imu([30], [3000])
    got = clock.take(0)
    assert got.temperature.tolist() == [21.0] and got.stamp_ns.tolist() == [2000]
    clock.add_reading(0, 35, 23.0)
    assert len(clock.take(0)) == 0
    got = clock.take(0, everything=True)     # the end of a stream: the newest stamp
    assert got.stamp_ns.tolist() == [3000]
    clock.add_imu([40, 50, 60, 70], [4000, 5000, 6000, 7000])   # history 3: the newest 3
    clock.add_reading(0, 12, 24.0)
    assert clock.take(0).stamp_ns.tolist() == [5000]   # before all kept: the oldest's
    clock.add_imu([65], [6500])              # another publisher's clock: sorted in
    clock.add_reading(0, 66, 25.0)
    assert clock.take(0).stamp_ns.tolist() == [6500]


def test_the_silent_input_hint_names_a_headerless_temp_topic_and_its_type():
    # a um7 driver under a namespace: /robot/imu/temperature is std_msgs/Float32 while the
    # node listens on /imu/temperature; a Float32 that is not named temp* is not offered
    from types import SimpleNamespace
    from thermal_imu_calib.nodes import input_hints
    graph = [('/robot/imu/temperature', ['std_msgs/msg/Float32']),
             ('/battery/voltage', ['std_msgs/msg/Float32']),
             ('/imu/temperature', ['sensor_msgs/msg/Temperature'])]
    node = SimpleNamespace(get_topic_names_and_types=lambda: graph)
    ours = [SimpleNamespace(topic_name='/imu/temperature')]
    assert input_hints.thermal_topics_hint(node, ours) == (
        "; thermal-input topics on the graph: /robot/imu/temperature (set temperature_topics:="
        "'[/robot/imu/temperature]' temperature_types:='[std_msgs/msg/Float32]')")


def test_live_stamps_equal_the_offline_rule_for_any_delivery_order():
    # one publish sequence; the two topics delivered in random batches, each topic in order
    # (as DDS delivers one topic) but the topics interleaved at random (as the executor
    # runs the callbacks): the live clock gives what on_imu_clock gives the log
    rng = np.random.default_rng(7)
    is_imu = rng.random(3000) < 0.7
    source = np.cumsum(rng.integers(1, 1000, 3000))
    imu_src, imu_stamp = source[is_imu], 10 ** 12 + 5 * source[is_imu]
    read_src, values = source[~is_imu], rng.normal(30.0, 5.0, int((~is_imu).sum()))
    want = on_imu_clock(values, np.searchsorted(imu_src, read_src), imu_stamp, None)
    clock = LiveImuClock(1, history=1000)    # the lag stays under it (else: the oldest's)
    got, i, j = [], 0, 0
    while i < len(imu_src) or j < len(read_src):
        if i < len(imu_src) and (j == len(read_src) or rng.random() < 0.5):
            k = int(rng.integers(1, 40))
            clock.add_imu(imu_src[i:i + k].tolist(), imu_stamp[i:i + k].tolist())
            i += k
        else:
            for s, v in zip(read_src[j:j + 10].tolist(), values[j:j + 10].tolist()):
                clock.add_reading(0, s, v)
            j += 10
        got.append(clock.take(0))
    got.append(clock.take(0, everything=True))
    np.testing.assert_array_equal(np.concatenate([g.stamp_ns for g in got]), want.stamp_ns)
    np.testing.assert_array_equal(np.concatenate([g.temperature for g in got]),
                                  want.temperature)
    assert clock.left_out == len(values) - len(want)
