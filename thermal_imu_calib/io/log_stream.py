"""From a log-ordered message stream to RawChunks, and the copy of a log while it streams.

``_Chunker`` groups IMU and temperature messages into RawChunks of at most ``chunk_size``
IMU messages (payloads decoded in bulk by :mod:`thermal_imu_calib.io.cdr`); ``_chunked``
feeds it messages, ``_bulk_chunks`` cuts bulk MCAP batches at the same points.
``copy_and_stream`` copies every input message to a writer while yielding the chunks.
``_guarded`` and ``_named`` turn a back end's or a decoder's failure into a LogError that
names the log.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from . import cdr
from .bag_writer import LogWriter
from .cdr import IMU_MSGTYPE
from .headerless import decode_values, HEADERLESS_MSGTYPES, StampChoice, THERMAL_MSGTYPES
from .log_info import LogError, RawChunk


class _Chunker:
    """Group a log-ordered message stream into RawChunks (shared by stream and copy)."""

    def __init__(self, reader, imu_topic: str, temperature_topics: Sequence[str],
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
        reader.check_topics(temperature_topics, THERMAL_MSGTYPES)
        types = reader.topic_types()
        #: header-less topics -> their type; their readings take the IMU's stamps
        self.headerless = {t: types[t] for t in temperature_topics
                           if types[t] in HEADERLESS_MSGTYPES}
        #: per temperature topic: its header stamps, or the IMU's clock (``StampChoice``)
        self.choices = {t: StampChoice(t, t in self.headerless) for t in temperature_topics}
        self._imu_before: dict[str, list[int]] = {t: [] for t in temperature_topics}
        self._carry_ns: int | None = None     # the last IMU stamp of the chunks before
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
            self._imu_before[topic].append(len(self._imu_raw))
            self._n_temp += 1
            if self._n_temp >= self.chunk_size:
                return self._build()
        return None

    def flush(self) -> RawChunk | None:
        if self._imu_raw or self._n_temp or any(c.holding for c in self.choices.values()):
            return self._build(final=True)
        return None

    def _build(self, final: bool = False) -> RawChunk:
        try:
            imu = cdr.decode_imu(self._imu_raw)
        except ValueError as err:
            raise LogError(f'topic {self.imu_topic!r}: {err}') from err
        temps, notes = {}, []
        for topic, raws in self._temp_raw.items():
            choice = self.choices[topic]
            try:
                if topic in self.headerless:
                    stamps, values, frame = np.zeros(len(raws), np.int64), decode_values(
                        raws, self.headerless[topic]), ''
                else:
                    cols = cdr.decode_temperature(raws)
                    stamps, values, frame = cols.stamp_ns, cols.temperature, cols.frame_id
            except ValueError as err:
                raise LogError(f'topic {topic!r}: {err}') from err
            if choice.on_imu_clock is False:     # header stamps (the common case)
                temps[topic] = cols
                continue
            temps[topic] = choice.place(stamps, values, self._imu_before[topic],
                                        imu.stamp_ns, self._carry_ns, final, frame)
            notes += [n for n in [choice.pop_note()] if n]
        chunk = RawChunk(imu, np.array(self._imu_t, dtype=np.int64), temps,
                         self._imu_raw if self.keep_raw else None, notes)
        if len(imu):
            self._carry_ns = int(imu.stamp_ns[-1])
        self._imu_raw, self._imu_t = [], []
        self._temp_raw = {t: [] for t in self.temperature_topics}
        self._imu_before = {t: [] for t in self.temperature_topics}
        self._n_temp = 0
        return chunk


def _bulk_chunks(reader, chunker, batches, on_batch=None) -> Iterator[RawChunk]:
    """Turn bulk MCAP batches into RawChunks (the cut points of ``_Chunker``)."""
    from .mcap_source import chunk_stream

    src = reader._src
    try:
        for imu, times, temps, raws in chunk_stream(
                batches, chunker.imu_topic, src.channel_ids({chunker.imu_topic}),
                chunker.temperature_topics,
                [src.channel_ids({t}) for t in chunker.temperature_topics],
                chunker.chunk_size, chunker.keep_raw, on_batch, chunker.headerless,
                chunker.choices):
            yield RawChunk(imu, times, temps, raws,
                           [n for n in (c.pop_note() for c in chunker.choices.values()) if n])
    except ValueError as err:
        raise LogError(f'{err}') from err


def copy_and_stream(reader, writer: LogWriter, imu_topic: str,
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
