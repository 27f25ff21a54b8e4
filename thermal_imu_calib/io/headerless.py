"""Thermal inputs without a header (std_msgs/Float32, Float64), put on the IMU's clock.

Some drivers publish the die temperature as a bare number: the ROS 2 um6/um7 drivers
publish ``std_msgs/msg/Float32`` on ``imu/temperature``. With no header stamp, a reading is
placed on the IMU's clock: it takes the header stamp of the IMU message logged before it
(offline, :func:`on_imu_clock`; a log is read in log-time order) or published before it
(live, :class:`LiveImuClock`, by the DDS source timestamps). Readings before the first IMU
message are not used. Several readings between two IMU messages share that stamp and the
last one counts (``align.TemperatureTrack`` keeps the last value added at a stamp).

Values are degC for a temperature, or a thermal proxy in its declared unit, as for the
header-stamped types of ``cdr.SCALAR_MSGTYPES``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .cdr import SCALAR_MSGTYPES
from .columns import TemperatureColumns
from .mcap_read import take_rows

#: header-less scalars a thermal input may arrive as: message type -> CDR value dtype
HEADERLESS_MSGTYPES = {'std_msgs/msg/Float32': np.dtype('<f4'),
                       'std_msgs/msg/Float64': np.dtype('<f8')}
#: every message type a thermal input may be read from
THERMAL_MSGTYPES = (*SCALAR_MSGTYPES, *HEADERLESS_MSGTYPES)

_ENCAPSULATION = b'\x00\x01\x00\x00'   # little-endian XCDR1 (what ROS 2 writes)


def _values(u8: np.ndarray, msgtype: str) -> np.ndarray:
    """Return the values (float64) of (n, 4 + value size) payload rows of ``msgtype``.

    Raises ValueError unless every row starts with the little-endian CDR header.
    """
    bad = np.flatnonzero((u8[:, 0] != 0) | (u8[:, 1] != 1))
    if len(bad):
        row = int(bad[0])
        raise ValueError(f'{msgtype} message {row} is not little-endian CDR (encapsulation '
                         f'{bytes(u8[row, :2]).hex()}); re-record or convert the log with a '
                         'little-endian ROS 2 middleware.')
    return u8[:, 4:].copy().view(HEADERLESS_MSGTYPES[msgtype])[:, 0].astype(np.float64)


def _too_short(msgtype: str, sizes: np.ndarray, size: int) -> None:
    short = np.flatnonzero(sizes < size)
    if len(short):
        raise ValueError(f'{msgtype} message {int(short[0])} is only {int(sizes[short[0]])} '
                         f'bytes, too short to be a {msgtype} ({size}); check that the topic '
                         f'really carries {msgtype} messages.')


def decode_values(raws: Sequence[bytes], msgtype: str) -> np.ndarray:
    """Return the values (float64) of serialized ``msgtype`` messages (Float32/Float64)."""
    size = 4 + HEADERLESS_MSGTYPES[msgtype].itemsize
    n = len(raws)
    if not n:
        return np.zeros(0)
    _too_short(msgtype, np.fromiter(map(len, raws), np.int64, n), size)
    return _values(np.frombuffer(b''.join(r[:size] for r in raws), np.uint8).reshape(n, size),
                   msgtype)


def decode_values_packed(buf: np.ndarray, starts, lengths, msgtype: str) -> np.ndarray:
    """Like :func:`decode_values` for payloads packed in one uint8 buffer."""
    size = 4 + HEADERLESS_MSGTYPES[msgtype].itemsize
    lengths = np.asarray(lengths, np.int64)
    if not len(lengths):
        return np.zeros(0)
    _too_short(msgtype, lengths, size)
    return _values(take_rows(buf, size, np.asarray(starts, np.int64)), msgtype)


def encode_values(values, msgtype: str) -> list[bytes]:
    """Serialize values as ``msgtype`` CDR messages (Float32 rounds to single precision)."""
    dtype = HEADERLESS_MSGTYPES[msgtype]
    v = np.asarray(values, np.float64).reshape(-1).astype(dtype)
    return [_ENCAPSULATION + x.tobytes() for x in v]


def on_imu_clock(values: np.ndarray, imu_before: np.ndarray, imu_stamp_ns: np.ndarray,
                 carry_ns: int | None) -> TemperatureColumns:
    """Stamp header-less readings with the newest IMU stamp logged before each.

    ``imu_before[i]`` is how many IMU messages of this span were logged before reading
    ``i``; ``imu_stamp_ns`` are those IMU messages' header stamps (ns, log order) and
    ``carry_ns`` the stamp of the last IMU message of the spans before (None: none yet).
    Readings with no IMU message before them are left out.
    """
    values = np.asarray(values, np.float64)
    before = np.asarray(imu_before, np.int64)
    prior = np.int64(0 if carry_ns is None else carry_ns)
    table = np.concatenate([[prior], np.asarray(imu_stamp_ns, np.int64)])
    keep = (before > 0) | (carry_ns is not None)
    return TemperatureColumns(table[before[keep]], values[keep])


class LiveImuClock:
    """Put header-less readings on the IMU's clock live, in the order they were published.

    A node's callbacks do not run in publish order (the executor may take a temperature
    before the IMU messages published ahead of it), so the order comes from the publishers:
    the DDS source timestamp of each message (ns, taken at publish; ``ros2 bag play`` and a
    driver publishing both topics keep the log's order). Feed the IMU messages with
    :meth:`add_imu` and the readings with :meth:`add_reading`; :meth:`take` returns the
    readings published before the newest IMU message seen, each with the header stamp of
    the newest IMU message published before it, as offline (:func:`on_imu_clock`). A
    reading published after every IMU message seen waits for the next one (one topic is
    delivered in order, so none published before it can still come); ``take(index,
    everything=True)`` stamps the waiting ones with the newest IMU stamp (the end of a
    stream, as offline). Readings
    published before the first IMU message are left out. The newest ``history`` IMU messages
    at least are kept (at most twice that; a reading published before all of them takes the
    oldest's stamp).
    """

    def __init__(self, n_inputs: int, history: int = 4096):
        self.history = int(history)
        # IMU source timestamps (increasing) and header stamps in [:n]; room for two
        # histories, so an append copies only the new messages (the kept half moves down
        # once per ``history`` messages)
        self._src_buf = np.zeros(2 * self.history, np.int64)
        self._stamp_buf = np.zeros(2 * self.history, np.int64)
        self._n = 0
        self._wait: list[list[tuple[int, float]]] = [[] for _ in range(n_inputs)]
        self.left_out = 0                       # readings before the first IMU message
        self._trimmed = False                   # older IMU messages were let go

    @property
    def _src(self) -> np.ndarray:
        return self._src_buf[:self._n]

    @property
    def _stamp(self) -> np.ndarray:
        return self._stamp_buf[:self._n]

    def add_imu(self, source_ns, stamp_ns) -> None:
        """Add IMU messages (source timestamps and header stamps, ns, in arrival order)."""
        b = min(len(source_ns), self.history)
        if not b:
            return
        if b < len(source_ns):                         # more than a history at once
            self._n, self._trimmed = 0, True
        if self._n + b > len(self._src_buf):          # keep the newest history - b
            keep = self.history - b
            self._src_buf[:keep] = self._src_buf[self._n - keep:self._n]
            self._stamp_buf[:keep] = self._stamp_buf[self._n - keep:self._n]
            self._n, self._trimmed = keep, True
        n = self._n
        if b == 1:                                     # one message: no array to build
            first = self._src_buf[n] = source_ns[-1]
            self._stamp_buf[n] = stamp_ns[-1]
            ordered = True
        else:
            src = np.asarray(source_ns, np.int64)[-b:]
            self._src_buf[n:n + b] = src
            self._stamp_buf[n:n + b] = np.asarray(stamp_ns, np.int64)[-b:]
            first, ordered = src[0], not np.any(src[1:] < src[:-1])
        self._n = n + b
        if not ordered or (n and first < self._src_buf[n - 1]):
            order = np.argsort(self._src, kind='stable')   # another publisher's clock
            self._src_buf[:self._n] = self._src[order]
            self._stamp_buf[:self._n] = self._stamp[order]

    def add_reading(self, index: int, source_ns: int, value: float) -> None:
        """Add one reading of input ``index`` (its source timestamp, ns)."""
        self._wait[index].append((int(source_ns), float(value)))

    def take(self, index: int, everything: bool = False) -> TemperatureColumns:
        """Return input ``index``'s readings that can be stamped now (all with ``everything``)."""
        wait = self._wait[index]
        if not wait or not self._n:
            if everything:
                self.left_out += len(wait)
                wait.clear()
            return TemperatureColumns.empty()
        src = np.array([s for s, _ in wait], np.int64)
        ready = np.ones(len(wait), bool) if everything else src <= self._src[-1]
        n = int(np.count_nonzero(ready))
        if not n:
            return TemperatureColumns.empty()
        values = np.array([v for _, v in wait], float)[ready]
        before = np.searchsorted(self._src, src[ready], side='right')   # IMU first at a tie
        first = (before > 0) | self._trimmed
        self.left_out += int(n - first.sum())
        self._wait[index] = [w for w, r in zip(wait, ready) if not r]
        return TemperatureColumns(self._stamp[np.maximum(before[first] - 1, 0)], values[first])
