"""Bulk MCAP writer: whole chunks built with numpy, never one library call per message.

Messages are appended as packed record bytes (copied verbatim from a bulk read, or built
from payloads with one vectorised scatter); when the pending chunk reaches
``chunk_size`` bytes it is compressed (zstd, lz4 or none), CRC'd and written with its
message indexes.  ``finish`` writes DataEnd (data section CRC if asked), then the summary
section (schemas, channels, statistics, chunk indexes, summary offsets) and the footer
with its CRC: the same layout the ``mcap`` library's ``Writer`` produces, checked in
``test/test_io_mcap_bulk.py`` with the mcap library's reader (CRCs validated) and rosbags.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence

import numpy as np

from .mcap_read import (MAGIC, OP_CHANNEL, OP_CHUNK, OP_CHUNK_INDEX, OP_DATA_END, OP_FOOTER,
                        OP_HEADER, OP_MESSAGE, OP_MESSAGE_INDEX, OP_SCHEMA, OP_STATISTICS)
from .packed import Batch, gather, MESSAGE_HEADER

OP_SUMMARY_OFFSET = 0x0E
COMPRESSIONS = ('', 'zstd', 'lz4')


def _string(s: str) -> bytes:
    b = s.encode('utf-8')
    return struct.pack('<I', len(b)) + b


def _record(op: int, content: bytes) -> bytes:
    return struct.pack('<BQ', op, len(content)) + content


def _string_map(m: Mapping) -> bytes:
    body = b''.join(_string(k) + _string(v) for k, v in m.items())
    return struct.pack('<I', len(body)) + body


def _u16_u64_map(m: Mapping) -> bytes:
    body = b''.join(struct.pack('<HQ', k, v) for k, v in sorted(m.items()))
    return struct.pack('<I', len(body)) + body


def message_records(channel_id: int, sequence, log_time, publish_time,
                    payloads: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Build MCAP message records for ``payloads`` in one pass.

    ``payloads`` is a sequence of bytes-like objects or an (n, size) uint8 array;
    ``channel_id`` is one id or one per message.  Returns ``(records, starts)``: the
    records concatenated as uint8 and each record's
    offset in it.  ``sequence``/``log_time``/``publish_time`` are one value per message.
    """
    packed = isinstance(payloads, np.ndarray) and payloads.ndim == 2
    n = len(payloads)
    lens = (np.full(n, payloads.shape[1], np.int64) if packed
            else np.fromiter(map(len, payloads), np.int64, n))
    rec_len = lens + MESSAGE_HEADER
    starts = np.zeros(n, np.int64)
    np.cumsum(rec_len[:-1], out=starts[1:])
    total = int(rec_len.sum())
    out = np.empty(total, np.uint8)
    head = np.empty(n, np.dtype({'names': ['op', 'length', 'channel', 'sequence', 'log_time',
                                           'publish_time'],
                                 'formats': ['u1', '<u8', '<u2', '<u4', '<u8', '<u8'],
                                 'offsets': [0, 1, 9, 11, 15, 23], 'itemsize': MESSAGE_HEADER}))
    head['op'] = OP_MESSAGE
    head['length'] = lens + (MESSAGE_HEADER - 9)
    head['channel'] = channel_id
    head['sequence'] = np.asarray(sequence, np.int64) & 0xFFFFFFFF
    head['log_time'] = np.asarray(log_time, np.int64)
    head['publish_time'] = np.asarray(publish_time, np.int64)
    hb = head.view(np.uint8).reshape(n, MESSAGE_HEADER)
    if n and np.all(lens == lens[0]):
        rows = out.reshape(n, MESSAGE_HEADER + int(lens[0]))
        rows[:, :MESSAGE_HEADER] = hb
        rows[:, MESSAGE_HEADER:] = (payloads if packed else np.frombuffer(
            b''.join(payloads), np.uint8).reshape(n, -1))
        return out, starts
    hidx = (starts[:, None] + np.arange(MESSAGE_HEADER)).reshape(-1)
    out[hidx] = hb.reshape(-1)
    body = np.frombuffer(b''.join(payloads), np.uint8)
    pstart = np.zeros(n, np.int64)
    np.cumsum(lens[:-1], out=pstart[1:])
    out[np.arange(len(body)) + np.repeat(starts + MESSAGE_HEADER - pstart, lens)] = body
    return out, starts


class McapBulkWriter:
    """Write an indexed, chunked MCAP file to the open binary file ``f``.

    ``compression`` is '' (none), 'zstd' or 'lz4'; chunks close once they hold
    ``chunk_size`` bytes of records.  Call ``finish`` to write the summary; the caller
    closes ``f``.
    """

    def __init__(self, f, *, profile: str = 'ros2', library: str = 'thermal_imu_calib',
                 compression: str = '', chunk_size: int = 1 << 20, zstd_level: int = 1,
                 data_crc: bool = False):
        """Write the magic and header record.

        Every chunk gets the CRC of its records; ``data_crc`` also computes the CRC of
        the whole data section (DataEnd; 0 = not computed, as the mcap library's default).
        """
        if compression not in COMPRESSIONS:
            raise ValueError(f'unknown MCAP compression {compression!r}; use one of '
                             f'{COMPRESSIONS}.')
        self._f = f
        self._compression = compression
        self._chunk_size = int(chunk_size)
        self._compress = self._compressor(compression, zstd_level)
        self._crc = 0
        self._data_crc = data_crc
        self._pos = 0
        self.schemas: dict[int, bytes] = {}
        self.channels: dict[int, bytes] = {}
        self._chunk_indexes: list[bytes] = []
        self._counts: dict[int, int] = {}
        self._n = 0
        self._t0: int | None = None
        self._t1: int | None = None
        self._pieces: list[np.ndarray] = []
        self._idx: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending = 0
        self._finished = False
        self._emit(MAGIC + _record(OP_HEADER, _string(profile) + _string(library)))

    @staticmethod
    def _compressor(name: str, level: int):
        if name == 'zstd':
            import zstandard

            cctx = zstandard.ZstdCompressor(level=level)
            return cctx.compress
        if name == 'lz4':
            import lz4.frame

            return lz4.frame.compress
        return None

    def _emit(self, data) -> None:
        self._f.write(data)
        if self._data_crc:
            self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    def add_schema(self, name: str, encoding: str, data: bytes, schema_id: int | None = None
                   ) -> int:
        """Write a schema record; returns its id (the next free one unless given)."""
        sid = schema_id if schema_id is not None else max(self.schemas, default=0) + 1
        if sid in self.schemas or not 0 < sid < 1 << 16:
            raise ValueError(f'schema id {sid} is taken or out of range (1..65535).')
        rec = _record(OP_SCHEMA, struct.pack('<H', sid) + _string(name) + _string(encoding)
                      + struct.pack('<I', len(data)) + data)
        self.schemas[sid] = rec
        self._emit(rec)
        return sid

    def add_channel(self, topic: str, message_encoding: str, schema_id: int,
                    metadata: Mapping | None = None, channel_id: int | None = None) -> int:
        """Write a channel record; returns its id (the next free one unless given)."""
        cid = channel_id if channel_id is not None else max(self.channels, default=-1) + 1
        if cid in self.channels or not 0 <= cid < 1 << 16:
            raise ValueError(f'channel id {cid} is taken or out of range (0..65535).')
        rec = _record(OP_CHANNEL, struct.pack('<HH', cid, schema_id) + _string(topic)
                      + _string(message_encoding) + _string_map(metadata or {}))
        self.channels[cid] = rec
        self._counts[cid] = 0
        self._emit(rec)
        return cid

    def add_messages(self, channel_id, log_time, payloads: Sequence[bytes], *,
                     publish_time=None, sequence=None) -> None:
        """Append messages in the given order (publish time defaults to the log time).

        ``channel_id`` is one id or one per message.
        """
        if not len(payloads):
            return
        log_time = np.asarray(log_time, np.int64)
        publish_time = log_time if publish_time is None else publish_time
        if sequence is None:
            sequence = np.zeros(len(payloads), np.int64)
        recs, starts = message_records(channel_id, sequence, log_time, publish_time, payloads)
        channel = np.broadcast_to(np.asarray(channel_id, np.uint16), (len(starts),))
        self._append(recs, starts, channel, log_time)

    def copy_batch(self, batch: Batch, channel_map: Mapping[int, int] | None = None) -> None:
        """Append the records of ``batch`` verbatim (channel ids mapped by ``channel_map``)."""
        if not len(batch):
            return
        length = batch.data_len + MESSAGE_HEADER
        recs = gather(batch.buf, batch.start, length)
        starts = np.zeros(len(batch), np.int64)
        np.cumsum(length[:-1], out=starts[1:])
        channel = batch.channel
        if channel_map:
            lut = np.arange(1 << 16, dtype=np.uint16)
            for a, b in channel_map.items():
                lut[a] = b
            channel = lut[channel]
            if np.any(channel != batch.channel):
                pos = (starts[:, None] + np.array([9, 10])).reshape(-1)
                recs[pos] = channel.astype('<u2').view(np.uint8)
        self._append(recs, starts, channel, batch.log_time)

    def _append(self, recs: np.ndarray, starts: np.ndarray, channel: np.ndarray,
                log_time: np.ndarray) -> None:
        unknown = np.setdiff1d(np.unique(channel), list(self.channels))
        if len(unknown):
            raise ValueError(f'channel id {int(unknown[0])} was not added; call add_channel '
                             'first.')
        n, i = len(starts), 0
        while i < n:  # cut at record boundaries so chunks stay near chunk_size
            base = int(starts[i])
            room = max(self._chunk_size - self._pending, 1)
            j = max(int(np.searchsorted(starts, base + room, side='left')), i + 1)
            end = int(starts[j]) if j < n else len(recs)
            self._pieces.append(recs[base:end])
            self._idx.append((starts[i:j] - base + self._pending, channel[i:j], log_time[i:j]))
            self._pending += end - base
            i = j
            if self._pending >= self._chunk_size:
                self.flush_chunk()

    def flush_chunk(self) -> None:
        """Write the pending messages as one chunk plus its message indexes."""
        if not self._pieces:
            return
        data = self._pieces[0] if len(self._pieces) == 1 else np.concatenate(self._pieces)
        starts = np.concatenate([i[0] for i in self._idx])
        channel = np.concatenate([i[1] for i in self._idx])
        log_time = np.concatenate([i[2] for i in self._idx])
        self._pieces, self._idx, self._pending = [], [], 0
        t0, t1 = int(log_time.min()), int(log_time.max())
        crc = zlib.crc32(data)
        body = data if self._compress is None else self._compress(data)
        chunk_start = self._pos
        head = struct.pack('<QQQI', t0, t1, len(data), crc) + _string(self._compression) \
            + struct.pack('<Q', len(body))
        self._emit(struct.pack('<BQ', OP_CHUNK, len(head) + len(body)) + head)
        self._emit(body)
        chunk_len = self._pos - chunk_start
        offsets = {}
        index_start = self._pos
        order = np.lexsort((starts, log_time, channel))
        channel, log_time, starts = channel[order], log_time[order], starts[order]
        cuts = np.flatnonzero(np.diff(channel)) + 1
        parts = []
        pos = index_start
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(channel)]):
            cid = int(channel[lo])
            pairs = np.empty((hi - lo, 2), '<u8')
            pairs[:, 0] = log_time[lo:hi]
            pairs[:, 1] = starts[lo:hi]
            rec = _record(OP_MESSAGE_INDEX, struct.pack('<HI', cid, pairs.nbytes)
                          + pairs.tobytes())
            offsets[cid] = pos
            pos += len(rec)
            parts.append(rec)
            self._counts[cid] += hi - lo
        index = b''.join(parts)
        self._emit(index)
        self._n += len(channel)
        self._t0 = t0 if self._t0 is None else min(self._t0, t0)
        self._t1 = t1 if self._t1 is None else max(self._t1, t1)
        self._chunk_indexes.append(_record(OP_CHUNK_INDEX, struct.pack(
            '<QQQQ', t0, t1, chunk_start, chunk_len) + _u16_u64_map(offsets)
            + struct.pack('<Q', len(index)) + _string(self._compression)
            + struct.pack('<QQ', len(body), len(data))))

    def finish(self) -> None:
        """Flush the last chunk, write DataEnd, the summary section and the footer."""
        if self._finished:
            return
        self._finished = True
        self.flush_chunk()
        self._emit(_record(OP_DATA_END, struct.pack('<I', self._crc)))
        summary_start = self._pos
        groups = [(OP_SCHEMA, list(self.schemas.values())),
                  (OP_CHANNEL, list(self.channels.values())),
                  (OP_STATISTICS, [_record(OP_STATISTICS, struct.pack(
                      '<QHIIIIQQ', self._n, len(self.schemas), len(self.channels), 0, 0,
                      len(self._chunk_indexes), self._t0 or 0, self._t1 or 0)
                      + _u16_u64_map(self._counts))]),
                  (OP_CHUNK_INDEX, self._chunk_indexes)]
        summary, offsets = [], []
        pos = summary_start
        for op, recs in groups:
            if not recs:
                continue
            blob = b''.join(recs)
            offsets.append(_record(OP_SUMMARY_OFFSET, struct.pack('<BQQ', op, pos, len(blob))))
            summary.append(blob)
            pos += len(blob)
        summary_offset_start = pos
        data = b''.join(summary + offsets)
        footer_head = struct.pack('<BQQQ', OP_FOOTER, 20, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(data))
        self._f.write(data + footer_head + struct.pack('<I', crc) + MAGIC)
