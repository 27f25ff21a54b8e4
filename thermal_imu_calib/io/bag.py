"""Read ROS 2 logs as numpy column chunks: ``open_log`` and ``LogReader``.

Inputs: a rosbag2 directory (sqlite3 or mcap storage, with metadata.yaml), a bare ``.mcap``
file or a bare ``.db3`` file (``log_open.locate_log``), read by rosbags' ``Reader`` or, for
MCAP files whose profile is not ``ros2`` but whose channels are CDR with ``ros2msg``
schemas, the ``mcap`` library (``log_sources``). ``LogReader`` gives the topics (index,
checks against the expected types), a one-pass summary (``info``) and the chunked,
bounded-memory stream of IMU and temperature samples (``log_stream``). Outputs are written
by ``bag_writer`` (a bare ``.mcap`` file, ``mcap`` library, ``ros2`` profile, or a rosbag2
directory, rosbags ``Writer``, metadata version 9 as written by Jazzy).

Only raw CDR bytes cross this module; Imu/Temperature payloads are decoded in bulk by
:mod:`thermal_imu_calib.io.cdr`.  Readers support one iteration at a time.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
import os

import yaml

from .bag_writer import LogWriter, write_columns  # noqa: F401  (re-exported)
from .log_info import (_StatsBuilder, _STORAGE_SUFFIXES, LogError,  # noqa: F401  (re-exported)
                       LogInfo, RawChunk, TopicInfo, TopicStats)
from .log_open import _with_wal, locate_log
from .log_sources import open_source
from .log_stream import (_bulk_chunks, _chunked, _Chunker, _guarded,  # noqa: F401  (re-exported)
                         _named, copy_and_stream)


def open_log(path) -> LogReader:
    """Open a rosbag2 directory, a bare ``.mcap`` or a bare ``.db3`` file for reading."""
    return LogReader(path)


class LogReader:
    """Read-only access to a ROS 2 log; use as a context manager or call ``close``."""

    def __init__(self, path):
        """Open ``path``; raises LogError with a one-line explanation when it cannot."""
        p, kind = locate_log(path)
        self.path = p
        self._scan_cache: LogInfo | None = None
        self._wal_copy = None
        read_path, wal = _with_wal(p)
        if wal:
            self._wal_copy = read_path
        self._src = open_source(p, read_path, kind)
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
