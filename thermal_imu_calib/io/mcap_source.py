"""Bulk MCAP message source for :class:`thermal_imu_calib.io.bag.LogReader`.

Wraps :mod:`.mcap_read` for the log reader: per-message tuples for callers that want
them, and :func:`chunk_stream`, which turns batches straight into IMU/temperature
columns (``cdr.decode_imu_packed``) without one Python object per message.  Errors are
``ValueError`` (damaged file, malformed payload) with a message that names the topic or
the chunk and offset; the log reader turns them into LogError.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence

import numpy as np

from . import cdr
from .columns import ImuColumns
from .headerless import decode_values_packed, StampChoice
from .mcap_read import iter_batches, McapBulkReader, McapFormatError
from .packed import Batch, compact, concat_batches


class McapBulkSource:
    """Messages of one indexed MCAP file, read chunk by chunk.

    ``base`` is the source that parsed the log's topics (rosbags or the mcap library);
    its ``conns``/``mixed``/counts/times are reused so both report the same metadata.
    """

    def __init__(self, reader: McapBulkReader, base, error=ValueError):
        """Use ``reader`` (summary parsed) for messages and ``base`` for metadata.

        A damaged chunk found while iterating raises ``error`` (the caller's error type).
        """
        self._reader = reader
        self._error = error
        self._base = base
        self.conns = base.conns
        self.mixed = base.mixed
        self.message_count = base.message_count
        self.start_ns = base.start_ns
        self.end_ns = base.end_ns
        known = {c.topic for c in base.conns}
        s = reader.summary
        self._topic = {cid: ch.topic for cid, ch in s.channels.items() if ch.topic in known}
        base_types = {c.topic: c.msgtype for c in base.conns}
        self._type = {cid: s.schemas[ch.schema_id].name if ch.schema_id in s.schemas
                      else base_types.get(ch.topic, '') for cid, ch in s.channels.items()}

    @classmethod
    def open(cls, path, base, error=ValueError) -> McapBulkSource | None:
        """Return a bulk source for ``path``, or None when it has no usable index."""
        reader = McapBulkReader(path)
        if reader.summary is None:
            reader.close()
            return None
        return cls(reader, base, error)

    def channel_ids(self, topics) -> np.ndarray:
        """Channel ids of ``topics`` (all known topics when None)."""
        return np.array(sorted(cid for cid, t in self._topic.items()
                               if topics is None or t in topics), np.uint16)

    def topic_of(self, cid: int) -> str:
        """Topic name of a channel id."""
        return self._topic[cid]

    def batches(self, topics=None) -> Iterator[Batch]:
        """Yield log-time ordered batches of the messages on ``topics`` (None: all)."""
        try:
            yield from iter_batches(self._reader, self.channel_ids(topics))
        except McapFormatError as err:
            raise self._error(f'{err}') from err

    def messages(self, topics) -> Iterator[tuple[str, str, int, bytes]]:
        """Yield ``(topic, msgtype, log_time_ns, raw)`` one by one (rosbags' order)."""
        ids = self.channel_ids(topics)
        if not len(ids):
            return
        topic, typ = self._topic, self._type
        for b in self.batches(topics):
            for cid, t, raw in zip(b.channel.tolist(), b.log_time.tolist(), b.payloads()):
                yield topic[cid], typ[cid], t, raw

    def close(self) -> None:
        """Close the file and the metadata source."""
        self._reader.close()
        self._base.close()


def _payload_rows(b: Batch):
    """Payloads as an (n, size) uint8 array when all have one size, else a list of bytes."""
    if len(b) and b.data_len.min() == b.data_len.max():
        from numpy.lib.stride_tricks import sliding_window_view
        return sliding_window_view(b.buf, int(b.data_len[0]))[b.data_start]
    return b.payloads()


def chunk_stream(batches, imu_topic: str, imu_ids, temp_topics: Sequence[str],
                 temp_ids: Sequence, chunk_size: int, keep_raw: bool,
                 on_batch: Callable[[Batch], None] | None = None,
                 headerless: Mapping[str, str] | None = None,
                 choices: Mapping[str, StampChoice] | None = None
                 ) -> Iterator[tuple[ImuColumns, np.ndarray, dict, list | None]]:
    """Group batches into ``(imu, imu_log_time_ns, {topic: temps}, imu_raw)`` chunks.

    The cut points are those of a per-message chunker: a chunk closes when it holds
    ``chunk_size`` IMU messages or ``chunk_size`` temperature messages (the temperature
    messages logged meanwhile go with it).  ``on_batch`` sees every batch first (used to
    copy all messages to an output).  ``imu_raw`` (with ``keep_raw``) is an (n, size)
    uint8 array when every payload of the chunk has one size, else a list of bytes.
    ``headerless`` maps the temperature topics without a header (std_msgs/Float32, Float64)
    to their type: their readings take the stamp of the IMU message logged before each
    (:func:`.headerless.on_imu_clock`). ``choices`` (per temperature topic, made here when
    not given) keep a header-stamped topic's stamps or put it on the IMU's clock likewise
    (:class:`.headerless.StampChoice`).
    """
    headerless = dict(headerless or {})
    choices = dict(choices or {t: StampChoice(t, t in headerless) for t in temp_topics})
    pend: list = []
    n_imu = n_temp = 0
    carry: list = [None]    # the last IMU stamp of the chunks before

    def lut(ids):
        table = np.zeros(1 << 16, bool)
        table[np.asarray(ids, np.int64)] = True
        return table
    imu_lut = lut(imu_ids)
    temp_luts = [lut(ids) for ids in temp_ids]

    def decode_imu(b: Batch):
        try:
            cols = cdr.decode_imu_packed(b.buf, b.data_start, b.data_len)
        except ValueError as err:
            raise ValueError(f'topic {imu_topic!r}: {err}') from err
        return cols, b.log_time, _payload_rows(b) if keep_raw else None

    def build(final=False):
        if not pend:              # the end, with readings still waiting for their clock
            return (ImuColumns.empty(), np.zeros(0, np.int64),
                    {t: choices[t].place(np.zeros(0, np.int64), np.zeros(0),
                                         np.zeros(0, np.int64), np.zeros(0, np.int64),
                                         carry[0], True) for t in temp_topics},
                    [] if keep_raw else None)
        parts = [p[0] for p in pend]
        cols = ImuColumns.concat([c for c, _, _ in parts])
        frames = {c.frame_id for c, _, _ in parts if len(c)}
        cols.frame_id = frames.pop() if len(frames) == 1 else ''
        times = np.concatenate([t for _, t, _ in parts])
        temps = {}
        for j, topic in enumerate(temp_topics):
            t = concat_batches([p[1][j] for p in pend])
            try:
                if topic in headerless:
                    values = decode_values_packed(t.buf, t.data_start, t.data_len,
                                                  headerless[topic])
                    stamps, frame = np.zeros(len(values), np.int64), ''
                else:
                    tc = cdr.decode_temperature_packed(t.buf, t.data_start, t.data_len)
                    stamps, values, frame = tc.stamp_ns, tc.temperature, tc.frame_id
            except ValueError as err:
                raise ValueError(f'topic {topic!r}: {err}') from err
            choice = choices[topic]
            if choice.on_imu_clock is False:     # header stamps (the common case)
                temps[topic] = tc
            else:
                temps[topic] = choice.place(stamps, values,
                                            np.concatenate([p[2][j] for p in pend]),
                                            cols.stamp_ns, carry[0], final, frame)
        if len(cols):
            carry[0] = int(cols.stamp_ns[-1])
        raws = None
        if keep_raw:
            raws = [r for _, _, r in parts if len(r)]
            if raws and all(isinstance(r, np.ndarray) for r in raws) and len(
                    {r.shape[1] for r in raws}) == 1:
                raws = raws[0] if len(raws) == 1 else np.concatenate(raws)
            else:
                raws = [bytes(x) for r in raws for x in r]
        return cols, times, temps, raws

    for b in batches:
        if on_batch is not None:
            on_batch(b)
        is_imu = imu_lut[b.channel]
        is_temp = [t[b.channel] for t in temp_luts]
        any_temp = np.logical_or.reduce(is_temp) if is_temp else np.zeros(len(b), bool)
        rows = np.flatnonzero(is_imu | any_temp)
        while len(rows):
            ci = n_imu + np.cumsum(is_imu[rows])
            ct = n_temp + np.cumsum(any_temp[rows])
            full = np.flatnonzero((is_imu[rows] & (ci >= chunk_size))
                                  | (any_temp[rows] & (ct >= chunk_size)))
            cut = int(full[0]) + 1 if len(full) else len(rows)
            part = rows[:cut]
            pend.append((decode_imu(b.take(part[is_imu[part]])),
                         [compact(b.take(part[m[part]])) for m in is_temp],
                         [ci[:cut][m[part]] if choices[t].on_imu_clock is not False
                          else None for t, m in zip(temp_topics, is_temp)]))  # IMU rows before
            n_imu, n_temp = int(ci[cut - 1]), int(ct[cut - 1])
            rows = rows[cut:]
            if len(full):
                yield build()
                pend, n_imu, n_temp = [], 0, 0
    if n_imu or n_temp or any(c.holding for c in choices.values()):
        yield build(final=True)
