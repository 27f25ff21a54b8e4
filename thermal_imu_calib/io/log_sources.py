"""The storage back ends behind ``bag.LogReader``, and which one opens a log.

rosbags' ``Reader`` handles a rosbag2 directory (sqlite3 or mcap storage), a bare ``.mcap``
and a bare ``.db3`` file (``_RosbagsSource``); MCAP files whose profile is not ``ros2`` but
whose channels are CDR with ``ros2msg`` schemas fall back to the ``mcap`` library
(``_McapLibSource``); one indexed ``.mcap`` file is then read in bulk
(``mcap_source.McapBulkSource``). Every source offers ``conns`` (one ``_Conn`` per topic),
``mixed``, ``message_count``, ``start_ns``/``end_ns``, ``messages(topics)`` and ``close()``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from .log_info import LogError
from .log_open import _explain_unreadable


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


def open_source(p: Path, read_path: Path, kind: str):
    """Return the message source of the log at ``read_path`` (``p``: its name in errors).

    rosbags' Reader first; an MCAP file it refuses falls back to the ``mcap`` library;
    then the bulk MCAP reader when the log is one indexed .mcap file
    (``_bulk_source``). Raises LogError naming the cause when none can read it.
    """
    try:
        src = _RosbagsSource(read_path)
    except LogError:
        raise
    except Exception as err:  # rosbags raises ReaderError, KeyError, OSError, ...
        _explain_unreadable(p, kind, err)
        if p.suffix != '.mcap':
            raise LogError(f'{p}: cannot read this {kind}: {err}; check that it is a '
                           'complete ROS 2 bag (try `ros2 bag info`).') from err
        try:
            src = _McapLibSource(read_path)
        except LogError:
            raise
        except Exception as err2:
            raise LogError(f'{p}: cannot read this MCAP file: {err}; {err2}; check that '
                           'it is a complete ROS 2 MCAP file (try `mcap info`).') from err2
    return _bulk_source(read_path, src)
