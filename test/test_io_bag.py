"""Log readers/writers against real files and independent readers (rosbags, mcap_ros2)."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import get_typestore, Stores

from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag import copy_and_stream, open_log
from thermal_imu_calib.io.bag_writer import LogWriter, write_columns
from thermal_imu_calib.io.log_info import LogError
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
IMU, TEMP, STR = cdr.IMU_MSGTYPE, cdr.TEMPERATURE_MSGTYPE, 'std_msgs/msg/String'
T0 = 1_700_000_000_000_000_000
N_IMU, IMU_DT, TEMP_EVERY = 1500, 5_000_000, 20  # 200 Hz IMU, 10 Hz temperature


def _hdr(stamp, frame):
    sec, nsec = divmod(int(stamp), 1_000_000_000)
    return T['std_msgs/msg/Header'](T['builtin_interfaces/msg/Time'](sec, nsec), frame)


def _log_messages(seed=0):
    """Return [(topic, msgtype, log_time, raw)] of a small realistic log, log-time sorted."""
    rng = np.random.default_rng(seed)
    v3, q = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Quaternion']
    out = []
    for i in range(N_IMU):
        stamp = T0 + i * IMU_DT
        msg = T[IMU](_hdr(stamp, 'imu_link'), q(*rng.normal(size=4)), rng.normal(size=9),
                     v3(*rng.normal(size=3)), rng.normal(size=9), v3(*rng.normal(size=3)),
                     rng.normal(size=9))
        out.append(('/imu', IMU, stamp + 300_000, bytes(TS.serialize_cdr(msg, IMU))))
        if i % TEMP_EVERY == 0:
            for topic, base in (('/temp_a', 20.0), ('/temp_b', 30.0)):
                tmsg = T[TEMP](_hdr(stamp + 1_000_000, 'board'), base + i * 1e-3, 0.01)
                out.append((topic, TEMP, stamp + 1_200_000, bytes(TS.serialize_cdr(tmsg, TEMP))))
        if i % 500 == 0:
            out.append(('/note', STR, stamp + 2_000_000,
                        bytes(TS.serialize_cdr(T[STR](f'note {i}'), STR))))
    out.sort(key=lambda m: m[2])
    return out


@pytest.fixture(scope='module')
def messages():
    return _log_messages()


def _write_rosbags(path, msgs, storage):
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {}
        for topic, msgtype, t, raw in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=TS)
            w.write(conns[topic], t, raw)


def _write_mcap_ros2(path, msgs):
    """Bare MCAP written by mcap_ros2 (serializing from dicts, like a third-party tool)."""
    from mcap_ros2.writer import Writer as Ros2Writer

    with open(path, 'wb') as f:
        w = Ros2Writer(f)
        schemas = {}
        for topic, msgtype, t, raw in msgs:
            if msgtype not in schemas:
                schemas[msgtype] = w.register_msgdef(
                    msgtype, TS.generate_msgdef(msgtype, ros_version=2)[0])
            w.write_message(topic, schemas[msgtype], _to_dict(TS.deserialize_cdr(raw, msgtype)),
                            log_time=t, publish_time=t)
        w.finish()


def _to_dict(msg):
    if hasattr(msg, '__msgtype__'):
        return {k: _to_dict(getattr(msg, k)) for k in msg.__dataclass_fields__
                if k != '__msgtype__'}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    return msg


@pytest.fixture(scope='module', params=['rosbag2-sqlite3', 'rosbag2-mcap', 'bare-db3',
                                        'bare-mcap-ros2'])
def log_path(request, tmp_path_factory, messages):
    base = tmp_path_factory.mktemp(request.param)
    if request.param == 'bare-mcap-ros2':
        path = base / 'log.mcap'
        _write_mcap_ros2(path, messages)
        return path
    storage = request.param.split('-')[-1]
    _write_rosbags(base / 'bag', messages, 'sqlite3' if storage == 'db3' else storage)
    if storage == 'db3':
        return next((base / 'bag').glob('*.db3'))
    return base / 'bag'


def _ref_imu(msgs):
    raws = [m[3] for m in msgs if m[0] == '/imu']
    dec = [TS.deserialize_cdr(r, IMU) for r in raws]
    stamps = [d.header.stamp.sec * 10**9 + d.header.stamp.nanosec for d in dec]
    accel = [[d.linear_acceleration.x, d.linear_acceleration.y, d.linear_acceleration.z]
             for d in dec]
    return np.array(stamps), np.array(accel), raws


def test_topics_and_iter_raw(log_path, messages):
    with open_log(log_path) as log:
        info = log.topics()
        assert {k: (v.msgtype, v.count) for k, v in info.items()} == {
            '/imu': (IMU, N_IMU), '/temp_a': (TEMP, N_IMU // TEMP_EVERY),
            '/temp_b': (TEMP, N_IMU // TEMP_EVERY), '/note': (STR, 3)}
        got = list(log.iter_raw())
        assert [(m[0], m[1], m[2]) for m in got] == [(m[0], m[1], m[2]) for m in messages]
        assert [bytes(m[3]) for m in got] == [m[3] for m in messages]
        only = list(log.iter_raw(['/note']))
        assert [m[3] for m in only] == [m[3] for m in messages if m[0] == '/note']
        scanned = log.topics(scan=True)['/imu']
        assert scanned.first_log_time_ns == T0 + 300_000
        assert scanned.last_log_time_ns == T0 + (N_IMU - 1) * IMU_DT + 300_000


def test_stream_chunks_match_reference(log_path, messages):
    stamps, accel, raws = _ref_imu(messages)
    with open_log(log_path) as log:
        chunks = list(log.stream('/imu', ['/temp_a', '/temp_b'], chunk_size=400, keep_raw=True))
    assert [len(c) for c in chunks] == [400, 400, 400, 300]
    np.testing.assert_array_equal(np.concatenate([c.imu.stamp_ns for c in chunks]), stamps)
    np.testing.assert_array_equal(np.concatenate([c.imu.accel for c in chunks]), accel)
    np.testing.assert_array_equal(np.concatenate([c.imu_log_time_ns for c in chunks]),
                                  stamps + 300_000)
    assert [bytes(r) for c in chunks for r in c.imu_raw] == raws
    assert chunks[0].imu.frame_id == 'imu_link'
    # Temperature samples land in the chunk during which they were logged.
    for c in chunks:
        assert list(c.temps) == ['/temp_a', '/temp_b']
        ta = c.temps['/temp_a']
        assert ta.frame_id == 'board'
        assert np.all(ta.stamp_ns + 200_000 <= c.imu_log_time_ns[-1])
    allt = np.concatenate([c.temps['/temp_b'].temperature for c in chunks])
    np.testing.assert_allclose(allt, 30.0 + np.arange(0, N_IMU, TEMP_EVERY) * 1e-3)
    with open_log(log_path) as log:
        assert all(c.imu_raw is None for c in log.stream('/imu', chunk_size=1000))


def test_info_reports_rates_and_temperatures(log_path):
    with open_log(log_path) as log:
        info = log.info()
    imu = info.topics['/imu']
    assert imu.rate_hz == pytest.approx(200.0)
    assert imu.mean_rate_hz == pytest.approx(200.0)
    assert imu.max_gap_s == pytest.approx(0.005)
    assert imu.stamps_backwards == 0 and imu.frame_id == 'imu_link'
    ta = info.topics['/temp_a']
    assert ta.rate_hz == pytest.approx(10.0)
    assert ta.temperature_min == pytest.approx(20.0)
    assert ta.temperature_max == pytest.approx(20.0 + (N_IMU - TEMP_EVERY) * 1e-3)
    assert info.topics['/note'].rate_hz is None and info.topics['/note'].count == 3
    assert info.message_count == N_IMU + 2 * (N_IMU // TEMP_EVERY) + 3
    assert info.duration_s == pytest.approx((N_IMU - 1) * 0.005, abs=0.01)
    text = info.format()
    assert '/temp_a' in text and 'degC' in text and 'Hz' in text
    assert info.topics_of_type(TEMP) == ['/temp_a', '/temp_b']


def test_reader_errors_are_explained(tmp_path, log_path):
    with pytest.raises(LogError, match='no such file'):
        open_log(tmp_path / 'missing.mcap')
    (tmp_path / 'x.bag').write_bytes(b'#ROSBAG V2.0')
    with pytest.raises(LogError, match="unknown log format '.bag'.*rosbags-convert"):
        open_log(tmp_path / 'x.bag')
    (tmp_path / 'dir').mkdir()
    (tmp_path / 'dir' / 'a.mcap').write_bytes(b'')
    with pytest.raises(LogError, match='no metadata.yaml.*reindex'):
        open_log(tmp_path / 'dir')
    (tmp_path / 'broken.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(LogError, match='cannot read'):
        open_log(tmp_path / 'broken.mcap')
    with open_log(log_path) as log:
        with pytest.raises(LogError, match=r"'/nope' is not in .*/imu \[sensor_msgs/msg/Imu\]"):
            list(log.stream('/nope'))
        with pytest.raises(LogError, match='expected sensor_msgs/msg/Imu'):
            list(log.stream('/temp_a'))
        with pytest.raises(LogError, match='expected sensor_msgs/msg/Temperature'):
            list(log.stream('/imu', ['/note']))
        with pytest.raises(LogError, match='distinct'):
            list(log.stream('/imu', ['/temp_a', '/temp_a']))


def test_write_columns_read_back_by_other_readers(tmp_path):
    n = 700
    stamps = T0 + np.arange(n, dtype=np.int64) * 2_500_000
    rng = np.random.default_rng(5)
    imu = ImuColumns(stamps, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), 'imu')
    temp = TemperatureColumns(stamps[::50] + 1, 25.0 + np.arange(14) * 0.5, 'die')
    chunks = [imu.slice(slice(0, 300)), imu.slice(slice(300, None))]
    halves = [TemperatureColumns(temp.stamp_ns[:5], temp.temperature[:5], 'die'),
              TemperatureColumns(temp.stamp_ns[5:], temp.temperature[5:], 'die')]

    bare = tmp_path / 'sim.mcap'
    counts = write_columns(bare, '/imu', chunks, {'/imu_temp': halves}, gyro_cov=1e-6)
    assert counts == {'/imu': n, '/imu_temp': 14}
    with open(bare, 'rb') as f:  # independent reader 1: mcap + mcap_ros2 decoder
        rows = list(make_reader(f, decoder_factories=[DecoderFactory()])
                    .iter_decoded_messages(log_time_order=True))
    imu_rows = [r for r in rows if r.channel.topic == '/imu']
    assert [r.message.log_time for r in imu_rows] == stamps.tolist()
    m = imu_rows[3].decoded_message
    assert m.header.frame_id == 'imu'
    assert (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec) == stamps[3]
    assert [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] == \
        imu.accel[3].tolist()
    assert list(m.orientation_covariance)[:2] == [-1.0, 0.0]
    assert list(m.angular_velocity_covariance)[::4] == [1e-6] * 3
    log_times = [r.message.log_time for r in rows]
    assert log_times == sorted(log_times)  # interleaved by stamp while streaming
    t_rows = [r.decoded_message for r in rows if r.channel.topic == '/imu_temp']
    assert [x.temperature for x in t_rows] == temp.temperature.tolist()
    assert t_rows[0].header.frame_id == 'die'

    for storage in ('mcap', 'sqlite3'):  # independent reader 2: rosbags AnyReader
        path = tmp_path / f'sim_{storage}'
        write_columns(path, '/imu', imu, {'/imu_temp': temp}, storage=storage)
        with AnyReader([path]) as reader:  # verifies definitions against type hashes
            conns = {c.topic: c for c in reader.connections}
            assert conns['/imu'].digest == TS.hash_rihs01(IMU)
            got = [(t, reader.deserialize(raw, c.msgtype))
                   for c, t, raw in reader.messages([conns['/imu']])]
        assert [t for t, _ in got] == stamps.tolist()
        assert got[10][1].header.frame_id == 'imu'
        assert got[10][1].angular_velocity.z == imu.gyro[10, 2]


def test_writer_errors_and_overwrite(tmp_path):
    out = tmp_path / 'o.mcap'
    with LogWriter(out) as w:
        w.add_topic('/imu', IMU)
        w.add_topic('/imu', IMU)  # idempotent
        with pytest.raises(LogError, match='already added as'):
            w.add_topic('/imu', TEMP)
        with pytest.raises(LogError, match=r"call add_topic\('/x', msgtype\)"):
            w.write('/x', 0, b'')
        with pytest.raises(LogError, match='not a ROS 2 Jazzy standard type'):
            w.add_topic('/c', 'my_pkg/msg/Thing')
    with pytest.raises(LogError, match='exists already'):
        LogWriter(out)
    with LogWriter(out, overwrite=True) as w:
        w.add_topic('/t', TEMP)
        w.write_many('/t', [5, 6], cdr.encode_temperature(
            TemperatureColumns(np.array([5, 6]), np.array([1.0, 2.0]))))
    with open_log(out) as log:
        assert log.topic_types() == {'/t': TEMP} and log.message_count == 2
    with pytest.raises(LogError, match='bare .db3 output is not supported'):
        LogWriter(tmp_path / 'x.db3')
    keep = tmp_path / 'keep'
    keep.mkdir()
    (keep / 'thesis.tex').write_text('precious')
    with pytest.raises(LogError, match='refusing to delete'):
        LogWriter(keep, overwrite=True)
    assert (keep / 'thesis.tex').exists()


@pytest.mark.parametrize('out_name,storage', [('out.mcap', 'mcap'), ('out_dir', 'sqlite3')])
def test_copy_and_stream_builds_compensate(tmp_path, messages, out_name, storage):
    src = tmp_path / 'in'
    _write_rosbags(src, messages, 'mcap')
    out = tmp_path / out_name
    with open_log(src) as log, LogWriter(out, storage) as w:
        w.add_topic('/imu_comp', IMU)
        seen = 0
        for chunk in copy_and_stream(log, w, '/imu', ['/temp_a'], chunk_size=256):
            patched = cdr.patch_imu(chunk.imu_raw, chunk.imu.accel + 1.0, chunk.imu.gyro * 2)
            w.write_many('/imu_comp', chunk.imu_log_time_ns, patched)
            seen += len(chunk)
    assert seen == N_IMU
    with Reader(out) as r:  # rosbags reads both bare .mcap and rosbag2 dirs
        got = [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]
        types = {c.topic: c.msgtype for c in r.connections}
    assert types == {'/imu': IMU, '/temp_a': TEMP, '/temp_b': TEMP, '/note': STR,
                     '/imu_comp': IMU}
    copied = [g for g in got if g[0] != '/imu_comp']
    assert copied == [(m[0], m[2], m[3]) for m in messages]  # verbatim and in order
    comp = [g for g in got if g[0] == '/imu_comp']
    originals = [m for m in messages if m[0] == '/imu']
    assert [g[1] for g in comp] == [m[2] for m in originals]
    for (_, _, new), (_, _, _, old) in list(zip(comp, originals))[::97]:
        a, b = TS.deserialize_cdr(new, IMU), TS.deserialize_cdr(old, IMU)
        assert a.header == b.header and a.orientation == b.orientation
        np.testing.assert_array_equal(a.linear_acceleration_covariance,
                                      b.linear_acceleration_covariance)
        assert a.linear_acceleration.x == b.linear_acceleration.x + 1.0
        assert a.angular_velocity.y == b.angular_velocity.y * 2
    if storage == 'sqlite3':
        with AnyReader([out]) as reader:  # hashes of copied definitions are consistent
            assert {c.topic for c in reader.connections} == set(types)


def test_copy_refuses_clashing_output_topic(tmp_path, messages):
    src = tmp_path / 'in'
    _write_rosbags(src, messages[:50], 'sqlite3')
    with open_log(src) as log, LogWriter(tmp_path / 'o.mcap') as w:
        w.add_topic('/imu', IMU)
        with pytest.raises(LogError, match="'/imu' also exists in the input"):
            next(copy_and_stream(log, w, '/imu'))
    with open_log(src) as log, LogWriter(tmp_path / 'o2.mcap') as w:
        w.add_topic('/imu', IMU)
        for chunk in copy_and_stream(log, w, '/imu', exclude=['/imu']):
            w.write_many('/imu', chunk.imu_log_time_ns, chunk.imu_raw)
    with open_log(tmp_path / 'o2.mcap') as log:
        assert list(log.iter_raw()) == [m for m in messages[:50]]


def test_mcap_without_ros2_profile_falls_back_to_mcap_library(tmp_path, messages):
    from mcap.writer import Writer as McapWriter

    path = tmp_path / 'foreign.mcap'
    with open(path, 'wb') as f:
        w = McapWriter(f)
        w.start(profile='', library='other-tool')
        sid = w.register_schema(IMU, 'ros2msg', TS.generate_msgdef(IMU, ros_version=2)[0]
                                .encode())
        cid = w.register_channel('/imu', 'cdr', sid)
        imu = [m for m in messages if m[0] == '/imu'][:300]
        for _, _, t, raw in imu:
            w.add_message(cid, log_time=t, data=raw, publish_time=t)
        w.finish()
    with pytest.raises(Exception, match='Profile is not ros2'):
        Reader(path).open()
    with open_log(path) as log:
        assert log.topic_types() == {'/imu': IMU}
        chunks = list(log.stream('/imu', chunk_size=128))
    stamps, accel, _ = _ref_imu(imu)
    np.testing.assert_array_equal(np.concatenate([c.imu.stamp_ns for c in chunks]), stamps)
    np.testing.assert_array_equal(np.concatenate([c.imu.accel for c in chunks]), accel)


def test_temperature_only_spans_are_flushed(tmp_path):
    temp = TemperatureColumns(T0 + np.arange(50, dtype=np.int64) * 10**8, np.linspace(0, 5, 50))
    path = tmp_path / 't.mcap'
    write_columns(path, '/imu', [], {'/t': temp})
    with open_log(path) as log:
        chunks = list(log.stream('/imu', ['/t'], chunk_size=20))
    # the spans are cut at chunk_size; the readings wait for an IMU message to judge their
    # clock by (io.headerless.StampChoice) and, with none in the log, come at the end with
    # their own stamps
    assert [len(c.temps['/t']) for c in chunks] == [0, 0, 50]
    assert all(len(c) == 0 for c in chunks)
    np.testing.assert_array_equal(np.concatenate([c.temps['/t'].stamp_ns for c in chunks]),
                                  temp.stamp_ns)


def test_relative_topic_names_are_found_as_a_recorder_stores_them():
    # calibrator_node writes its inputs as its parameters name them (imu/temperature);
    # ros2 bag record stores them resolved, in the root namespace or under one
    from thermal_imu_calib.io.topics import in_log
    root = {'/imu/data_raw': 'Imu', '/imu/temperature': 'Temperature'}
    spaced = {'/robot1/imu/data_raw': 'Imu', '/robot1/imu/temperature': 'Temperature'}
    two = {**spaced, '/robot2/imu/temperature': 'Temperature'}
    assert in_log(root, 'imu/temperature') == '/imu/temperature'
    assert in_log(root, '/imu/temperature') == '/imu/temperature'
    assert in_log(spaced, 'imu/temperature') == '/robot1/imu/temperature'
    assert in_log(two, 'imu/temperature') == 'imu/temperature'     # ambiguous: as given
    assert in_log(root, 'temperature') == '/imu/temperature'
    assert in_log(root, '/other/temperature') == '/other/temperature'
    assert in_log({'imu/temperature': 'Temperature'}, 'imu/temperature') == 'imu/temperature'


def _robot_log(path, temperatures):
    """Write an IMU (frame imu_link) and the given {topic: frame_id} temperature topics."""
    n = 50
    stamps = 1_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    imu = ImuColumns(stamps, np.tile([0.0, 0.0, 9.8], (n, 1)), np.zeros((n, 3)), 'imu_link')
    temps = {t: TemperatureColumns(stamps[::10], np.full(5, 30.0), frame)
             for t, frame in temperatures.items()}
    write_columns(str(path), '/imu/data_raw', imu, temps)
    return str(path)


def test_the_imu_temperature_is_picked_among_a_robots_temperature_topics(tmp_path):
    # a robot's bag has a battery's or a motor's temperature too: all of them used to
    # become thermal inputs (a bias polynomial in the battery temperature: 371 ug against
    # 4.3 ug with the IMU's alone on a simulated session)
    from thermal_imu_calib.io.topics import resolve_topics
    cases = {
        'frame': ({'/battery/temperature': 'battery', '/sensors/t_imu': 'imu_link'},
                  ['/sensors/t_imu'], "header.frame_id 'imu_link'"),
        'namespace': ({'/battery/temperature': '', '/imu/temperature': ''},
                      ['/imu/temperature'], 'namespace /imu'),
        'one': ({'/battery/temperature': 'battery'}, ['/battery/temperature'],
                "frame_id 'battery' is not the IMU's"),
        'one_of_the_imu': ({'/imu/temperature': ''}, ['/imu/temperature'], None)}
    for name, (topics, want, why) in cases.items():
        notes = []
        with open_log(_robot_log(tmp_path / f'{name}.mcap', topics)) as r:
            assert resolve_topics(r, None, None, notes) == ('/imu/data_raw', want), name
            assert resolve_topics(r, None, [''])[1] == []            # '' : no input
        assert (why in notes[0]) if why else not notes, (name, notes)
    with open_log(_robot_log(tmp_path / 'none.mcap', {'/battery/temperature': 'battery',
                                                      '/motor/temperature': 'motor'})) as r:
        with pytest.raises(LogError, match=r"none is the IMU's .*--temperature-topic ''"):
            resolve_topics(r, None, None)


def test_info_says_which_topics_calibrate_would_use(tmp_path, capsys):
    from thermal_imu_calib.cli import main
    log = _robot_log(tmp_path / 'robot.mcap', {'/battery/temperature': 'battery',
                                               '/imu/temperature': 'imu_link'})
    assert main(['info', log]) == 0
    out = capsys.readouterr().out
    assert 'calibrate would use: IMU /imu/data_raw, temperature /imu/temperature\n' in out
    assert "note: temperature input /imu/temperature (header.frame_id 'imu_link'" in out
    assert main(['info', log, '--temperature-topic', '']) == 0
    assert 'temperature none' in capsys.readouterr().out
