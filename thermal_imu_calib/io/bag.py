"""Read and write ROS 2 logs as numpy column chunks.

Inputs: a rosbag2 directory (sqlite3 or mcap storage, with metadata.yaml), a bare ``.mcap``
file or a bare ``.db3`` file.  rosbags' ``Reader`` handles all three; MCAP files whose
profile is not ``ros2`` but whose channels are CDR with ``ros2msg`` schemas fall back to
the ``mcap`` library.  Outputs: a bare ``.mcap`` file (``mcap`` library, ``ros2`` profile)
or a rosbag2 directory (rosbags ``Writer``, metadata version 9 as written by Jazzy).

Only raw CDR bytes cross this module; Imu/Temperature payloads are decoded in bulk by
:mod:`thermal_imu_calib.io.cdr`.  Readers support one iteration at a time.

Cohesive: the log reader: two storage back ends behind one chunked, bounded-memory
iterator.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np
import yaml

from . import cdr
from .cdr import IMU_MSGTYPE, SCALAR_MSGTYPES

from .bag_writer import LogWriter, write_columns  # noqa: F401  (re-exported)
from .log_info import (_StatsBuilder, _STORAGE_SUFFIXES, LogError,  # noqa: F401  (re-exported)
                       LogInfo, RawChunk, TopicInfo, TopicStats)


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


def _check_name(p: Path) -> None:
    """Refuse a path that is not UTF-8 text: the bag libraries cannot open it (not the data)."""
    try:
        str(p).encode('utf-8')
    except UnicodeEncodeError as e:
        bad = os.fsencode(str(p))[len(str(p)[:e.start].encode('utf-8', 'surrogateescape'))]
        shown = str(p).encode('utf-8', 'surrogateescape').decode('utf-8', 'backslashreplace')
        raise LogError(f'{shown}: the path is not UTF-8 text (byte 0x{bad:02x} at character '
                       f'{e.start}), which the log readers cannot open; the data was not read: '
                       'rename the file or directory to a UTF-8 name and try again') from None


def _with_wal(p: Path) -> tuple[Path, str]:
    """Return (path to read, note): a checkpointed private copy when a .db3 has a -wal part.

    rosbags opens SQLite ``immutable``, which ignores the write-ahead log, so a .db3 whose
    last messages are still in ``NAME.db3-wal`` (a recorder still running, or one that
    stopped without a checkpoint) would be read without them. The log (a bare .db3 or the
    whole bag directory) is copied with its WAL to a temporary directory, checkpointed
    there with sqlite3, and read from the copy; the original is never written. A log whose
    files change while they are copied is still being recorded: refused (LogError).
    """
    dbs = [p] if p.suffix == '.db3' else sorted(p.glob('*.db3')) if p.is_dir() else []
    wals = [Path(f'{d}-wal') for d in dbs if Path(f'{d}-wal').is_file()
            and Path(f'{d}-wal').stat().st_size > 0]
    if not wals:
        return p, ''
    import shutil
    import sqlite3
    import tempfile

    def state():
        return [(f.stat().st_size, f.stat().st_mtime_ns) for f in dbs + wals]
    before = state()
    tmp = Path(tempfile.mkdtemp(prefix='thermal-imu-calib-wal-'))
    try:
        dst = tmp / p.name
        if p.is_dir():
            shutil.copytree(p, dst, ignore=shutil.ignore_patterns('*-shm'))
        else:
            for f in [p] + [w for w in wals]:
                shutil.copy2(f, tmp / f.name)
        if state() != before:
            raise LogError(f'{p}: its SQLite files changed while being read: the log is still '
                           'being recorded; wait until the recording has stopped, then try '
                           'again')
        for d in ([dst] if not p.is_dir() else sorted(dst.glob('*.db3'))):
            con = sqlite3.connect(str(d))
            try:
                con.execute('PRAGMA wal_checkpoint(TRUNCATE)')
            finally:
                con.close()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    size = sum(w.stat().st_size for w in wals)
    names = ', '.join(w.name for w in wals)
    return dst, (f'with {size} bytes of its SQLite write-ahead log ({names}: the recorder was '
                 'still running or did not close the bag) included')


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
        _check_name(p)
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
        self._wal_copy = None
        read_path, wal = _with_wal(p)
        if wal:
            self._wal_copy = read_path
        try:
            self._src = _RosbagsSource(read_path)
        except LogError:
            raise
        except Exception as err:  # rosbags raises ReaderError, KeyError, OSError, ...
            _explain_unreadable(p, kind, err)
            if p.suffix != '.mcap':
                raise LogError(f'{p}: cannot read this {kind}: {err}; check that it is a '
                               'complete ROS 2 bag (try `ros2 bag info`).') from err
            try:
                self._src = _McapLibSource(read_path)
            except LogError:
                raise
            except Exception as err2:
                raise LogError(f'{p}: cannot read this MCAP file: {err}; {err2}; check that '
                               'it is a complete ROS 2 MCAP file (try `mcap info`).') from err2
        self._src = _bulk_source(read_path, self._src)
        if kind == 'rosbag2 directory':
            try:
                meta = yaml.safe_load((p / 'metadata.yaml').read_text())
                kind += f" ({meta['rosbag2_bagfile_information']['storage_identifier']})"
            except Exception:  # rosbags already parsed it; this is only a label
                pass
        self.storage = kind + (f', {wal}' if wal else '')

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the underlying files (and the checkpointed copy of a WAL log)."""
        try:
            self._src.close()
        finally:
            if self._wal_copy is not None:
                import shutil
                shutil.rmtree(os.path.dirname(self._wal_copy), ignore_errors=True)
                self._wal_copy = None

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
            yield from _named(self.path, _bulk_chunks(
                self, chunker, _guarded(self.path, self._src.batches(chunker.topics))))
            return
        yield from _named(self.path, _chunked(
            chunker, _guarded(self.path, self._src.messages(chunker.topics))))

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
            topics = {k: v.finish() for k, v in stats.items()}
            total = self.message_count
            index = None
            if wanted is None:      # every message was read: count them, not the index
                read = sum(t.count for t in topics.values())
                total, index = read, (total if read != total else None)
            result = LogInfo(str(self.path), self.storage, total, self.start_ns,
                             self.end_ns, topics, index)
        except LogError:
            raise
        except Exception as err:  # a damaged message body (CDR decode of stamps)
            raise LogError(f'{self.path}: a message cannot be decoded ({err.__class__.__name__}: '
                           f'{err}); the log is damaged.') from err
        if wanted is None:
            self._scan_cache = result
        return result


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
        yield from _named(reader.path, _bulk_chunks(
            reader, chunker, _guarded(reader.path, src.batches(None)), copy_batch))
        return
    write = writer.write

    def copy(messages):
        for msg in messages:
            if msg[0] in copied:
                write(msg[0], msg[2], msg[3])
            yield msg

    yield from _named(reader.path, _chunked(
        chunker, copy(_guarded(reader.path, reader._src.messages(None)))))


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


def _named(path, chunks):
    """Yield from ``chunks``; a decoding error (ValueError, LogError) names the log file."""
    try:
        yield from chunks
    except (ValueError, LogError) as err:
        text = str(err)
        if text.startswith(str(path)):
            raise
        raise LogError(f'{path}: {text}') from err


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
