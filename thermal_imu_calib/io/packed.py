"""Message records packed in one uint8 buffer: the batch of an MCAP file's messages.

A :class:`Batch` is messages in log-time order whose records (header and payload) sit in
one ``uint8`` buffer, with per-message columns beside it; ``cdr.decode_imu_packed`` decodes
fields straight from the buffer. The helpers read fixed-width rows at many offsets of such
a buffer (``windows``, ``take_rows``) and concatenate pieces of it (``gather``) with numpy,
without a Python loop per message. Times are int64 nanoseconds; offsets and lengths bytes.
Read by ``io/mcap_read.py``, written by ``io/mcap_write.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: an MCAP message record's header: opcode, record length, channel id, sequence, log time,
#: publish time (bytes)
MESSAGE_HEADER = 31


@dataclass
class Batch:
    """Messages in log-time order whose records sit in one uint8 buffer.

    ``start`` is each record's offset in ``buf`` (its opcode byte); the payload is
    ``buf[start + 31 : start + 31 + data_len]``.  Times are int64 nanoseconds.
    """

    buf: np.ndarray
    start: np.ndarray
    channel: np.ndarray
    sequence: np.ndarray
    log_time: np.ndarray
    publish_time: np.ndarray
    data_len: np.ndarray

    def __len__(self):
        return int(self.start.shape[0])

    @property
    def data_start(self) -> np.ndarray:
        """Payload offsets in ``buf``."""
        return self.start + MESSAGE_HEADER

    def take(self, rows) -> Batch:
        """Return the messages at ``rows`` (indices or mask), sharing the buffer."""
        return Batch(self.buf, self.start[rows], self.channel[rows], self.sequence[rows],
                     self.log_time[rows], self.publish_time[rows], self.data_len[rows])

    def payloads(self) -> list[bytes]:
        """Return each payload as a bytes object (for per-message consumers)."""
        raw = self.buf.tobytes() if len(self) else b''
        s = self.data_start.tolist()
        e = (self.data_start + self.data_len).tolist()
        return [raw[a:b] for a, b in zip(s, e)]

    def records(self) -> np.ndarray:
        """Return every message record (header and payload) verbatim, as one uint8 array."""
        return gather(self.buf, self.start, self.data_len + MESSAGE_HEADER)


def windows(buf: np.ndarray, width: int) -> np.ndarray:
    """Return the read-only (len - width + 1, width) view of every ``width``-byte window.

    ``sliding_window_view`` for a contiguous 1-d uint8 array, built without its overhead
    (this is called a few times per chunk); row ``i`` is ``buf[i:i + width]``.
    """
    if buf.ndim != 1 or buf.itemsize != 1 or not buf.flags.c_contiguous or width > len(buf):
        from numpy.lib.stride_tricks import sliding_window_view
        return sliding_window_view(buf, width)
    out = np.ndarray((len(buf) - width + 1, width), buf.dtype, buf, 0, (1, 1))
    out.flags.writeable = False
    return out


def take_rows(buf: np.ndarray, width: int, starts) -> np.ndarray:
    """Return the (n, width) uint8 copy of ``buf[s:s + width]`` for each ``s`` in ``starts``.

    ``windows(buf, width)[starts]``, but each row is copied as one ``V<width>`` item (a
    memcpy) instead of byte by byte: about twice as fast for the short fields read here.
    """
    if (width <= 0 or buf.ndim != 1 or buf.itemsize != 1 or not buf.flags.c_contiguous
            or width > len(buf)):
        return windows(buf, width)[starts]
    items = np.ndarray((len(buf) - width + 1,), np.dtype(f'V{width}'), buf, 0, (1,))
    return items[starts].view(np.uint8).reshape(-1, width)


def gather(buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenate ``buf[starts[i]:starts[i] + lengths[i]]`` for all i (uint8).

    Adjacent pieces are merged into runs, so records copied in file order (the usual case)
    cost one memcpy per run.
    """
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if not len(starts) or int(lengths.sum()) == 0:
        return np.zeros(0, np.uint8)
    ends = starts + lengths
    brk = np.flatnonzero(ends[:-1] != starts[1:]) + 1
    if len(brk) < 64:
        lo = np.r_[0, brk]
        hi = np.r_[brk, len(starts)] - 1
        pieces = [buf[a:b] for a, b in zip(starts[lo].tolist(), ends[hi].tolist())]
        return pieces[0].copy() if len(pieces) == 1 else np.concatenate(pieces)
    if lengths[0] == lengths.min() == lengths.max():
        # equal-size pieces (records of one message type): one row gather
        return take_rows(buf, int(lengths[0]), starts).reshape(-1)
    total = int(lengths.sum())
    shift = starts - (np.cumsum(lengths) - lengths)
    idx = np.arange(total, dtype=np.int64) + np.repeat(shift, lengths)
    return buf[idx]


def concat_batches(batches: list[Batch]) -> Batch:
    """Concatenate batches into one (their buffers are copied into one, unless only one)."""
    batches = [b for b in batches if len(b)] or batches[:1]
    if not batches:
        z = np.zeros(0, np.int64)
        return Batch(np.zeros(0, np.uint8), z, z.astype(np.uint16), z.astype(np.uint32), z,
                     z, z)
    if len(batches) == 1:
        return batches[0]
    bufs, starts, shift = [], [], 0
    for b in batches:
        bufs.append(b.buf)
        starts.append(b.start + shift)
        shift += len(b.buf)
    cat = np.concatenate
    return Batch(cat(bufs), cat(starts), cat([b.channel for b in batches]),
                 cat([b.sequence for b in batches]), cat([b.log_time for b in batches]),
                 cat([b.publish_time for b in batches]), cat([b.data_len for b in batches]))


def compact(batch: Batch) -> Batch:
    """Copy the records of ``batch`` into a fresh buffer of just them."""
    length = batch.data_len + MESSAGE_HEADER
    buf = gather(batch.buf, batch.start, length)
    start = (np.cumsum(length) - length).astype(np.int64)
    return Batch(buf, start, batch.channel, batch.sequence, batch.log_time,
                 batch.publish_time, batch.data_len)
