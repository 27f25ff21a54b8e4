"""Writing rosbag2 logs (sqlite3 or mcap) from column chunks.

``LogWriter`` registers topics with their message definitions
(from the Jazzy type store) and writes serialized messages;
``write_columns`` writes ImuColumns/TemperatureColumns. An
output that would overwrite an input is refused.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
import yaml

from . import cdr
from .cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
from .headerless import encode_values, HEADERLESS_MSGTYPES, THERMAL_MSGTYPES
from .columns import ImuColumns, TemperatureColumns

from .log_info import _IDL_PREFIX, _STORAGE_SUFFIXES, LogError


# --------------------------------------------------------------------------- writers


def _jazzy_typestore():
    from rosbags.typesys import get_typestore, Stores

    return get_typestore(Stores.ROS2_JAZZY)


def _definition_from_store(msgtype: str) -> tuple[str, str]:
    store = _jazzy_typestore()
    if msgtype not in store.types:
        raise LogError(f'message type {msgtype!r} is not a ROS 2 Jazzy standard type and no '
                       'definition was given; pass msgdef= (the concatenated .msg text).')
    return store.generate_msgdef(msgtype, ros_version=2)[0], store.hash_rihs01(msgtype)


def _hash_from_definition(msgtype: str, msgdef: str) -> str:
    """Compute the RIHS01 type hash of ``msgtype`` from its (concatenated) definition."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg, get_typestore, Stores

    store = get_typestore(Stores.EMPTY)
    if msgdef.startswith(_IDL_PREFIX):
        typs = {}
        for part in msgdef.split('=' * 80 + '\n')[1:]:
            typs.update(get_types_from_idl(part.split('\n', 1)[1]))
    else:
        typs = get_types_from_msg(msgdef, msgtype)
    store.register(typs)
    return store.hash_rihs01(msgtype)


def _qos_text(qos: Sequence) -> str:
    from rosbags.rosbag2.metadata import dump_qos_v9

    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False).strip()


class LogWriter:
    """Write raw CDR messages to a bare ``.mcap`` file or a rosbag2 directory.

    ``path`` ending in ``.mcap`` gives a single MCAP file (``ros2`` profile, chunked,
    indexed); anything else a rosbag2 directory with ``storage`` 'mcap' or 'sqlite3'.
    ``compression='zstd'`` compresses MCAP chunks (or each sqlite3 message).  Use as a
    context manager; on an exception the output is left incomplete (not finalised).
    """

    def __init__(self, path, storage: str = 'mcap', *, compression: str = 'none',
                 overwrite: bool = False):
        """Create the output; refuses to replace an existing path unless ``overwrite``."""
        p = Path(path).expanduser()
        if storage not in ('mcap', 'sqlite3'):
            raise LogError(f'unknown storage {storage!r}; use "mcap" or "sqlite3".')
        if compression not in ('none', 'zstd'):
            raise LogError(f'unknown compression {compression!r}; use "none" or "zstd".')
        if p.suffix == '.db3':
            raise LogError(f'{p}: bare .db3 output is not supported; give a directory path '
                           '(rosbag2 bag with storage="sqlite3") or a .mcap file.')
        if p.exists():
            if not overwrite:
                raise LogError(f'{p} exists already; choose another output path or allow '
                               'overwriting.')
            _remove_log(p)
        p.parent.mkdir(parents=True, exist_ok=True)
        self.path = p
        self.storage = 'mcap' if p.suffix == '.mcap' else storage
        self.bare = p.suffix == '.mcap'
        self._topics: dict[str, object] = {}
        self._types: dict[str, str] = {}
        self._closed = False
        if self.bare:
            from .mcap_write import McapBulkWriter

            self._file = open(p, 'xb')
            self._mcap = McapBulkWriter(self._file, profile='ros2', library='thermal_imu_calib',
                                        compression='zstd' if compression == 'zstd' else '')
            self._schemas: dict[str, int] = {}
            self._seq: dict[str, int] = {}
            self._pending: list = []
        else:
            from rosbags.rosbag2 import Writer
            from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

            plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
            self._bag = Writer(p, version=9, storage_plugin=plugin)
            if compression == 'zstd':
                mode = CompressionMode.STORAGE if storage == 'mcap' else CompressionMode.MESSAGE
                self._bag.set_compression(mode, CompressionFormat.ZSTD)
            try:
                self._bag.open()
            except Exception as err:
                raise LogError(f'{p}: cannot create the bag: {err}; check the path and '
                               'permissions.') from err

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @property
    def topics(self) -> dict[str, str]:
        """Return ``{topic: msgtype}`` of the topics added so far."""
        return dict(self._types)

    def add_topic(self, name: str, msgtype: str, *, msgdef: str | None = None,
                  type_hash: str | None = None, qos: Sequence = ()) -> None:
        """Register a topic; definition and hash default to the ROS 2 Jazzy ones.

        ``msgdef`` is the concatenated definition text (``ros2msg``, or ``ros2idl`` when it
        starts with the IDL separator); ``qos`` are rosbags ``Qos`` objects (offered QoS).
        Adding the same topic twice with the same type is a no-op.
        """
        if name in self._types:
            if self._types[name] != msgtype:
                raise LogError(f'topic {name!r} was already added as {self._types[name]}, not '
                               f'{msgtype}; use another output topic name.')
            return
        if not msgdef:
            msgdef, type_hash = _definition_from_store(msgtype)
        if not type_hash:
            try:
                type_hash = _hash_from_definition(msgtype, msgdef)
            except Exception:
                try:
                    type_hash = _definition_from_store(msgtype)[1]
                except LogError:
                    raise LogError(f'cannot compute the type hash of {msgtype!r} from its '
                                   'definition; pass type_hash= or leave the topic out.'
                                   ) from None
        if self.bare:
            if msgtype not in self._schemas:
                enc = 'ros2idl' if msgdef.startswith(_IDL_PREFIX) else 'ros2msg'
                self._schemas[msgtype] = self._mcap.add_schema(msgtype, enc, msgdef.encode())
            meta = {'offered_qos_profiles': _qos_text(qos), 'topic_type_hash': type_hash}
            self._topics[name] = self._mcap.add_channel(name, 'cdr', self._schemas[msgtype],
                                                        meta)
            self._seq[name] = 0
        else:
            self._topics[name] = self._bag.add_connection(
                name, msgtype, msgdef=msgdef, rihs01=type_hash, offered_qos_profiles=list(qos))
        self._types[name] = msgtype

    def _handle(self, topic: str):
        try:
            return self._topics[topic]
        except KeyError:
            raise LogError(f'topic {topic!r} was not added to {self.path}; call '
                           f'add_topic({topic!r}, msgtype) first.') from None

    def write(self, topic: str, log_time_ns: int, raw: bytes) -> None:
        """Write one serialized message with the given log time."""
        handle = self._handle(topic)
        t = int(log_time_ns)
        if self.bare:
            self._seq[topic] += 1
            self._pending.append((handle, t, raw, self._seq[topic]))
            if len(self._pending) >= 4096:
                self._flush_pending()
        else:
            self._bag.write(handle, t, raw)

    def write_many(self, topic: str, log_times: Iterable[int], raws: Iterable[bytes]) -> None:
        """Write messages pairwise from ``log_times`` and ``raws``.

        ``raws`` is a sequence of bytes or an (n, size) uint8 array of equal-size payloads.
        """
        log_times = np.asarray(log_times, dtype=np.int64).tolist()
        packed = isinstance(raws, np.ndarray) and raws.ndim == 2  # (n, size) uint8 payloads
        raws = raws if packed and self.bare else [r.tobytes() for r in raws] if packed \
            else list(raws)
        if len(log_times) != len(raws):
            raise LogError(f'write_many got {len(log_times)} log times for {len(raws)} '
                           'messages; pass one log time per message.')
        handle = self._handle(topic)
        if self.bare:
            self._flush_pending()
            seq = self._seq[topic]
            self._mcap.add_messages(handle, log_times, raws,
                                    sequence=np.arange(seq + 1, seq + 1 + len(raws)))
            self._seq[topic] = seq + len(raws)
        elif self.storage == 'sqlite3' and hasattr(getattr(self._bag, 'storage', None),
                                                   'cursor') and log_times:
            _sqlite_write_many(self._bag, handle, log_times, raws)
        else:
            write = self._bag.write
            for t, raw in zip(log_times, raws):
                write(handle, t, raw)

    def _flush_pending(self) -> None:
        """Hand messages buffered by ``write`` to the bulk writer, in the order written."""
        if self._pending:
            cid, t, raw, seq = zip(*self._pending)
            self._pending = []
            self._mcap.add_messages(np.array(cid), np.array(t, np.int64), raw,
                                    sequence=np.array(seq, np.int64))

    def copy_batch(self, batch, channel_map) -> None:
        """Copy bulk-read MCAP records verbatim (bare .mcap output; input -> output ids)."""
        self._flush_pending()
        self._mcap.copy_batch(batch, channel_map)

    def close(self) -> None:
        """Finalise the output (index, summary, metadata.yaml)."""
        if self._closed:
            return
        self._closed = True
        if self.bare:
            try:
                self._flush_pending()
                self._mcap.finish()
            finally:
                self._file.close()
        else:
            self._bag.close()

    def abort(self) -> None:
        """Stop writing without finalising; the partial output stays on disk."""
        if self._closed:
            return
        self._closed = True
        if self.bare:
            self._file.close()
        else:
            self._bag.abort()


def _sqlite_write_many(bag, conn, log_times: list, raws: list) -> None:
    """One ``executemany`` into rosbags' open sqlite3 transaction (what ``write`` does)."""
    from rosbags.rosbag2.enums import CompressionMode

    if bag.compression_mode == CompressionMode.MESSAGE:
        from rosbags.rosbag2.writer import zstd
        raws = [zstd.compress(r) for r in raws]
    bag.storage.cursor.executemany(
        'INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)',
        zip([conn.id] * len(raws), log_times, raws))
    bag.counts[conn.id] += len(raws)
    bag.min_timestamp = min(min(log_times), bag.min_timestamp)
    bag.max_timestamp = max(max(log_times), bag.max_timestamp)


def _remove_log(p: Path) -> None:
    """Delete an existing output log, refusing anything that does not look like one."""
    if p.is_file() and p.suffix == '.mcap':
        p.unlink()
        return
    if p.is_dir():
        names = [x for x in p.iterdir()]
        looks = (p / 'metadata.yaml').is_file() and all(
            x.is_file() and (x.name == 'metadata.yaml' or x.suffix in _STORAGE_SUFFIXES
                             or x.name.endswith(('.zstd', '-shm', '-wal'))) for x in names)
        if looks or not names:
            shutil.rmtree(p)
            return
    raise LogError(f'{p} exists and does not look like a log written by this tool; refusing to '
                   'delete it, remove it yourself or choose another output path.')


def _as_chunks(value) -> Iterator:
    if isinstance(value, (ImuColumns, TemperatureColumns)):
        yield value
    else:
        yield from value


def write_columns(path, imu_topic: str, imu_chunks, temperature: Mapping | None = None,
                  storage: str = 'mcap', *, accel_cov=None, gyro_cov=None,
                  temperature_variance: float | Mapping = 0.0, compression: str = 'none',
                  overwrite: bool = False, msgtypes: Mapping | None = None) -> dict[str, int]:
    """Write IMU and temperature columns as a log, with log time = header stamp.

    ``imu_chunks`` is an ImuColumns or an iterable of them; ``temperature`` maps topic to
    TemperatureColumns or an iterable of them (each stamp-sorted).  Messages are written
    interleaved in stamp order while streaming.  ``temperature_variance`` is one value or
    topic -> value; ``msgtypes`` maps a temperature topic to another type of
    ``headerless.THERMAL_MSGTYPES`` (default sensor_msgs/msg/Temperature; a std_msgs/Float32
    or Float64 keeps only the value, its stamp being the log time).  Returns the message
    count per topic.
    """
    temperature = dict(temperature or {})
    msgtypes = dict(msgtypes or {})
    bad = {t: m for t, m in msgtypes.items() if m not in THERMAL_MSGTYPES}
    if bad:
        raise LogError(f'msgtypes {bad} are not thermal-input scalars; use one of '
                       f'{", ".join(THERMAL_MSGTYPES)}.')
    variance = (dict(temperature_variance) if isinstance(temperature_variance, Mapping)
                else {t: temperature_variance for t in temperature})
    its = {topic: _as_chunks(v) for topic, v in temperature.items()}
    pending: dict[str, TemperatureColumns] = {t: TemperatureColumns.empty() for t in its}
    counts = {imu_topic: 0, **{t: 0 for t in its}}
    with LogWriter(path, storage, compression=compression, overwrite=overwrite) as w:
        w.add_topic(imu_topic, IMU_MSGTYPE)
        for t in its:
            w.add_topic(t, msgtypes.get(t, TEMPERATURE_MSGTYPE))

        def take_temps(until: int | None) -> list:
            parts = []
            for topic, it in its.items():
                buf = pending[topic]
                while until is None or not len(buf) or buf.stamp_ns[-1] <= until:
                    nxt = next(it, None)
                    if nxt is None:
                        break
                    buf = _concat_temps(buf, nxt)
                cut = (len(buf) if until is None
                       else int(np.searchsorted(buf.stamp_ns, until, side='right')))
                now = TemperatureColumns(buf.stamp_ns[:cut], buf.temperature[:cut],
                                         buf.frame_id)
                pending[topic] = TemperatureColumns(buf.stamp_ns[cut:], buf.temperature[cut:],
                                                    buf.frame_id)
                if len(now):
                    kind = msgtypes.get(topic, TEMPERATURE_MSGTYPE)
                    parts.append((topic, now.stamp_ns, encode_values(now.temperature, kind)
                                  if kind in HEADERLESS_MSGTYPES else
                                  cdr.encode_temperature(now, variance.get(topic, 0.0))))
            return parts

        def emit(parts: list) -> None:
            if not parts:
                return
            times = np.concatenate([p[1] for p in parts])
            topics = [p[0] for p in parts for _ in range(len(p[1]))]
            raws = [r for p in parts for r in p[2]]
            for i in np.argsort(times, kind='stable').tolist():
                w.write(topics[i], int(times[i]), raws[i])
                counts[topics[i]] += 1

        for chunk in _as_chunks(imu_chunks):
            if not len(chunk):
                continue
            raws = cdr.encode_imu(chunk, accel_cov=accel_cov, gyro_cov=gyro_cov)
            emit([(imu_topic, chunk.stamp_ns, raws)] + take_temps(int(chunk.stamp_ns.max())))
        emit(take_temps(None))
    return counts


def _concat_temps(a: TemperatureColumns, b: TemperatureColumns) -> TemperatureColumns:
    if not len(a):
        return b
    return TemperatureColumns(np.concatenate([a.stamp_ns, b.stamp_ns]),
                              np.concatenate([a.temperature, b.temperature]),
                              a.frame_id or b.frame_id)
