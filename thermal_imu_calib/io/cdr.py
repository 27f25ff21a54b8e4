"""Bulk CDR fast path for ``sensor_msgs/msg/Imu`` and ``sensor_msgs/msg/Temperature``.

ROS 2 serialises both messages as little-endian XCDR1 (encapsulation ``00 01 00 00``).
Alignment is relative to the first byte after that 4-byte encapsulation header, so
with ``L`` the frame_id length including its NUL terminator the payload is::

    0   int32  header.stamp.sec
    4   uint32 header.stamp.nanosec
    8   uint32 L
    12  L bytes frame_id (NUL terminated), zero padding up to o = align8(12 + L)
    o   float64 fields (Imu: 37 of them, Temperature: temperature, variance)

Messages of equal total size and equal ``o`` share one layout, so a batch is decoded by
grouping on those two numbers and reading each group with a single structured
``np.frombuffer`` over the joined buffer; the only per-message Python work is ``len`` and
the final split into ``bytes`` objects.  Everything here is cross-checked against
rosbags' ``serialize_cdr``/``deserialize_cdr`` in ``test/test_io_cdr.py``.

Big-endian CDR (encapsulation ``00 00``) and XCDR2 payloads are refused with ValueError.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
from .columns import ImuColumns, TemperatureColumns
from .packed import take_rows

IMU_MSGTYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_MSGTYPE = 'sensor_msgs/msg/Temperature'
#: header-stamped scalars with the Temperature layout (header, float64 value, float64
#: variance): any of them can carry a thermal input (a proxy's unit is declared by the
#: user); message type -> name of the value field
SCALAR_MSGTYPES = {TEMPERATURE_MSGTYPE: 'temperature',
                   'sensor_msgs/msg/FluidPressure': 'fluid_pressure',
                   'sensor_msgs/msg/Illuminance': 'illuminance',
                   'sensor_msgs/msg/RelativeHumidity': 'relative_humidity'}

CDR_LE_HEADER = b'\x00\x01\x00\x00'
_HDR = 4  # encapsulation header bytes; payload offsets below are relative to its end

# float64 fields after the padded header, as (name, count).
_IMU_FIELDS = (
    ('orientation', 4),
    ('orientation_covariance', 9),
    ('angular_velocity', 3),
    ('angular_velocity_covariance', 9),
    ('linear_acceleration', 3),
    ('linear_acceleration_covariance', 9),
)
_TEMPERATURE_FIELDS = (('temperature', 1), ('variance', 1))


def _align8(x):
    return (x + 7) & ~7


def _layout(fields: Sequence[tuple[str, int]], body: int, itemsize: int) -> np.dtype:
    """Return a structured dtype for records of ``itemsize`` bytes whose floats start at body."""
    names = ['encapsulation', 'sec', 'nanosec', 'frame_len']
    formats: list = ['<u2', '<i4', '<u4', '<u4']
    offsets = [0, _HDR + 0, _HDR + 4, _HDR + 8]
    pos = _HDR + body
    for name, count in fields:
        names.append(name)
        formats.append(('<f8', (count,)) if count > 1 else '<f8')
        offsets.append(pos)
        pos += 8 * count
    return np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                     'itemsize': itemsize})


def _payload_size(fields: Sequence[tuple[str, int]]) -> int:
    return 8 * sum(count for _, count in fields)


def _groups(raws: Sequence[bytes], fields: Sequence[tuple[str, int]], what: str
            ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """Yield ``(rows, records, u8, body)`` per layout group.

    ``rows`` are indices into ``raws``, ``records`` a structured (read-only) view, ``u8``
    the same bytes as an (n, size) uint8 array and ``body`` the offset of the floats.
    """
    n = len(raws)
    if n == 0:
        return
    sizes = np.fromiter(map(len, raws), np.int64, n)

    def rows_u8(rows, size):
        buf = b''.join([raws[i] for i in rows]) if len(rows) < n else b''.join(raws)
        return np.frombuffer(buf, np.uint8).reshape(len(rows), size)
    yield from _sized_groups(sizes, rows_u8, fields, what)


def _packed_groups(buf: np.ndarray, starts, lengths, fields, what):
    """Like :func:`_groups` for payloads packed in one uint8 buffer (no bytes objects).

    Payload ``i`` is ``buf[starts[i]:starts[i] + lengths[i]]``; rows of equal size are
    gathered with one fancy index over a sliding-window view (a copy of just those bytes).
    """
    starts = np.asarray(starts, dtype=np.int64)
    sizes = np.asarray(lengths, dtype=np.int64)
    if len(sizes) == 0:
        return

    def rows_u8(rows, size):
        if size == 0 or len(buf) < size:
            return np.zeros((len(rows), size), np.uint8)
        return take_rows(buf, size, starts[rows])
    yield from _sized_groups(sizes, rows_u8, fields, what)


def _sized_groups(sizes, rows_u8, fields, what):
    """Yield ``(rows, records, u8, body)`` per layout group; ``rows_u8(rows, size)`` gathers."""
    floats = _payload_size(fields)
    one = sizes.min() == sizes.max()
    for size in (sizes[:1] if one else np.unique(sizes)):
        size = int(size)
        rows = np.arange(len(sizes)) if one else np.flatnonzero(sizes == size)
        if size < _HDR + 12 + floats:
            raise ValueError(
                f'{what} message {int(rows[0])} is only {size} bytes, too short to be a '
                f'{what}; check that the topic really carries {what} messages.')
        u8 = rows_u8(rows, size)
        encap = u8[:, 1].astype(np.uint16) | (u8[:, 0].astype(np.uint16) << 8)
        if np.any(encap != 1):
            bad = int(encap[np.flatnonzero(encap != 1)[0]])
            kind = 'big-endian CDR' if bad == 0 else f'encapsulation kind 0x{bad:04x}'
            raise ValueError(
                f'{what} payload uses {kind}; only little-endian CDR (00 01) is supported, '
                'so re-record or convert the log with a little-endian ROS 2 middleware.')
        frame_len = u8[:, _HDR + 8:_HDR + 12].copy().view('<u4')[:, 0].astype(np.int64)
        body = (12 + frame_len + 7) & ~7
        bad = (_HDR + body + floats > size) | (frame_len == 0)
        if np.any(bad):
            raise ValueError(
                f'{what} message {int(rows[np.flatnonzero(bad)[0]])} has a frame_id length field '
                f'that does not fit in its {size} bytes; the data is corrupt or not a {what}.')
        same = body.min() == body.max()
        for b in (body[:1] if same else np.unique(body)):
            sel = slice(None) if same else body == b
            sub = u8 if same else u8[sel]
            records = sub.view(_layout(fields, int(b), size)).reshape(-1)
            yield rows[sel], records, sub, int(b)


def _frame_id(u8: np.ndarray, frame_len: np.ndarray) -> str | None:
    """Return the common frame_id of a group, or None when the rows differ."""
    L = int(frame_len[0])
    if np.any(frame_len != L):
        return None
    text = u8[:, _HDR + 12:_HDR + 12 + L - 1]
    if len(text) > 1 and np.any(text != text[0]):
        return None
    return bytes(text[0]).decode('utf-8', errors='replace')


def _stamps(records: np.ndarray) -> np.ndarray:
    return records['sec'].astype(np.int64) * 1_000_000_000 + records['nanosec'].astype(np.int64)


def _merge_frame(current, new):
    if current is False:
        return new
    return current if current == new else None


def decode_imu(raws: Sequence[bytes]) -> ImuColumns:
    """Decode serialized ``sensor_msgs/msg/Imu`` messages into columns (input order kept).

    ``frame_id`` is the common frame of all messages, or '' when they differ.
    Raises ValueError for big-endian or malformed payloads.
    """
    return _imu_columns(len(raws), _groups(raws, _IMU_FIELDS, 'Imu'))


def decode_imu_packed(buf: np.ndarray, starts, lengths) -> ImuColumns:
    """Decode Imu payloads packed in the uint8 array ``buf`` (``buf[starts[i]:+lengths[i]]``).

    Same result and checks as :func:`decode_imu`, without one bytes object per message
    (what the bulk MCAP reader hands over).
    """
    fast = _imu_packed_one_layout(buf, starts, lengths)
    if fast is not None:
        return fast
    return _imu_columns(len(lengths), _packed_groups(buf, starts, lengths, _IMU_FIELDS, 'Imu'))


_HEAD = np.dtype({'names': ['sec', 'nanosec', 'frame_len'], 'formats': ['<i4', '<u4', '<u4'],
                  'offsets': [_HDR, _HDR + 4, _HDR + 8], 'itemsize': _HDR + 12})
_GYRO_AT = 8 * 13     # angular_velocity after orientation (4) and its covariance (9)
_ACCEL_AT = 8 * 25    # linear_acceleration after angular_velocity (3) and its covariance (9)


def _imu_packed_one_layout(buf: np.ndarray, starts, lengths) -> ImuColumns | None:
    """Decode packed Imu payloads that all share one layout, gathering only what is used.

    Only the 16 header bytes, the two float64 triples and the frame_id are copied out
    (not the 37 floats of every message). Returns None when sizes, frame_id lengths or
    encapsulations differ or anything fails a check: the general path then decodes (and
    raises its errors); the values are the same bytes either way.
    """
    starts = np.asarray(starts, dtype=np.int64)
    sizes = np.asarray(lengths, dtype=np.int64)
    n = len(sizes)
    if n == 0 or sizes.min() != sizes.max():
        return None
    size = int(sizes[0])
    if size < _HDR + 12 + _payload_size(_IMU_FIELDS) or len(buf) < size:
        return None
    head = take_rows(buf, _HDR + 12, starts)
    if np.any(head[:, 0] != 0) or np.any(head[:, 1] != 1):
        return None
    h = head.view(_HEAD).reshape(-1)
    frame_len = h['frame_len']
    flen = int(frame_len[0])
    if flen == 0 or np.any(frame_len != flen):
        return None
    body = _HDR + ((12 + flen + 7) & ~7)
    if body - _HDR + _payload_size(_IMU_FIELDS) > size - _HDR:
        return None
    frame = ''
    if flen > 1:
        text = take_rows(buf, flen - 1, starts + (_HDR + 12))
        if len(text) > 1 and np.any(text != text[0]):
            frame = None
        else:
            frame = bytes(text[0]).decode('utf-8', errors='replace')
    gyro = take_rows(buf, 24, starts + (body + _GYRO_AT)).view('<f8')
    accel = take_rows(buf, 24, starts + (body + _ACCEL_AT)).view('<f8')
    stamp = h['sec'].astype(np.int64) * 1_000_000_000 + h['nanosec'].astype(np.int64)
    return ImuColumns(stamp, accel.astype(np.float64, copy=False),
                      gyro.astype(np.float64, copy=False), frame or '')


def _imu_columns(n: int, groups) -> ImuColumns:
    stamp = np.empty(n, np.int64)
    accel = np.empty((n, 3))
    gyro = np.empty((n, 3))
    frame = False
    for rows, rec, u8, _ in groups:
        stamp[rows] = _stamps(rec)
        accel[rows] = rec['linear_acceleration']
        gyro[rows] = rec['angular_velocity']
        frame = _merge_frame(frame, _frame_id(u8, rec['frame_len']))
    return ImuColumns(stamp, accel, gyro, frame or '')


def decode_imu_full(raws: Sequence[bytes]) -> dict[str, np.ndarray]:
    """Decode every Imu field: stamp_ns, orientation (n,4) and the three (n,9) covariances."""
    n = len(raws)
    out = {'stamp_ns': np.empty(n, np.int64)}
    for name, count in _IMU_FIELDS:
        out[name] = np.empty((n, count))
    for rows, rec, _, _ in _groups(raws, _IMU_FIELDS, 'Imu'):
        out['stamp_ns'][rows] = _stamps(rec)
        for name, _ in _IMU_FIELDS:
            out[name][rows] = rec[name]
    return out


def _split(buf: bytes, size: int) -> list[bytes]:
    return [buf[i:i + size] for i in range(0, len(buf), size)]


def _patch(raws: Sequence[bytes], fields: dict[str, np.ndarray], what: str,
           layout=_IMU_FIELDS) -> list[bytes]:
    out: list = [None] * len(raws)
    for rows, _, u8, body in _groups(raws, layout, what):
        size = u8.shape[1]
        work = np.array(u8)  # writable copy
        rec = work.view(_layout(layout, body, size)).reshape(-1)
        for name, values in fields.items():
            rec[name] = values[rows]
        for i, piece in zip(rows, _split(work.tobytes(), size)):
            out[i] = piece
    return out


def _as_rows(values, n: int, width: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (n, width):
        raise ValueError(f'{name} has shape {arr.shape}, expected ({n}, {width}); pass one '
                         f'row per message.')
    return arr


def patch_imu(raws: Sequence[bytes], accel, gyro) -> list[bytes]:
    """Return copies of ``raws`` with linear_acceleration and angular_velocity replaced.

    ``accel`` and ``gyro`` are (n, 3) arrays in m/s^2 and rad/s, one row per message;
    every other byte (header, orientation, covariances, padding) is left identical.
    """
    n = len(raws)
    return _patch(raws, {'linear_acceleration': _as_rows(accel, n, 3, 'accel'),
                         'angular_velocity': _as_rows(gyro, n, 3, 'gyro')}, 'Imu')


def patch_imu_rows(u8: np.ndarray, accel, gyro) -> np.ndarray:
    """:func:`patch_imu` for payloads of one size given as an (n, size) uint8 array.

    Returns a new (n, size) array; the input is not modified.
    """
    n, size = u8.shape
    accel = _as_rows(accel, n, 3, 'accel')
    gyro = _as_rows(gyro, n, 3, 'gyro')
    out = np.array(u8)
    for rows, _, sub, body in _sized_groups(np.full(n, size), lambda r, s: u8 if len(r) == n
                                            else u8[r], _IMU_FIELDS, 'Imu'):
        work = np.array(sub)
        rec = work.view(_layout(_IMU_FIELDS, body, size)).reshape(-1)
        rec['linear_acceleration'] = accel[rows]
        rec['angular_velocity'] = gyro[rows]
        out[rows] = work
    return out


def covariance9(cov, n: int, name: str = 'covariance') -> np.ndarray:
    """Expand a covariance spec to (n, 9) row-major 3x3 matrices.

    Accepts None (all zero: unknown), a scalar variance (isotropic diagonal), a (3,)
    diagonal, a (9,) or (3, 3) matrix, or per-message (n, 9) / (n, 3, 3) arrays.
    """
    if cov is None:
        return np.zeros((n, 9))
    arr = np.asarray(cov, dtype=np.float64)
    if arr.ndim == 0 or arr.shape == (3,):
        arr = np.diag(np.broadcast_to(arr, (3,))).reshape(9)
    if arr.shape == (3, 3):
        arr = arr.reshape(9)
    if arr.shape == (9,):
        return np.broadcast_to(arr, (n, 9)).copy()
    if arr.shape in ((n, 3, 3), (n, 9)):
        return arr.reshape(n, 9)
    raise ValueError(f'{name} has shape {arr.shape}; give a scalar variance, a (3,) diagonal, '
                     f'a (3, 3) / (9,) matrix, or one of those per message.')


def patch_imu_covariance(raws: Sequence[bytes], accel_cov=None, gyro_cov=None) -> list[bytes]:
    """Return copies of ``raws`` with the accel and/or gyro covariance replaced.

    A covariance left as None keeps the original bytes; see :func:`covariance9` for the
    accepted shapes.
    """
    n = len(raws)
    fields = {}
    if accel_cov is not None:
        fields['linear_acceleration_covariance'] = covariance9(accel_cov, n, 'accel_cov')
    if gyro_cov is not None:
        fields['angular_velocity_covariance'] = covariance9(gyro_cov, n, 'gyro_cov')
    if not fields:
        return list(raws)
    return _patch(raws, fields, 'Imu')


def _encode(stamp_ns: np.ndarray, frame_id: str, fields: dict[str, np.ndarray],
            layout: Sequence[tuple[str, int]]) -> list[bytes]:
    frame = frame_id.encode('utf-8') + b'\x00'
    body = _align8(12 + len(frame))
    size = _HDR + body + _payload_size(layout)
    n = len(stamp_ns)
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    sec, nanosec = np.divmod(stamp_ns, 1_000_000_000)
    if n and (sec.min() < -2**31 or sec.max() >= 2**31):
        raise ValueError('stamp_ns is outside the int32 seconds range of builtin_interfaces/Time;'
                         ' pass stamps in nanoseconds since the epoch.')
    u8 = np.zeros((n, size), np.uint8)
    u8[:, :_HDR] = np.frombuffer(CDR_LE_HEADER, np.uint8)
    u8[:, _HDR + 12:_HDR + 12 + len(frame)] = np.frombuffer(frame, np.uint8)
    rec = u8.view(_layout(layout, body, size)).reshape(-1)
    rec['sec'] = sec
    rec['nanosec'] = nanosec
    rec['frame_len'] = len(frame)
    for name, values in fields.items():
        rec[name] = values
    return _split(u8.tobytes(), size)


def encode_imu(cols: ImuColumns, orientation_covariance0: float = -1.0, accel_cov=None,
               gyro_cov=None) -> list[bytes]:
    """Serialize IMU columns as ``sensor_msgs/msg/Imu`` CDR messages (frame_id from cols).

    Orientation is all zeros with ``orientation_covariance[0] = orientation_covariance0``
    (-1 marks "no orientation estimate" per REP-145 / the Imu message comment); the
    accel/gyro covariances default to zero (unknown), see :func:`covariance9`.
    """
    n = len(cols)
    ocov = np.zeros((n, 9))
    ocov[:, 0] = orientation_covariance0
    return _encode(cols.stamp_ns, cols.frame_id, {
        'orientation_covariance': ocov,
        'angular_velocity': _as_rows(cols.gyro, n, 3, 'gyro'),
        'angular_velocity_covariance': covariance9(gyro_cov, n, 'gyro_cov'),
        'linear_acceleration': _as_rows(cols.accel, n, 3, 'accel'),
        'linear_acceleration_covariance': covariance9(accel_cov, n, 'accel_cov'),
    }, _IMU_FIELDS)


def decode_temperature(raws: Sequence[bytes]) -> TemperatureColumns:
    """Decode serialized ``sensor_msgs/msg/Temperature`` messages into columns.

    The value is degC for a temperature, or a proxy in its declared unit; any type of
    ``SCALAR_MSGTYPES`` has the same layout and decodes the same way.
    """
    return _temperature_columns(len(raws), _groups(raws, _TEMPERATURE_FIELDS, 'Temperature'))


def decode_temperature_packed(buf: np.ndarray, starts, lengths) -> TemperatureColumns:
    """Decode packed Temperature payloads (see :func:`decode_imu_packed`)."""
    return _temperature_columns(len(lengths), _packed_groups(
        buf, starts, lengths, _TEMPERATURE_FIELDS, 'Temperature'))


def _temperature_columns(n: int, groups) -> TemperatureColumns:
    stamp = np.empty(n, np.int64)
    temp = np.empty(n)
    frame = False
    for rows, rec, u8, _ in groups:
        stamp[rows] = _stamps(rec)
        temp[rows] = rec['temperature']
        frame = _merge_frame(frame, _frame_id(u8, rec['frame_len']))
    return TemperatureColumns(stamp, temp, frame or '')


def encode_temperature(cols: TemperatureColumns, variance=0.0) -> list[bytes]:
    """Serialize temperature columns as ``sensor_msgs/msg/Temperature`` CDR messages.

    ``variance`` is a scalar or one value per sample (0 means unknown). The bytes are also
    valid messages of every other type of ``SCALAR_MSGTYPES``.
    """
    n = len(cols)
    return _encode(cols.stamp_ns, cols.frame_id, {
        'temperature': np.asarray(cols.temperature, dtype=np.float64).reshape(n),
        'variance': np.broadcast_to(np.asarray(variance, dtype=np.float64), (n,)),
    }, _TEMPERATURE_FIELDS)


def header_stamps(raws: Sequence[bytes]) -> np.ndarray:
    """Return header stamps (int64 ns) of any messages starting with std_msgs/Header.

    Only the first 12 bytes are read, so this works for every stamped message type.
    """
    n = len(raws)
    if n == 0:
        return np.zeros(0, np.int64)
    head = np.frombuffer(b''.join([r[:_HDR + 8] for r in raws]), np.uint8)
    if head.size != n * (_HDR + 8):
        raise ValueError('a message is shorter than a std_msgs/Header; the topic does not carry '
                         'stamped messages.')
    head = head.reshape(n, _HDR + 8)
    if np.any(head[:, 1] != 1) or np.any(head[:, 0] != 0):
        raise ValueError('payload is not little-endian CDR (00 01); only little-endian CDR is '
                         'supported.')
    rec = head.view(np.dtype({'names': ['sec', 'nanosec'], 'formats': ['<i4', '<u4'],
                              'offsets': [_HDR, _HDR + 4], 'itemsize': _HDR + 8})).reshape(-1)
    return _stamps(rec)
