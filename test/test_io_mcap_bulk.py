"""Bulk MCAP reader/writer: byte-level round trips, cross-checks and damaged files.

Every file the bulk writer produces is read back with the ``mcap`` library (chunk,
summary and data-section CRCs validated), with rosbags and with the bulk reader; files
written by the ``mcap`` library (several compressions, schemas inside chunks, chunks
overlapping in time, no message indexes) are read by the bulk reader and must give
exactly what rosbags gives.
"""

import struct

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag import copy_and_stream, open_log
from thermal_imu_calib.io.bag_writer import LogWriter
from thermal_imu_calib.io.log_info import LogError
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
from thermal_imu_calib.io.mcap_read import iter_batches, McapBulkReader, McapFormatError
from thermal_imu_calib.io.mcap_source import McapBulkSource

STORE = get_typestore(Stores.ROS2_JAZZY)
T0 = 1_700_000_000_000_000_000


def _content(n=3000, seed=0):
    """Imu at 1 kHz, Temperature at 10 Hz and a std_msgs/String topic, as raw CDR."""
    rng = np.random.default_rng(seed)
    st = T0 + np.arange(n, dtype=np.int64) * 1_000_000
    imu = cdr.encode_imu(ImuColumns(st, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                                    'imu_link'))
    ts = st[::100]
    temp = cdr.encode_temperature(TemperatureColumns(ts, 20 + rng.normal(size=len(ts)), 'imu'))
    string = STORE.types['std_msgs/msg/String']
    text = [bytes(STORE.serialize_cdr(string(data='x' * int(k)), 'std_msgs/msg/String'))
            for k in rng.integers(0, 40, len(ts))]
    return {'/imu': ('sensor_msgs/msg/Imu', st, imu),
            '/temp': ('sensor_msgs/msg/Temperature', ts, temp),
            '/text': ('std_msgs/msg/String', ts + 500_000, text)}


def _events(content):
    """All messages as (log_time, topic, raw), in a log-time order with stable ties."""
    ev = [(int(t), topic, raw) for topic, (_, ts, raws) in content.items()
          for t, raw in zip(ts, raws)]
    return sorted(ev, key=lambda e: e[0])


def _write_bulk(path, content, compression='none'):
    with LogWriter(path, compression=compression) as w:
        for topic, (msgtype, _, _) in content.items():
            w.add_topic(topic, msgtype)
        for t, topic, raw in _events(content):
            w.write(topic, t, raw)


def _write_mcap_lib(path, content, compression=CompressionType.ZSTD, chunk_size=20000,
                    index_types=IndexType.ALL, order=None):
    with open(path, 'wb') as f:
        w = Writer(f, compression=compression, chunk_size=chunk_size, index_types=index_types)
        w.start(profile='ros2', library='test')
        ids = {}
        for topic, (msgtype, _, _) in content.items():
            msgdef = STORE.generate_msgdef(msgtype, ros_version=2)[0]
            sid = w.register_schema(msgtype, 'ros2msg', msgdef.encode())
            ids[topic] = w.register_channel(topic, 'cdr', sid, {
                'offered_qos_profiles': '', 'topic_type_hash': STORE.hash_rihs01(msgtype)})
        ev = _events(content) if order is None else order(_events(content))
        for seq, (t, topic, raw) in enumerate(ev):
            w.add_message(ids[topic], log_time=t, data=raw, publish_time=t, sequence=seq)
        w.finish()


def _rosbags(path):
    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def _mcap_lib(path):
    with open(path, 'rb') as f:
        r = make_reader(f, validate_crcs=True)
        out = [(ch.topic, m.log_time, m.data, m.publish_time, m.sequence)
               for _, ch, m in r.iter_messages(log_time_order=True)]
    with open(path, 'rb') as f:  # every record, chunk and data-section CRCs checked
        list(StreamReader(f, validate_crcs=True).records)
    return out


def _bulk(path):
    with open_log(path) as log:
        assert isinstance(log._src, McapBulkSource)
        return [(topic, t, raw) for topic, _, t, raw in log.iter_raw()]


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_bulk_writer_output_reads_back_identically_everywhere(tmp_path, compression):
    content = _content()
    ours, ref = tmp_path / 'ours.mcap', tmp_path / 'ref.mcap'
    _write_bulk(ours, content, compression)
    _write_mcap_lib(ref, content)
    expected = [(topic, t, raw) for t, topic, raw in _events(content)]
    lib = _mcap_lib(ours)
    assert [m[:3] for m in lib] == expected
    assert _rosbags(ours) == expected
    assert _bulk(ours) == expected
    # the mcap library's writer gives the same messages, schemas and channels
    assert [m[:3] for m in _mcap_lib(ref)] == expected
    with open(ours, 'rb') as a, open(ref, 'rb') as b:
        sa, sb = make_reader(a).get_summary(), make_reader(b).get_summary()
    assert sa.statistics.message_count == sb.statistics.message_count == len(expected)
    assert sorted((s.name, s.encoding, s.data) for s in sa.schemas.values()) == sorted(
        (s.name, s.encoding, s.data) for s in sb.schemas.values())
    assert sorted((c.topic, c.message_encoding, c.metadata['topic_type_hash'])
                  for c in sa.channels.values()) == sorted(
        (c.topic, c.message_encoding, c.metadata['topic_type_hash'])
        for c in sb.channels.values())
    assert sa.statistics.message_start_time == T0
    assert len(sa.chunk_indexes) >= 1
    # per-topic sequence numbers count up from 1, publish time = log time
    seqs = [m[4] for m in lib if m[0] == '/imu']
    assert seqs == list(range(1, len(seqs) + 1))
    assert all(m[3] == m[1] for m in lib)


@pytest.mark.parametrize('compression', [CompressionType.NONE, CompressionType.ZSTD,
                                         CompressionType.LZ4])
def test_bulk_reader_matches_rosbags_on_mcap_library_files(tmp_path, compression):
    content = _content()
    path = tmp_path / 'lib.mcap'
    _write_mcap_lib(path, content, compression)  # schemas/channels sit inside chunks
    assert _bulk(path) == _rosbags(path)
    with open_log(path) as log:
        assert isinstance(log._src, McapBulkSource)
        chunks = list(log.stream('/imu', ['/temp'], chunk_size=700))
    imu = ImuColumns.concat([c.imu for c in chunks])
    ref = cdr.decode_imu(content['/imu'][2])
    np.testing.assert_array_equal(imu.stamp_ns, ref.stamp_ns)
    np.testing.assert_array_equal(imu.accel, ref.accel)
    np.testing.assert_array_equal(imu.gyro, ref.gyro)
    assert imu.frame_id == 'imu_link'
    assert max(len(c) for c in chunks) == 700
    temps = np.concatenate([c.temps['/temp'].temperature for c in chunks])
    np.testing.assert_array_equal(temps, cdr.decode_temperature(content['/temp'][2])
                                  .temperature)


def test_overlapping_chunks_ties_and_no_message_index_match_rosbags(tmp_path):
    content = _content(2000, seed=1)

    def shuffle_locally(ev):
        rng = np.random.default_rng(3)
        # messages out of order within +-50 places: chunks overlap in time; equal times
        key = np.arange(len(ev)) + rng.integers(-50, 50, len(ev))
        ev = [ev[i] for i in np.argsort(key, kind='stable')]
        return [(ev[i][0] // 3_000_000 * 3_000_000, ev[i][1], ev[i][2])
                for i in range(len(ev))]
    got = {}
    for k, index_types in enumerate((IndexType.ALL, IndexType.CHUNK)):
        path = tmp_path / f'overlap{k}.mcap'
        _write_mcap_lib(path, content, CompressionType.NONE, 4000, index_types,
                        shuffle_locally)
        got[k] = _bulk(path)
        if k == 0:
            want = _rosbags(path)  # rosbags needs message indexes: compare with file 0
    assert len(want) == sum(len(v[1]) for v in content.values())
    assert got[0] == want
    assert got[1] == want  # no message index: every record walked


def test_copy_and_stream_copies_every_record_byte_for_byte(tmp_path):
    content = _content()
    src, dst = tmp_path / 'in.mcap', tmp_path / 'out.mcap'
    _write_mcap_lib(src, content, CompressionType.LZ4)
    with open_log(src) as log, LogWriter(dst) as w:
        w.add_topic('/new', 'sensor_msgs/msg/Imu')
        n = 0
        for ch in copy_and_stream(log, w, '/imu', ['/temp'], chunk_size=500):
            w.write_many('/new', ch.imu_log_time_ns, ch.imu_raw)
            n += len(ch)
    assert n == 3000
    with open(src, 'rb') as f:
        before = [(ch.topic, m.log_time, m.publish_time, m.sequence, m.data)
                  for _, ch, m in make_reader(f).iter_messages(log_time_order=True)]
    after = _mcap_lib(dst)
    copied = [(m[0], m[1], m[3], m[4], m[2]) for m in after if m[0] != '/new']
    assert copied == before
    assert [m[2] for m in after if m[0] == '/new'] == content['/imu'][2]


def _chunk_offsets(path):
    with McapBulkReader(path) as r:
        return [(c.chunk_start_offset, c.compression) for c in r.summary.chunk_indexes]


def _corrupt(path, at, data):
    raw = bytearray(path.read_bytes())
    raw[at:at + len(data)] = data
    path.write_bytes(bytes(raw))


def _read_all(path):
    with open_log(path) as log:
        return list(log.stream('/imu', ['/temp']))


def test_damaged_chunks_give_clear_errors_naming_chunk_and_offset(tmp_path):
    content = _content()
    # bad CRC: flip one payload byte of an uncompressed chunk
    path = tmp_path / 'crc.mcap'
    _write_bulk(path, content)
    off, _ = _chunk_offsets(path)[0]
    raw = bytearray(path.read_bytes())
    _corrupt(path, off + 200, bytes([raw[off + 200] ^ 0xFF]))
    with pytest.raises(LogError, match=rf'chunk 0 at byte {off}: CRC mismatch'):
        _read_all(path)
    # corrupt compressed data
    path = tmp_path / 'zstd.mcap'
    _write_bulk(path, content, 'zstd')
    off, comp = _chunk_offsets(path)[0]
    assert comp == 'zstd'
    _corrupt(path, off + 9 + 40 + 4 + 20, b'\xde\xad\xbe\xef' * 4)
    with pytest.raises(LogError, match=rf'chunk 0 at byte {off}: (cannot decompress|CRC)'):
        _read_all(path)
    # unknown compression (same length so every offset stays valid)
    path = tmp_path / 'comp.mcap'
    _write_bulk(path, content, 'zstd')
    raw = path.read_bytes().replace(b'\x04\x00\x00\x00zstd', b'\x04\x00\x00\x00brot', 1)
    path.write_bytes(raw)
    with pytest.raises(LogError, match=r"chunk 0 at byte \d+: unknown compression 'brot'"):
        _read_all(path)


def test_truncated_chunk_is_refused_not_read_short(tmp_path):
    content = _content()
    path = tmp_path / 'cut.mcap'
    _write_bulk(path, content)
    offs = _chunk_offsets(path)
    # the chunk index promises more bytes than the file holds
    with McapBulkReader(path) as r:
        index = r.summary.chunk_indexes[-1]
        cut = index.chunk_start_offset + index.chunk_length // 2
        data = path.read_bytes()
    bad = tmp_path / 'short.mcap'
    with open(bad, 'wb') as f:
        f.write(data[:cut])
    with pytest.raises(LogError):  # no footer: rosbags refuses the file as a whole
        _read_all(bad)
    with McapBulkReader(path) as r, open(path, 'rb') as f:
        r._file = open(bad, 'rb')
        try:
            with pytest.raises(McapFormatError,
                               match=rf'chunk {len(offs) - 1} at byte '
                                     rf'{index.chunk_start_offset}: truncated'):
                list(iter_batches(r))
        finally:
            r._file.close()


def test_records_that_overrun_the_chunk_are_refused(tmp_path):
    content = _content(500)
    path = tmp_path / 'len.mcap'
    _write_mcap_lib(path, content, CompressionType.NONE, 1 << 20, IndexType.CHUNK)
    off, _ = _chunk_offsets(path)[0]
    records = off + 9 + 8 + 8 + 8 + 4 + 4 + 8  # start of the uncompressed records
    # blow up the first record's length field and recompute the chunk CRC
    raw = bytearray(path.read_bytes())
    rec_len = struct.unpack_from('<Q', raw, off + 9 + 16)[0]
    struct.pack_into('<Q', raw, records + 1, 1 << 30)
    import zlib
    struct.pack_into('<I', raw, off + 9 + 24, zlib.crc32(bytes(raw[records:records + rec_len])))
    path.write_bytes(bytes(raw))
    with pytest.raises(LogError, match=rf'chunk 0 at byte {off}:'):
        _read_all(path)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_rosbag2_directory_with_mcap_storage_reads_in_bulk(tmp_path, compression):
    content = _content(800)
    path = tmp_path / 'bag'
    with LogWriter(path, storage='mcap', compression=compression) as w:
        for topic, (msgtype, _, _) in content.items():
            w.add_topic(topic, msgtype)
        for t, topic, raw in _events(content):
            w.write(topic, t, raw)
    assert _bulk(path) == _rosbags(path) == [(topic, t, raw)
                                             for t, topic, raw in _events(content)]


def test_data_section_crc_when_asked_validates_with_the_mcap_library(tmp_path):
    from thermal_imu_calib.io.mcap_write import McapBulkWriter
    content = _content(500)
    path = tmp_path / 'crc.mcap'
    with open(path, 'wb') as f:
        w = McapBulkWriter(f, compression='lz4', chunk_size=5000, data_crc=True)
        sid = w.add_schema('sensor_msgs/msg/Imu', 'ros2msg', b'')
        cid = w.add_channel('/imu', 'cdr', sid)
        _, st, raws = content['/imu']
        w.add_messages(cid, st, raws)
        w.finish()
    with open(path, 'rb') as f:
        data_end = [r for r in StreamReader(f, validate_crcs=True).records
                    if type(r).__name__ == 'DataEnd']
    assert data_end[0].data_section_crc != 0
    assert [m[2] for m in _mcap_lib(path)] == raws
    with open(path, 'rb') as f:  # a flipped byte inside a chunk fails the library's check
        raw = bytearray(f.read())
    raw[200] ^= 0xFF
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(raw))
    with open(bad, 'rb') as f, pytest.raises(Exception):
        list(StreamReader(f, validate_crcs=True).records)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_sqlite3_write_many_equals_per_message_writes(tmp_path, compression):
    content = _content(600)
    logs = {}
    for how in ('many', 'single'):
        path = tmp_path / how
        with LogWriter(path, storage='sqlite3', compression=compression) as w:
            for topic, (msgtype, _, _) in content.items():
                w.add_topic(topic, msgtype)
            for topic, (_, ts, raws) in content.items():
                if how == 'many':
                    w.write_many(topic, ts, raws)
                else:
                    for t, raw in zip(ts, raws):
                        w.write(topic, int(t), raw)
        logs[how] = path
    expected = [(topic, t, raw) for t, topic, raw in _events(content)]
    for path in logs.values():
        got = _rosbags(path)
        assert sorted(got, key=lambda e: e[1]) == sorted(expected, key=lambda e: e[1])
        with Reader(path) as r:
            assert r.message_count == len(expected)
            assert {c.topic: c.msgcount for c in r.connections} == {
                t: len(v[1]) for t, v in content.items()}
            assert r.start_time == T0


def test_compensate_bulk_path_gives_the_per_message_path_bytes(tmp_path):
    from thermal_imu_calib import sim
    from thermal_imu_calib.calibration import Calibration
    from thermal_imu_calib.app.compensate import compensate_log
    src = tmp_path / 'demo.mcap'
    sim.write_scenario(str(src), 'demo', 0)
    cal = Calibration.load(str(src) + '.truth.yaml')
    db = tmp_path / 'demo_db'  # the same log in sqlite3: read message by message (rosbags)
    with open_log(src) as log, LogWriter(db, storage='sqlite3') as w:
        for topic, msgtype in log.topic_types().items():
            w.add_topic(topic, msgtype)
        for topic, _, t, raw in log.iter_raw():
            w.write(topic, t, raw)
    outs = {}
    for name, path in (('bulk', src), ('per_message', db)):
        with open_log(path) as log:
            assert isinstance(log._src, McapBulkSource) == (name == 'bulk')
        out = tmp_path / f'{name}.mcap'
        stats = compensate_log(path, out, cal, chunk_size=3000, progress=False)
        assert stats['imu_out'] == stats['imu_in'] > 20000
        outs[name] = _mcap_lib(out)
    assert [m[:3] for m in outs['bulk']] == [m[:3] for m in outs['per_message']]
    comp = [m for m in outs['bulk'] if m[0] == '/imu/data_compensated']
    raw = [m for m in outs['bulk'] if m[0] == '/imu/data_raw']
    assert len(comp) == len(raw) and comp[0][2] != raw[0][2]
    a = cdr.decode_imu([m[2] for m in comp])
    b = cdr.decode_imu([m[2] for m in raw])
    np.testing.assert_array_equal(a.stamp_ns, b.stamp_ns)
    assert np.max(np.abs(a.accel - b.accel)) > 0


def test_one_large_write_is_cut_into_chunks_of_about_chunk_size(tmp_path):
    from thermal_imu_calib.io.mcap_write import McapBulkWriter
    content = _content(5000)
    _, st, raws = content['/imu']
    path = tmp_path / 'cut.mcap'
    with open(path, 'wb') as f:
        w = McapBulkWriter(f, chunk_size=100_000)
        cid = w.add_channel('/imu', 'cdr', w.add_schema('sensor_msgs/msg/Imu', 'ros2msg', b''))
        w.add_messages(cid, st, raws)
        w.finish()
    with McapBulkReader(path) as r:
        sizes = [c.uncompressed_size for c in r.summary.chunk_indexes]
    record = len(raws[0]) + 31
    assert len(sizes) == -(-5000 * record // 100_000) or len(sizes) == 5000 * record // 100_000 + 1
    assert max(sizes) < 100_000 + record
    assert [m[2] for m in _mcap_lib(path)] == raws
