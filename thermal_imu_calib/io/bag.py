"""Read and write ROS 2 logs as numpy column chunks.

Inputs: a rosbag2 directory (sqlite3 or mcap storage, with metadata.yaml), a bare ``.mcap``
file or a bare ``.db3`` file.  rosbags' ``Reader`` handles all three; MCAP files whose
profile is not ``ros2`` but whose channels are CDR with ``ros2msg`` schemas fall back to
the ``mcap`` library.  Outputs: a bare ``.mcap`` file (``mcap`` library, ``ros2`` profile)
or a rosbag2 directory (rosbags ``Writer``, metadata version 9 as written by Jazzy).

Only raw CDR bytes cross this module; Imu/Temperature payloads are decoded in bulk by
:mod:`thermal_imu_calib.io.cdr`.  Readers support one iteration at a time.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..input_units import TEMPERATURE_BOUNDS
from . import cdr
from .cdr import IMU_MSGTYPE, SCALAR_MSGTYPES, TEMPERATURE_MSGTYPE
from .columns import ImuColumns, TemperatureColumns

_IDL_PREFIX = '=' * 80 + '\nIDL: '
_STORAGE_SUFFIXES = ('.mcap', '.db3')


class LogError(Exception):
    """A log cannot be read or written as asked; the message says why and what to do."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log.

    ``first_log_time_ns`` / ``last_log_time_ns`` are None until the log has been scanned
    (``LogReader.topics(scan=True)`` or ``LogReader.info()``), because the storage indexes
    only know them for the whole log.
    """

    name: str
    msgtype: str
    count: int
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None


@dataclass
class TopicStats:
    """Per-topic statistics gathered by :meth:`LogReader.info`.

    Stamp statistics are filled for Imu and Temperature topics only (header stamps);
    ``rate_hz`` is the median-interval rate, ``mean_rate_hz`` the count over the stamp
    span, ``max_gap_s`` the largest stamp step and ``stamps_backwards`` how many steps
    went back in time.
    """

    name: str
    msgtype: str
    count: int = 0
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None
    first_stamp_ns: int | None = None
    last_stamp_ns: int | None = None
    rate_hz: float | None = None
    mean_rate_hz: float | None = None
    max_gap_s: float | None = None
    stamps_backwards: int = 0
    frame_id: str | None = None
    temperature_min: float | None = None
    temperature_max: float | None = None


@dataclass
class LogInfo:
    """Summary of a log for the ``info`` command."""

    path: str
    storage: str
    message_count: int
    start_ns: int | None
    end_ns: int | None
    topics: dict[str, TopicStats]

    @property
    def duration_s(self) -> float:
        """Log-time span in seconds (0 for an empty log)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * 1e-9

    def topics_of_type(self, msgtype: str) -> list[str]:
        """Return the names of topics carrying ``msgtype``."""
        return [name for name, t in self.topics.items() if t.msgtype == msgtype]

    def format(self) -> str:
        """Render a human-readable multi-line summary."""
        lines = [f'log:      {self.path} ({self.storage})',
                 f'messages: {self.message_count}   duration: {self.duration_s:.3f} s']
        width = max([len(n) for n in self.topics] + [5])
        for name, t in sorted(self.topics.items()):
            line = f'  {name:<{width}}  {t.msgtype:<30} {t.count:>9}'
            if t.rate_hz:
                line += f'  {t.rate_hz:9.2f} Hz'
            if t.max_gap_s is not None:
                line += f'  max gap {t.max_gap_s:.3f} s'
            if t.stamps_backwards:
                line += f'  {t.stamps_backwards} stamps backwards'
            if t.temperature_min is not None:
                lo, hi = TEMPERATURE_BOUNDS
                plausible = lo <= t.temperature_min and t.temperature_max <= hi
                unit = (' degC' if t.msgtype == TEMPERATURE_MSGTYPE and plausible else
                        ' (not degC: a thermal proxy? declare its unit with --input-unit)'
                        if t.msgtype == TEMPERATURE_MSGTYPE else '')
                line += f'  {t.temperature_min:.2f}..{t.temperature_max:.2f}{unit}'
            lines.append(line)
        return '\n'.join(lines)


@dataclass
class RawChunk:
    """A span of the log: IMU columns plus the temperature samples that arrived meanwhile."""

    imu: ImuColumns
    imu_log_time_ns: np.ndarray
    temps: dict[str, TemperatureColumns]
    #: the Imu payloads when asked for: a list of bytes, or from the bulk MCAP reader an
    #: (n, size) uint8 array when every payload of the chunk has one size
    imu_raw: list[bytes] | np.ndarray | None = None

    def __len__(self):
        return len(self.imu)


@dataclass(frozen=True)
class _Conn:
    """A topic's type as found in an input, enough to recreate it in an output."""

    topic: str
    msgtype: str
    msgdef: str = ''
    encoding: str = ''  # 'ros2msg', 'ros2idl' or '' when the log has no definition
    type_hash: str = ''
    qos: tuple = ()
    count: int = 0


# --------------------------------------------------------------------------- readers


class _RosbagsSource:
    """rosbags ``Reader`` over a rosbag2 directory, a ``.mcap`` or a ``.db3`` file."""

    def __init__(self, path: Path):
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag2 import Reader

        self._reader = Reader(path)
        self._reader.open()
        fmt = {MessageDefinitionFormat.MSG: 'ros2msg', MessageDefinitionFormat.IDL: 'ros2idl'}
        self.conns: list[_Conn] = []
        counts: dict[str, int] = {}
        for c in self._reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        seen = set()
        for c in self._reader.connections:
            if c.topic in seen:
                continue
            seen.add(c.topic)
            qos = tuple(getattr(c.ext, 'offered_qos_profiles', ()) or ())
            self.conns.append(_Conn(c.topic, c.msgtype, c.msgdef.data,
                                    fmt.get(c.msgdef.format, ''), c.digest or '', qos,
                                    counts[c.topic]))
        types: dict[str, set] = {}
        for c in self._reader.connections:
            types.setdefault(c.topic, set()).add(c.msgtype)
        self.mixed = {t: sorted(v) for t, v in types.items() if len(v) > 1}
        self.message_count = self._reader.message_count
        self.start_ns = self._reader.start_time if self.message_count else None
        self.end_ns = self._reader.end_time - 1 if self.message_count else None

    def messages(self, topics: set[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not conns:
            return
        for conn, t, raw in self._reader.messages(conns):
            yield conn.topic, conn.msgtype, t, raw

    def close(self):
        if self._reader.is_open:
            self._reader.close()


class _McapLibSource:
    """``mcap`` library reader for MCAP files rosbags refuses (e.g. profile not ``ros2``)."""

    def __init__(self, path: Path):
        from mcap.reader import make_reader

        self._file = open(path, 'rb')
        try:
            self._reader = make_reader(self._file)
            summary = self._reader.get_summary()
            if summary is None:
                raise LogError(f'{path}: MCAP file has no summary section; re-index it with '
                               '`mcap recover` and try again.')
            self.conns = []
            stats = summary.statistics
            counts = dict(stats.channel_message_counts) if stats else {}
            for cid, ch in summary.channels.items():
                schema = summary.schemas.get(ch.schema_id)
                if ch.message_encoding != 'cdr' or schema is None:
                    continue
                self.conns.append(_Conn(
                    ch.topic, schema.name, schema.data.decode('utf-8', 'replace'),
                    schema.encoding if schema.encoding in ('ros2msg', 'ros2idl') else '',
                    ch.metadata.get('topic_type_hash', ''), (), counts.get(cid, 0)))
            if not self.conns:
                raise LogError(f'{path}: MCAP file has no CDR-encoded ROS 2 channels; only '
                               'ROS 2 logs (cdr message encoding) can be read.')
            self.mixed = {}
            self.message_count = (stats.message_count if stats
                                  else sum(c.count for c in self.conns))
            self.start_ns = stats.message_start_time if stats and stats.message_count else None
            self.end_ns = stats.message_end_time if stats and stats.message_count else None
            self._types = {c.topic: c.msgtype for c in self.conns}
        except BaseException:
            self._file.close()
            raise

    def messages(self, topics: set[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
        wanted = list(self._types) if topics is None else [t for t in topics if t in self._types]
        if not wanted:
            return
        for _, channel, msg in self._reader.iter_messages(topics=wanted, log_time_order=True):
            yield channel.topic, self._types[channel.topic], msg.log_time, msg.data

    def close(self):
        self._file.close()


_MCAP_MAGIC = b'\x89MCAP0\r\n'


def _explain_unreadable(p: Path, kind: str, err: Exception) -> None:
    """Raise a LogError naming the cause when a log is unreadable for a known reason.

    Known: a non-UTF-8 metadata.yaml, and an MCAP file cut short (no end magic). Returns
    without raising otherwise.
    """
    if isinstance(err, UnicodeDecodeError) or 'codec can\'t decode' in str(err):
        name = p / 'metadata.yaml' if p.is_dir() else p
        raise LogError(f'{name}: cannot read it: not UTF-8 text ({err}); the {kind} is '
                       'damaged: restore metadata.yaml, or regenerate it with '
                       '`ros2 bag reindex`.') from None
    mcaps = ([p] if p.suffix == '.mcap' else
             sorted(p.glob('*.mcap')) if p.is_dir() else [])
    for f in mcaps:
        try:
            with open(f, 'rb') as fh:
                head = fh.read(8)
                size = fh.seek(0, 2)
                fh.seek(max(size - 8, 0))
                tail = fh.read(8)
        except OSError:
            continue
        if head != _MCAP_MAGIC:
            raise LogError(f'{f}: cannot read it: not an MCAP file (it does not start with the '
                           'MCAP magic bytes); is it the right file?') from None
        if tail != _MCAP_MAGIC:
            raise LogError(f'{f}: cannot read it: the MCAP file is truncated ({size} bytes, '
                           'no end magic: the recording was cut short or the copy is '
                           'incomplete); recover '
                           f'the complete messages with `mcap recover {f} -o recovered.mcap` '
                           '(mcap CLI) and use recovered.mcap.') from None


def _bulk_source(p: Path, src):
    """Read messages with the bulk MCAP reader when the log is one indexed .mcap file."""
    from .mcap_source import McapBulkSource

    paths = [p]
    if p.is_dir():  # rosbag2 directory: rosbags' storage files (decompressed if 'file' mode)
        bag = getattr(src, '_reader', None)
        if bag is None or getattr(bag, 'compression_mode', None) == 'message':
            return src
        paths = [Path(s.path) for s in getattr(bag.storage, 'storages', [])]
    if len(paths) != 1 or paths[0].suffix != '.mcap':
        return src
    try:
        return McapBulkSource.open(paths[0], src, LogError) or src
    except ValueError as err:
        src.close()
        raise LogError(f'{err}') from err


def _bulk_chunks(reader, chunker, batches, on_batch=None) -> Iterator[RawChunk]:
    """Turn bulk MCAP batches into RawChunks (the cut points of ``_Chunker``)."""
    from .mcap_source import chunk_stream

    src = reader._src
    try:
        for imu, times, temps, raws in chunk_stream(
                batches, chunker.imu_topic, src.channel_ids({chunker.imu_topic}),
                chunker.temperature_topics,
                [src.channel_ids({t}) for t in chunker.temperature_topics],
                chunker.chunk_size, chunker.keep_raw, on_batch):
            yield RawChunk(imu, times, temps, raws)
    except ValueError as err:
        raise LogError(f'{err}') from err


def open_log(path) -> LogReader:
    """Open a rosbag2 directory, a bare ``.mcap`` or a bare ``.db3`` file for reading."""
    return LogReader(path)


class LogReader:
    """Read-only access to a ROS 2 log; use as a context manager or call ``close``."""

    def __init__(self, path):
        """Open ``path``; raises LogError with a one-line explanation when it cannot."""
        p = Path(path).expanduser()
        if p.name == 'metadata.yaml' and p.is_file():
            p = p.parent
        if not p.exists():
            raise LogError(f'{p}: no such file or directory; pass a rosbag2 directory, a .mcap '
                           'or a .db3 file.')
        if p.is_dir():
            if not (p / 'metadata.yaml').is_file():
                files = sorted(x.name for x in p.iterdir() if x.suffix in _STORAGE_SUFFIXES)
                hint = (f'open the storage file directly ({p / files[0]}) or run '
                        f'`ros2 bag reindex {p}`' if files else
                        'pass a rosbag2 directory, a .mcap or a .db3 file')
                raise LogError(f'{p}: directory has no metadata.yaml, so it is not a rosbag2 '
                               f'bag; {hint}.')
            kind = 'rosbag2 directory'
        elif p.suffix in _STORAGE_SUFFIXES:
            kind = f'{p.suffix[1:]} file'
        else:
            raise LogError(f'{p}: unknown log format {p.suffix or "(no suffix)"!r}; pass a '
                           'rosbag2 directory, a .mcap or a .db3 file (convert ROS 1 .bag '
                           'files with `rosbags-convert`).')
        self.path = p
        self._scan_cache: LogInfo | None = None
        try:
            self._src = _RosbagsSource(p)
        except LogError:
            raise
        except Exception as err:  # rosbags raises ReaderError, KeyError, OSError, ...
            _explain_unreadable(p, kind, err)
            if p.suffix != '.mcap':
                raise LogError(f'{p}: cannot read this {kind}: {err}; check that it is a '
                               'complete ROS 2 bag (try `ros2 bag info`).') from err
            try:
                self._src = _McapLibSource(p)
            except LogError:
                raise
            except Exception as err2:
                raise LogError(f'{p}: cannot read this MCAP file: {err}; {err2}; check that '
                               'it is a complete ROS 2 MCAP file (try `mcap info`).') from err2
        self._src = _bulk_source(p, self._src)
        if kind == 'rosbag2 directory':
            try:
                meta = yaml.safe_load((p / 'metadata.yaml').read_text())
                kind += f" ({meta['rosbag2_bagfile_information']['storage_identifier']})"
            except Exception:  # rosbags already parsed it; this is only a label
                pass
        self.storage = kind

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the underlying files."""
        self._src.close()

    @property
    def message_count(self) -> int:
        """Messages in the log according to its index."""
        return int(self._src.message_count)

    @property
    def start_ns(self) -> int | None:
        """Log time of the first message (None when empty)."""
        return self._src.start_ns

    @property
    def end_ns(self) -> int | None:
        """Log time of the last message (None when empty)."""
        return self._src.end_ns

    def topic_types(self) -> dict[str, str]:
        """Return ``{topic: msgtype}`` straight from the index (cheap)."""
        return {c.topic: c.msgtype for c in self._src.conns}

    def topics(self, scan: bool = False) -> dict[str, TopicInfo]:
        """Return ``{topic: TopicInfo}``.

        Types and counts come from the index.  First/last log times are filled once the log
        has been scanned: pass ``scan=True`` to do it now (one pass over every message, no
        decoding beyond header stamps; the result is cached and shared with :meth:`info`).
        """
        info = self._scan_cache
        if scan and info is None:
            info = self.info()
        out = {}
        for c in self._src.conns:
            st = info.topics.get(c.topic) if info else None
            out[c.topic] = TopicInfo(c.topic, c.msgtype, st.count if st else c.count,
                                     st.first_log_time_ns if st else None,
                                     st.last_log_time_ns if st else None)
        return out

    def _describe_topics(self) -> str:
        items = [f'{c.topic} [{c.msgtype}]' for c in self._src.conns]
        return ', '.join(items) if items else '(none)'

    def check_topics(self, topics: Iterable[str],
                     expected: str | Iterable[str] | None = None) -> None:
        """Raise LogError unless every topic exists (and has type ``expected`` if given).

        ``expected`` is one message type or several accepted ones.
        """
        topics = [topics] if isinstance(topics, str) else topics
        types = self.topic_types()
        if expected is not None and not isinstance(expected, str):
            accepted = tuple(expected)
            for topic in topics:
                if topic in types and types[topic] not in accepted:
                    raise LogError(f'topic {topic!r} in {self.path} has type {types[topic]}, '
                                   f'expected {accepted[0]}'
                                   + (f' (or {", ".join(accepted[1:])})' if accepted[1:]
                                      else '')
                                   + f'; pick such a topic from: {self._describe_topics()}.')
            expected = None
        for topic in topics:
            if topic not in types:
                raise LogError(f'topic {topic!r} is not in {self.path}; it has: '
                               f'{self._describe_topics()}.')
            if topic in self._src.mixed:
                raise LogError(f'topic {topic!r} in {self.path} carries several types '
                               f'{self._src.mixed[topic]}; split the bag by type first.')
            if expected is not None and types[topic] != expected:
                raise LogError(f'topic {topic!r} in {self.path} has type {types[topic]}, '
                               f'expected {expected}; pick a {expected} topic from: '
                               f'{self._describe_topics()}.')

    _check_topics = check_topics  # kept for callers that used the private name

    def iter_raw(self, topics: Iterable[str] | None = None
                 ) -> Iterator[tuple[str, str, int, bytes]]:
        """Yield ``(topic, msgtype, log_time_ns, raw_cdr)`` in log-time order."""
        wanted = None
        if topics is not None:
            wanted = set([topics] if isinstance(topics, str) else topics)
            self.check_topics(wanted)
        return _guarded(self.path, self._src.messages(wanted))

    def stream(self, imu_topic: str, temperature_topics: Sequence[str] = (),
               chunk_size: int = 20000, keep_raw: bool = False) -> Iterator[RawChunk]:
        """Yield RawChunks of at most ``chunk_size`` IMU messages, in log-time order.

        Each chunk also holds the temperature samples (per topic, in the order given) logged
        since the previous chunk; memory stays bounded by ``chunk_size``.
        """
        chunker = _Chunker(self, imu_topic, temperature_topics, chunk_size, keep_raw)
        if hasattr(self._src, 'batches'):
            yield from _bulk_chunks(self, chunker,
                                    _guarded(self.path, self._src.batches(chunker.topics)))
            return
        yield from _chunked(chunker, _guarded(self.path, self._src.messages(chunker.topics)))

    def info(self, topics: Iterable[str] | None = None) -> LogInfo:
        """Scan the log once and summarise it (counts, log times, header-stamp rates, degC).

        ``topics`` restricts the scan (others keep their index counts only).  Scanning all
        topics is cached and also fills :meth:`topics` first/last log times.
        """
        if topics is None and self._scan_cache is not None:
            return self._scan_cache
        wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)
        if wanted is not None:
            self.check_topics(wanted)
        stats = {c.topic: _StatsBuilder(c.topic, c.msgtype) for c in self._src.conns}
        for c in self._src.conns:
            if wanted is not None and c.topic not in wanted:
                stats[c.topic].stats.count = c.count
        try:
            for topic, _, t, raw in _guarded(self.path, self._src.messages(wanted)):
                stats[topic].add(t, raw)
            result = LogInfo(str(self.path), self.storage, self.message_count, self.start_ns,
                             self.end_ns, {k: v.finish() for k, v in stats.items()})
        except LogError:
            raise
        except Exception as err:  # a damaged message body (CDR decode of stamps)
            raise LogError(f'{self.path}: a message cannot be decoded ({err.__class__.__name__}: '
                           f'{err}); the log is damaged.') from err
        if wanted is None:
            self._scan_cache = result
        return result


class _StatsBuilder:
    """Accumulate TopicStats over a scan, decoding stamps in batches."""

    BATCH = 20000

    def __init__(self, name: str, msgtype: str):
        self.stats = TopicStats(name, msgtype)
        self.stamped = msgtype == IMU_MSGTYPE or msgtype in SCALAR_MSGTYPES
        self.times: list[int] = []
        self.raws: list[bytes] = []
        self.medians: list[float] = []
        self.n_stamps = 0

    def add(self, t: int, raw: bytes) -> None:
        st = self.stats
        if st.first_log_time_ns is None:
            st.first_log_time_ns = t
        st.first_log_time_ns = min(st.first_log_time_ns, t)
        st.last_log_time_ns = t if st.last_log_time_ns is None else max(st.last_log_time_ns, t)
        st.count += 1
        if self.stamped:
            self.raws.append(raw)
            if len(self.raws) >= self.BATCH:
                self._flush()

    def _flush(self) -> None:
        if not self.raws:
            return
        st = self.stats
        try:
            if st.msgtype == IMU_MSGTYPE:
                cols = cdr.decode_imu(self.raws)
            else:
                cols = cdr.decode_temperature(self.raws)
                lo, hi = np.nanmin(cols.temperature), np.nanmax(cols.temperature)
                st.temperature_min = lo if st.temperature_min is None else min(
                    st.temperature_min, lo)
                st.temperature_max = hi if st.temperature_max is None else max(
                    st.temperature_max, hi)
        except ValueError as err:
            raise LogError(f'topic {st.name!r}: {err}') from err
        finally:
            self.raws = []
        s = cols.stamp_ns
        frame = cols.frame_id
        st.frame_id = frame if st.frame_id is None or st.frame_id == frame else ''
        if st.last_stamp_ns is not None:
            s = np.concatenate([[st.last_stamp_ns], s])
        else:
            st.first_stamp_ns = int(s[0])
        d = np.diff(s)
        if d.size:
            st.stamps_backwards += int(np.count_nonzero(d < 0))
            gap = float(d.max()) * 1e-9
            st.max_gap_s = gap if st.max_gap_s is None else max(st.max_gap_s, gap)
            pos = d[d > 0]
            if pos.size:
                self.medians.append(float(np.median(pos)))
        st.last_stamp_ns = int(s[-1])
        self.n_stamps += len(cols)

    def finish(self) -> TopicStats:
        self._flush()
        st = self.stats
        if self.medians:
            st.rate_hz = 1e9 / float(np.median(self.medians))
        if self.n_stamps > 1 and st.last_stamp_ns != st.first_stamp_ns:
            st.mean_rate_hz = (self.n_stamps - 1) * 1e9 / (st.last_stamp_ns - st.first_stamp_ns)
        if st.temperature_min is not None:
            st.temperature_min, st.temperature_max = (float(st.temperature_min),
                                                      float(st.temperature_max))
        return st


class _Chunker:
    """Group a log-ordered message stream into RawChunks (shared by stream and copy)."""

    def __init__(self, reader: LogReader, imu_topic: str, temperature_topics: Sequence[str],
                 chunk_size: int, keep_raw: bool):
        temperature_topics = ([temperature_topics] if isinstance(temperature_topics, str)
                              else list(temperature_topics))
        if chunk_size < 1:
            raise LogError(f'chunk_size must be >= 1 (got {chunk_size}).')
        if imu_topic in temperature_topics or len(set(temperature_topics)) < len(
                temperature_topics):
            raise LogError(f'topics must be distinct: IMU {imu_topic!r}, temperature '
                           f'{temperature_topics}; list each topic once.')
        reader.check_topics([imu_topic], IMU_MSGTYPE)
        reader.check_topics(temperature_topics, SCALAR_MSGTYPES)
        self.imu_topic = imu_topic
        self.temperature_topics = temperature_topics
        self.topics = {imu_topic, *temperature_topics}
        self.chunk_size = chunk_size
        self.keep_raw = keep_raw
        self._imu_raw: list[bytes] = []
        self._imu_t: list[int] = []
        self._temp_raw: dict[str, list[bytes]] = {t: [] for t in temperature_topics}
        self._n_temp = 0

    def add(self, topic: str, t: int, raw: bytes) -> RawChunk | None:
        if topic == self.imu_topic:
            self._imu_raw.append(raw)
            self._imu_t.append(t)
            if len(self._imu_raw) >= self.chunk_size:
                return self._build()
        elif topic in self._temp_raw:
            self._temp_raw[topic].append(raw)
            self._n_temp += 1
            if self._n_temp >= self.chunk_size:
                return self._build()
        return None

    def flush(self) -> RawChunk | None:
        if self._imu_raw or self._n_temp:
            return self._build()
        return None

    def _build(self) -> RawChunk:
        try:
            imu = cdr.decode_imu(self._imu_raw)
        except ValueError as err:
            raise LogError(f'topic {self.imu_topic!r}: {err}') from err
        temps = {}
        for topic, raws in self._temp_raw.items():
            try:
                temps[topic] = cdr.decode_temperature(raws)
            except ValueError as err:
                raise LogError(f'topic {topic!r}: {err}') from err
        chunk = RawChunk(imu, np.array(self._imu_t, dtype=np.int64), temps,
                         self._imu_raw if self.keep_raw else None)
        self._imu_raw, self._imu_t = [], []
        self._temp_raw = {t: [] for t in self.temperature_topics}
        self._n_temp = 0
        return chunk


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
    ``SCALAR_MSGTYPES`` (default sensor_msgs/msg/Temperature).  Returns the message count
    per topic.
    """
    temperature = dict(temperature or {})
    msgtypes = dict(msgtypes or {})
    bad = {t: m for t, m in msgtypes.items() if m not in SCALAR_MSGTYPES}
    if bad:
        raise LogError(f'msgtypes {bad} are not header-stamped scalars; use one of '
                       f'{", ".join(SCALAR_MSGTYPES)}.')
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
                    parts.append((topic, now.stamp_ns,
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


def copy_and_stream(reader: LogReader, writer: LogWriter, imu_topic: str,
                    temperature_topics: Sequence[str] = (), *, chunk_size: int = 20000,
                    keep_raw: bool = True, exclude: Iterable[str] = ()) -> Iterator[RawChunk]:
    """Copy every input message to ``writer`` verbatim while yielding IMU RawChunks.

    All input topics except ``exclude`` are registered on the writer with their original
    definitions, hashes and offered QoS, and each message is written, in log-time order,
    as it is read; between yields the caller writes its own topics (e.g. compensated IMU
    with ``writer.write_many(out, aligned.extra['imu_log_time_ns'], patched)``).  One pass
    over the input; memory bounded by ``chunk_size``.
    """
    exclude = set([exclude] if isinstance(exclude, str) else exclude)
    chunker = _Chunker(reader, imu_topic, temperature_topics, chunk_size, keep_raw)
    copied = set()
    for c in reader._src.conns:
        if c.topic in exclude:
            continue
        if c.topic in reader._src.mixed:
            raise LogError(f'input topic {c.topic!r} carries several types '
                           f'{reader._src.mixed[c.topic]}; exclude it from the copy.')
        if c.topic in writer.topics:
            raise LogError(f'output topic {c.topic!r} also exists in the input; choose another '
                           'output topic name or exclude the input topic from the copy.')
        writer.add_topic(c.topic, c.msgtype, msgdef=c.msgdef or None,
                         type_hash=c.type_hash or None, qos=c.qos)
        copied.add(c.topic)
    src = reader._src
    if hasattr(src, 'batches') and writer.bare:
        ids = src.channel_ids(copied)
        cmap = {int(i): writer._topics[src.topic_of(int(i))] for i in ids}

        def copy_batch(batch):
            writer.copy_batch(batch.take(np.isin(batch.channel, ids)), cmap)
        yield from _bulk_chunks(reader, chunker, _guarded(reader.path, src.batches(None)),
                                copy_batch)
        return
    write = writer.write

    def copy(messages):
        for msg in messages:
            if msg[0] in copied:
                write(msg[0], msg[2], msg[3])
            yield msg

    yield from _chunked(chunker, copy(_guarded(reader.path, reader._src.messages(None))))


def _guarded(path, messages):
    """Yield from a source's message iterator, turning its failures into LogError.

    A damaged chunk (checksum, compression, sqlite page) shows only when it is read.
    """
    try:
        yield from messages
    except LogError:
        raise
    except Exception as err:  # rosbags ReaderError, mcap errors, sqlite3.DatabaseError, ...
        raise LogError(f'{path}: the log is damaged: reading its messages failed '
                       f'({err.__class__.__name__}: {str(err)[:200]}); recover what is '
                       'readable (`mcap recover` for MCAP, `ros2 bag reindex` for a bag) '
                       'and try again.') from err


def _chunked(chunker, messages):
    """Feed ``(topic, msgtype, log_time, raw)`` messages to a _Chunker; yield its chunks."""
    wanted = chunker.topics
    for topic, _, t, raw in messages:
        if topic in wanted:
            chunk = chunker.add(topic, t, raw)
            if chunk is not None:
                yield chunk
    last = chunker.flush()
    if last is not None:
        yield last
