"""Thermal inputs without a header (std_msgs/Float32, Float64), put on the IMU's clock.

Some drivers publish the die temperature as a bare number: the ROS 2 um6/um7 drivers
publish ``std_msgs/msg/Float32`` on ``imu/temperature``. With no header stamp, a reading is
placed on the IMU's clock the way a node receiving both topics places it: it takes the
header stamp of the newest IMU message logged (offline) or received (live) before it. A
log is read in log-time order, so offline that is exact; live it is exact to the node's
batching of IMU messages (one message when it keeps up). Readings before the first IMU
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


def _check(u8: np.ndarray, msgtype: str) -> None:
    """Raise ValueError unless every row of ``u8`` starts with the little-endian header."""
    bad = np.flatnonzero((u8[:, 0] != 0) | (u8[:, 1] != 1))
    if len(bad):
        row = int(bad[0])
        raise ValueError(f'{msgtype} message {row} is not little-endian CDR (encapsulation '
                         f'{bytes(u8[row, :2]).hex()}); re-record or convert the log with a '
                         'little-endian ROS 2 middleware.')


def _too_short(msgtype: str, sizes: np.ndarray, size: int) -> None:
    short = np.flatnonzero(sizes < size)
    if len(short):
        raise ValueError(f'{msgtype} message {int(short[0])} is only {int(sizes[short[0]])} '
                         f'bytes, too short to be a {msgtype} ({size}); check that the topic '
                         f'really carries {msgtype} messages.')


def decode_values(raws: Sequence[bytes], msgtype: str) -> np.ndarray:
    """Return the values (float64) of serialized ``msgtype`` messages (Float32/Float64)."""
    dtype = HEADERLESS_MSGTYPES[msgtype]
    size = 4 + dtype.itemsize
    n = len(raws)
    if not n:
        return np.zeros(0)
    _too_short(msgtype, np.fromiter(map(len, raws), np.int64, n), size)
    u8 = np.frombuffer(b''.join(r[:size] for r in raws), np.uint8).reshape(n, size)
    _check(u8, msgtype)
    return u8[:, 4:].copy().view(dtype)[:, 0].astype(np.float64)


def decode_values_packed(buf: np.ndarray, starts, lengths, msgtype: str) -> np.ndarray:
    """Like :func:`decode_values` for payloads packed in one uint8 buffer."""
    dtype = HEADERLESS_MSGTYPES[msgtype]
    size = 4 + dtype.itemsize
    lengths = np.asarray(lengths, np.int64)
    if not len(lengths):
        return np.zeros(0)
    _too_short(msgtype, lengths, size)
    u8 = take_rows(buf, size, np.asarray(starts, np.int64))
    _check(u8, msgtype)
    return u8[:, 4:].copy().view(dtype)[:, 0].astype(np.float64)


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
