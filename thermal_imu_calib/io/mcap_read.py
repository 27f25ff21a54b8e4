"""Bulk MCAP reader: whole chunks decompressed, message records parsed with numpy.

The summary section (schemas, channels, statistics, chunk indexes) is read once; then
each chunk is read with one ``read``, decompressed (zstd or lz4), CRC-checked, and its
message records are located from the chunk's message indexes.  The located records are
verified to tile the chunk exactly (any gap is walked record by record and must hold only
non-message records), so the result is the same as walking every record, which is what
happens when a chunk has no message index.  The 31-byte record headers are then parsed
with one structured numpy view, and the payloads stay in the chunk buffer: a
:class:`Batch` carries the buffer plus per-message columns, and
``cdr.decode_imu_packed`` decodes Imu/Temperature fields straight from it.

Messages come out in rosbags' order: by log time, ties by chunk offset, then by position
in the chunk.  Overlapping chunks are merged with a bounded pool (only messages that no
later chunk can precede are released), so memory stays of the order of a few chunks.

Files without a summary or chunk index are not handled here (``read_summary`` returns
None); the caller falls back to a per-message reader.  Damage that this reader detects
(truncated chunk, bad CRC, unknown compression, records that do not fit) raises
:class:`McapFormatError` naming the chunk and its file offset.

The batches, and the numpy row views and gathers over their buffer, are ``io/packed.py``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from .packed import Batch, compact, concat_batches, MESSAGE_HEADER, take_rows

try:  # zlib-ng's SIMD CRC-32: ~10x zlib's (the same checksum)
    from zlib_ng.zlib_ng import crc32
except ImportError:  # pragma: no cover - zlib-ng is a dependency; zlib gives the same values
    from zlib import crc32

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_DATA_END = 7, 8, 11, 15
_MSG_DTYPE = np.dtype({'names': ['op', 'length', 'channel', 'sequence', 'log_time',
                                 'publish_time'],
                       'formats': ['u1', '<u8', '<u2', '<u4', '<u8', '<u8'],
                       'offsets': [0, 1, 9, 11, 15, 23], 'itemsize': MESSAGE_HEADER})
_MAX_SIZE = 1 << 40


class McapFormatError(ValueError):
    """An MCAP file is damaged or uses something this reader does not support."""


@dataclass(frozen=True)
class Schema:
    """An MCAP schema record."""

    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    """An MCAP channel record."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict


@dataclass(frozen=True)
class ChunkIndex:
    """Where a chunk and its message indexes are (an MCAP chunk index record)."""

    message_start_time: int
    message_end_time: int
    chunk_start_offset: int
    chunk_length: int
    message_index_offsets: dict
    message_index_length: int
    compression: str
    compressed_size: int
    uncompressed_size: int


@dataclass
class Summary:
    """What the summary section of a file says."""

    profile: str
    library: str
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    chunk_indexes: list = field(default_factory=list)
    message_count: int | None = None
    message_start_time: int = 0
    message_end_time: int = 0
    channel_message_counts: dict = field(default_factory=dict)


class _Cursor:
    """Little-endian field reader over a bytes object (summary-sized data only)."""

    def __init__(self, data: bytes, pos: int = 0, end: int | None = None, what: str = ''):
        self.data, self.pos = data, pos
        self.end = len(data) if end is None else end
        self.what = what

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > self.end:
            raise McapFormatError(f'{self.what}: a record field runs past the end of its '
                                  'record; the file is damaged (try `mcap recover`).')
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def view(self, n: int) -> memoryview:
        """Return the next ``n`` bytes without a copy, for chunk-sized fields."""
        if n < 0 or self.pos + n > self.end:
            self.take(n)  # raises the error of a field running past its record
        self.pos += n
        return memoryview(self.data)[self.pos - n:self.pos]

    def u8(self):
        return self.take(1)[0]

    def u16(self):
        return struct.unpack('<H', self.take(2))[0]

    def u32(self):
        return struct.unpack('<I', self.take(4))[0]

    def u64(self):
        return struct.unpack('<Q', self.take(8))[0]

    def string(self) -> str:
        return self.take(self.u32()).decode('utf-8', 'replace')

    def blob(self) -> bytes:
        return self.take(self.u32())

    def string_map(self) -> dict:
        end = self.pos + self.u32()
        out = {}
        while self.pos < end:
            k = self.string()
            out[k] = self.string()
        return out

    def u16_u64_map(self) -> dict:
        end = self.pos + self.u32()
        out = {}
        while self.pos < end:
            k = self.u16()
            out[k] = self.u64()
        return out


def _records(data: bytes, what: str) -> Iterator[tuple[int, _Cursor]]:
    """Yield ``(opcode, cursor over its content)`` for a run of records."""
    pos = 0
    while pos < len(data):
        if pos + 9 > len(data):
            raise McapFormatError(f'{what}: truncated record header at byte {pos}; the file '
                                  'is damaged (try `mcap recover`).')
        op, length = struct.unpack_from('<BQ', data, pos)
        if pos + 9 + length > len(data):
            raise McapFormatError(f'{what}: record (opcode 0x{op:02x}) at byte {pos} is '
                                  f'{length} bytes, past the end; the file is damaged (try '
                                  '`mcap recover`).')
        yield op, _Cursor(data, pos + 9, pos + 9 + length, what)
        pos += 9 + length


def read_summary(f, path='') -> Summary | None:
    """Parse header, footer and summary of an open binary MCAP file.

    Returns None when the file has no summary section or no chunk indexes while it has
    messages (the caller then needs a reader that scans the data section).
    """
    f.seek(0, 2)
    size = f.tell()
    f.seek(0)
    head = f.read(8 + 9)
    if head[:8] != MAGIC:
        raise McapFormatError(f'{path}: not an MCAP file (bad magic at byte 0).')
    if size < 8 + 9 + 29 + 8:
        return None
    op, length = struct.unpack_from('<BQ', head, 8)
    if op != OP_HEADER or length > 1 << 20:
        raise McapFormatError(f'{path}: the MCAP header record is missing at byte 8.')
    hdr = _Cursor(f.read(length), what=f'{path}: header')
    summary = Summary(hdr.string(), hdr.string())
    f.seek(size - 8 - 29)
    tail = f.read(29 + 8)
    if tail[-8:] != MAGIC or tail[0] != OP_FOOTER:
        return None  # truncated or unfinished: no footer to find the summary from
    summary_start, summary_offset_start, summary_crc = struct.unpack_from('<QQI', tail, 9)
    if summary_start == 0:
        return None
    footer_at = size - 8 - 29
    if not 8 < summary_start <= footer_at:
        raise McapFormatError(f'{path}: footer points at a summary section at byte '
                              f'{summary_start} outside the file; the file is damaged.')
    f.seek(summary_start)
    data = f.read(footer_at - summary_start)
    if summary_crc and crc32(tail[:1 + 8 + 16], crc32(data)) != summary_crc:
        raise McapFormatError(f'{path}: summary section (byte {summary_start}) fails its CRC '
                              'check; the file is damaged (try `mcap recover`).')
    what = f'{path}: summary section'
    for op, c in _records(data, what):
        if op == OP_SCHEMA:
            s = Schema(c.u16(), c.string(), c.string(), c.blob())
            summary.schemas[s.id] = s
        elif op == OP_CHANNEL:
            ch = Channel(c.u16(), c.u16(), c.string(), c.string(), c.string_map())
            summary.channels[ch.id] = ch
        elif op == OP_STATISTICS:
            summary.message_count = c.u64()
            c.u16(), c.u32(), c.u32(), c.u32(), c.u32()
            summary.message_start_time, summary.message_end_time = c.u64(), c.u64()
            summary.channel_message_counts = c.u16_u64_map()
        elif op == OP_CHUNK_INDEX:
            summary.chunk_indexes.append(ChunkIndex(
                c.u64(), c.u64(), c.u64(), c.u64(), c.u16_u64_map(), c.u64(), c.string(),
                c.u64(), c.u64()))
    if summary.message_count is None or (summary.message_count and not summary.chunk_indexes):
        return None
    return summary


_DECOMPRESS = {}


def _decompressor(name: str):
    if not _DECOMPRESS:
        import lz4.frame
        import zstandard

        _DECOMPRESS[''] = lambda data, size: data
        _DECOMPRESS['zstd'] = lambda data, size: zstandard.ZstdDecompressor().decompress(
            data, max_output_size=size)
        _DECOMPRESS['lz4'] = lambda data, size: lz4.frame.decompress(data)
    return _DECOMPRESS.get(name)


class McapBulkReader:
    """Read an indexed MCAP file chunk by chunk as :class:`Batch` es.

    ``summary`` is None when the file has no usable summary/chunk index; then only
    ``close`` may be called.
    """

    def __init__(self, path):
        """Open ``path`` and parse its summary (raises McapFormatError when damaged)."""
        self.path = str(path)
        self._file = open(path, 'rb')
        try:
            self.summary = read_summary(self._file, self.path)
        except BaseException:
            self._file.close()
            raise

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def __enter__(self) -> McapBulkReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def read_chunk(self, number: int, index: ChunkIndex) -> tuple[bytes, Batch]:
        """Read, decompress and check one chunk; return its records and messages (file order).

        ``number`` only names the chunk in errors.
        """
        where = f'{self.path}: chunk {number} at byte {index.chunk_start_offset}'
        if index.chunk_length > _MAX_SIZE or index.uncompressed_size > _MAX_SIZE:
            raise McapFormatError(f'{where}: implausible chunk size in the chunk index; the '
                                  'file is damaged (try `mcap recover`).')
        f = self._file
        f.seek(index.chunk_start_offset)
        rec = f.read(index.chunk_length + index.message_index_length)
        if len(rec) < index.chunk_length:
            raise McapFormatError(f'{where}: truncated (the file ends after {len(rec)} of its '
                                  f'{index.chunk_length} bytes); re-copy the file or run '
                                  '`mcap recover`.')
        if rec[0] != OP_CHUNK:
            raise McapFormatError(f'{where}: no chunk record there (opcode 0x{rec[0]:02x}); '
                                  'the chunk index is wrong or the file is damaged.')
        c = _Cursor(rec, 9, index.chunk_length, where)
        c.u64(), c.u64()
        usize, crc = c.u64(), c.u32()
        compression = c.string()
        data = c.view(c.u64())  # the records, compressed or not, without a copy
        decompress = _decompressor(compression)
        if decompress is None:
            raise McapFormatError(f'{where}: unknown compression {compression!r}; this reader '
                                  "supports '', 'zstd' and 'lz4' (recompress the file with "
                                  '`mcap compress`).')
        try:
            raw = decompress(data, usize)
        except Exception as err:
            raise McapFormatError(f'{where}: cannot decompress ({compression}): {err}; the '
                                  'chunk is corrupt (try `mcap recover`).') from err
        if len(raw) != usize:
            raise McapFormatError(f'{where}: decompressed to {len(raw)} bytes, its header says '
                                  f'{usize}; the chunk is corrupt (try `mcap recover`).')
        if crc and crc32(raw) != crc:
            raise McapFormatError(f'{where}: CRC mismatch of the uncompressed records; the '
                                  'chunk is corrupt (try `mcap recover`).')
        starts = self._message_starts(raw, rec, index, where)
        return raw, _parse_messages(raw, starts, where)

    def _message_starts(self, raw: bytes, rec: bytes, index: ChunkIndex, where: str
                        ) -> np.ndarray:
        """Record offsets of the chunk's messages, from its message indexes when they check."""
        parts = []
        for cid, off in index.message_index_offsets.items():
            pos = off - index.chunk_start_offset
            if not index.chunk_length <= pos <= len(rec) - 15 or rec[pos] != OP_MESSAGE_INDEX:
                return _walk(raw, where)
            length, = struct.unpack_from('<Q', rec, pos + 1)
            n_bytes, = struct.unpack_from('<I', rec, pos + 11)
            if pos + 15 + n_bytes > len(rec) or n_bytes % 16 or n_bytes + 6 > length:
                return _walk(raw, where)
            pairs = np.frombuffer(rec, '<u8', n_bytes // 8, pos + 15).reshape(-1, 2)
            parts.append(pairs[:, 1])
        if not parts:
            return _walk(raw, where)
        # each index lists its records in log-time order, mostly file order: a merge of
        # sorted runs for the stable (tim)sort
        starts = np.sort(np.concatenate(parts).astype(np.int64), kind='stable')
        u8 = np.frombuffer(raw, np.uint8)
        n = len(raw)
        if len(starts) and (starts[0] < 0 or starts[-1] + MESSAGE_HEADER > n):
            return _walk(raw, where)
        if not len(starts):
            return _walk(raw, where)
        if np.any(u8[starts] != OP_MESSAGE):
            return _walk(raw, where)
        lengths = _u64_at(u8, starts + 1)
        ends = starts + 9 + lengths.astype(np.int64)
        if np.any(lengths > n) or np.any(ends[:-1] > starts[1:]) or ends[-1] > n:
            return _walk(raw, where)
        gaps = np.flatnonzero(ends[:-1] != starts[1:])
        spans = [(0, int(starts[0]))] + [(int(ends[i]), int(starts[i + 1])) for i in gaps]
        spans.append((int(ends[-1]), n))
        for a, b in spans:
            if a == b:
                continue
            for op, _ in _records(raw[a:b], where):
                if op == OP_MESSAGE:  # a message the index does not list
                    return _walk(raw, where)
        return starts


def _u64_at(u8: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return take_rows(u8, 8, pos).view('<u8')[:, 0]


def _walk(raw: bytes, where: str) -> np.ndarray:
    """Record offsets of every message record, walking the records one by one."""
    out = []
    pos, n = 0, len(raw)
    unpack = struct.Struct('<BQ').unpack_from
    while pos < n:
        if pos + 9 > n:
            raise McapFormatError(f'{where}: truncated record header at byte {pos} of the '
                                  'uncompressed chunk; the chunk is corrupt.')
        op, length = unpack(raw, pos)
        if op == OP_MESSAGE:
            out.append(pos)
        pos += 9 + length
    if pos != n:
        raise McapFormatError(f'{where}: the last record runs {pos - n} bytes past the end of '
                              'the uncompressed chunk; the chunk is corrupt.')
    return np.array(out, dtype=np.int64)


def _parse_messages(raw: bytes, starts: np.ndarray, where: str) -> Batch:
    """Parse message record headers at ``starts`` of the uncompressed chunk ``raw``."""
    buf = np.frombuffer(raw, np.uint8)
    if len(starts) == 0:
        z = np.zeros(0, np.int64)
        return Batch(buf, z, z.astype(np.uint16), z.astype(np.uint32), z, z, z)
    if starts[-1] + MESSAGE_HEADER > len(buf):
        raise McapFormatError(f'{where}: message record at byte {int(starts[-1])} of the '
                              'uncompressed chunk is shorter than its header; corrupt chunk.')
    head = take_rows(buf, MESSAGE_HEADER, starts)
    h = head.view(_MSG_DTYPE).reshape(-1)
    length = h['length'].astype(np.int64)
    short = length < MESSAGE_HEADER - 9
    if np.any(short):
        i = int(np.flatnonzero(short)[0])
        raise McapFormatError(f'{where}: message record at byte {int(starts[i])} of the '
                              'uncompressed chunk is shorter than a message header; corrupt.')
    return Batch(buf, starts, h['channel'].copy(), h['sequence'].copy(),
                 h['log_time'].astype(np.int64), h['publish_time'].astype(np.int64),
                 length - (MESSAGE_HEADER - 9))


def iter_batches(reader: McapBulkReader, channels: Iterable[int] | None = None
                 ) -> Iterator[Batch]:
    """Yield batches of the messages on ``channels`` (all when None) in log-time order.

    Ties are ordered by chunk offset in the file, then record order inside the chunk (the
    order rosbags' reader gives).  Each batch holds at most a few chunks' messages.
    """
    summary = reader.summary
    wanted = None if channels is None else np.array(sorted(set(channels)), np.uint16)
    order = sorted(range(len(summary.chunk_indexes)),
                   key=lambda i: (summary.chunk_indexes[i].message_start_time,
                                  summary.chunk_indexes[i].chunk_start_offset))
    pool: Batch | None = None
    pool_key = np.zeros(0, np.int64)  # chunk_start_offset per pooled message
    for k, i in enumerate(order):
        index = summary.chunk_indexes[i]
        if wanted is not None and index.message_index_offsets and not any(
                int(c) in index.message_index_offsets for c in wanted):
            continue
        _, batch = reader.read_chunk(i, index)
        if wanted is not None:
            keep = np.zeros(1 << 16, bool)
            keep[wanted] = True
            batch = batch.take(keep[batch.channel])
        parts = ([pool] if pool is not None and len(pool) else []) + [batch]
        keys = ([pool_key] if pool is not None and len(pool) else []) + [
            np.full(len(batch), index.chunk_start_offset, np.int64)]
        pool = concat_batches(parts)
        pool_key = np.concatenate(keys)
        # stable: record order within a chunk (and the pool's own order) is kept
        lt = pool.log_time
        if not (np.all(lt[1:] >= lt[:-1]) and np.all(pool_key[1:] >= pool_key[:-1])):
            srt = np.lexsort((pool_key, lt))   # (already in that order: nothing to do)
            if np.any(srt != np.arange(len(srt))):
                pool, pool_key = pool.take(srt), pool_key[srt]
        nxt = (summary.chunk_indexes[order[k + 1]].message_start_time
               if k + 1 < len(order) else None)
        if nxt is None:
            continue
        cut = int(np.searchsorted(pool.log_time, nxt, side='left'))
        if cut:
            yield pool.take(slice(0, cut))
            rest = pool.take(slice(cut, None))
            pool = compact(rest) if len(rest) else None
            pool_key = pool_key[cut:]
    if pool is not None and len(pool):
        yield pool
