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

A header-stamped input whose stamps cannot be matched to the IMU's (a driver that leaves
them 0, or stamps by another clock: device time against ROS time) is put on the IMU's clock
the same way (:class:`StampChoice`), decided once per input at its first readings after
the first IMU message; the nodes use :class:`LiveClocks` for both.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .cdr import SCALAR_MSGTYPES
from .columns import TemperatureColumns
from .packed import take_rows

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

    def forget(self, index: int) -> None:
        """Drop input ``index``'s readings still waiting for an IMU message."""
        self._wait[index] = []

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


#: a header stamp further than this (s) from the IMU message logged or published before it
#: is on another clock than the IMU's (the default ``--max-gap`` / ``temperature_timeout``:
#: within it, the reading would be matched by its stamp). One constant, not a setting, so
#: the offline readers and the nodes choose alike whatever their gap.
OTHER_CLOCK_S = 5.0


class StampChoice:
    """Keep a thermal input's header stamps, or put its readings on the IMU's clock.

    Decided once, from one reading: offline the first logged after the first IMU message,
    live the newest taken once an IMU message has come (``take_live``). Its header stamp
    is 0, or further than ``OTHER_CLOCK_S`` from the span of the IMU header stamps before
    it (the first IMU message's to the one logged before it offline; to the newest
    received live): then
    every reading takes the stamp of the IMU message before it, as a header-less input's
    (``on_imu_clock``, ``LiveImuClock``), and the readings before the first IMU message are
    left out; otherwise the header stamps are used, those readings included. Readings
    before the choice wait for it. The two paths choose alike wherever the stamps are on
    one clock (a reading within seconds of the IMU's) or clearly not (0, another epoch).
    ``on_imu_clock`` is None until then (True from the start for a header-less input).
    """

    def __init__(self, topic: str, headerless: bool = False):
        self.topic = topic
        self.headerless = bool(headerless)
        self.on_imu_clock: bool | None = True if headerless else None
        self.left_out = 0             # readings before the first IMU message (not used)
        self._note = ''
        self._held: list[TemperatureColumns] = []
        self._waiting: list = []       # live: readings before the choice
        self._first_imu: int | None = None   # offline: the first IMU header stamp, ns

    def decide(self, stamp_ns: int, first_ns: int, last_ns: int) -> bool:
        """Choose from a reading's header stamp and the IMU stamps' span (ns); return it."""
        stamp_ns, first_ns, last_ns = int(stamp_ns), int(first_ns), int(last_ns)
        lo, hi = min(first_ns, last_ns), max(first_ns, last_ns)
        off = (stamp_ns - hi if stamp_ns > hi else min(stamp_ns - lo, 0)) * 1e-9
        self.on_imu_clock = bool(stamp_ns == 0 or abs(off) > OTHER_CLOCK_S)
        if self.on_imu_clock:
            what = ('has header stamp 0' if stamp_ns == 0 else
                    f'is stamped {off:+.6g} s from the IMU messages before it')
            self._note = (f'{self.topic}: the first reading after the first IMU message {what} '
                          f'(more than {OTHER_CLOCK_S:g} s: not stamped by the IMU\'s clock), so '
                          'its readings take the header stamp of the IMU message before each, '
                          'as a header-less input\'s; stamp both with one clock to use its own '
                          'stamps')
        return self.on_imu_clock

    def take_live(self, items: list, imu_span: tuple[int, int] | None, stamp_of) -> list:
        """Live, before the choice: hold ``items``; return every held one once it is made.

        The choice is made once an IMU message has been received (``imu_span``: the first
        and the newest IMU header stamps received; None before any), at the newest held
        reading (``stamp_of(item)``: its header stamp, ns): offline judges the first one
        logged after the first IMU message, and the older held ones may come from before
        it (a temperature driver started 10 s before the IMU's is on its clock). []
        while it waits.
        """
        self._waiting += list(items)
        if self.on_imu_clock is None:
            if imu_span is None or not self._waiting:
                return []
            self.decide(stamp_of(self._waiting[-1]), *imu_span)
        out, self._waiting = self._waiting, []
        return out

    @property
    def waiting(self) -> int:
        """Return how many readings wait for the choice (live)."""
        return len(self._waiting)

    @property
    def holding(self) -> bool:
        """Return True while readings wait for the choice (offline)."""
        return bool(self._held)

    def pop_note(self) -> str:
        """Return the note of an input put on the IMU's clock, once ('' otherwise)."""
        note, self._note = self._note, ''
        return note

    def place(self, stamp_ns, values, imu_before, imu_stamp_ns,
              carry_ns: int | None, final: bool = False,
              frame_id: str = '') -> TemperatureColumns:
        """Return the readings of one span to use now (offline), on the chosen clock.

        ``stamp_ns`` and ``values`` are the span's readings (header stamps; any for a
        header-less input), the rest as for :func:`on_imu_clock`. Before the choice the
        readings wait (none is returned); at the ``final`` span of a log with no IMU
        message after them, they keep their header stamps (nothing to judge them by).
        ``frame_id``: the readings' frame, kept with their header stamps.
        """
        if self.on_imu_clock is False:
            return TemperatureColumns(np.asarray(stamp_ns, np.int64),
                                      np.asarray(values, np.float64), frame_id)
        before = np.asarray(imu_before, np.int64)
        if self.on_imu_clock is None:
            if self._first_imu is None and len(imu_stamp_ns):
                self._first_imu = int(imu_stamp_ns[0])
            after = np.flatnonzero((before > 0) | (carry_ns is not None))
            if not len(after):
                self._held.append(TemperatureColumns(np.asarray(stamp_ns, np.int64),
                                                     np.asarray(values, np.float64),
                                                     frame_id))
                if not final:
                    return TemperatureColumns.empty()
            held, self._held = self._held, []
            if final and not len(after):
                return TemperatureColumns(np.concatenate([h.stamp_ns for h in held]),
                                          np.concatenate([h.temperature for h in held]),
                                          frame_id or next((h.frame_id for h in held), ''))
            i = int(after[0])
            table = np.concatenate([[0 if carry_ns is None else carry_ns],
                                    np.asarray(imu_stamp_ns, np.int64)])
            if not self.decide(int(stamp_ns[i]), self._first_imu, int(table[before[i]])):
                return TemperatureColumns(
                    np.concatenate([h.stamp_ns for h in held] + [np.asarray(stamp_ns,
                                                                            np.int64)]),
                    np.concatenate([h.temperature for h in held] + [np.asarray(values,
                                                                               np.float64)]),
                    next((h.frame_id for h in held if h.frame_id), frame_id))
            self.left_out += sum(map(len, held))
        out = on_imu_clock(values, before, imu_stamp_ns, carry_ns)
        self.left_out += len(before) - len(out)
        return out


class LiveClocks:
    """Live, for one node: each thermal input's clock, chosen and applied as offline.

    Holds a :class:`StampChoice` per input (``bare[j]``: input ``j``'s readings go on the
    IMU's clock, from the start for a header-less type, or once its stamps are judged to
    be on another clock) and the :class:`LiveImuClock` that stamps them. The IMU messages'
    source timestamps are needed only while an input is, or may still be, on the IMU's
    clock (``on``); once every input keeps its header stamps the node stops collecting
    them.
    """

    def __init__(self, topics: Sequence[str], headerless: Sequence[bool]):
        self.choices = [StampChoice(t, h) for t, h in zip(topics, headerless)]
        self.bare = [bool(h) for h in headerless]
        self.clock = LiveImuClock(len(self.choices))
        self.span: tuple[int, int] | None = None    # first, newest IMU header stamp (ns)
        self.on = bool(self.choices)
        self.notes: list[str] = []     # the choices' notes (an input put on the IMU's clock)

    def add_imu(self, source_ns, stamp_ns) -> None:
        """Add IMU messages (source timestamps, header stamps; ns, in arrival order).

        Needed only while ``on``: afterwards nothing is kept.
        """
        if not len(stamp_ns) or not self.on:
            return
        newest = int(np.max(stamp_ns))
        self.span = ((int(stamp_ns[0]), newest) if self.span is None
                     else (self.span[0], max(self.span[1], newest)))
        self.clock.add_imu(source_ns, stamp_ns)

    def choose(self, index: int, items: list, stamp_of) -> tuple[list, str]:
        """Hold readings of an input whose clock is not chosen yet (``StampChoice.take_live``).

        Returns (the readings to go on now, by the chosen clock; the note to log once the
        input is put on the IMU's clock, else '').
        """
        choice = self.choices[index]
        out = choice.take_live(items, self.span, stamp_of)
        if choice.on_imu_clock is None:
            return out, ''
        self.bare[index] = bool(choice.on_imu_clock)
        self.on = any(c.on_imu_clock is not False for c in self.choices)
        note = choice.pop_note()
        self.notes += [note] if note else []
        return out, note

    def describe(self) -> dict[str, str]:
        """Return {topic: how its readings are stamped} (for /diagnostics)."""
        def what(c):
            if c.on_imu_clock is None:
                return 'not chosen yet (no reading after the first IMU message)'
            if not c.on_imu_clock:
                return 'header stamps'
            return ("IMU's clock (no header)" if c.headerless else
                    "IMU's clock (header stamps 0 or on another clock)")
        return {c.topic: what(c) for c in self.choices}

    def undecided(self, index: int) -> bool:
        """Return True while input ``index``'s clock is not chosen."""
        return self.choices[index].on_imu_clock is None

    def fresh(self) -> 'LiveClocks':
        """Return new clocks of the same inputs and types, every choice to be made again.

        For a node's ``~/reset``: a new collection judges its inputs' stamps afresh, as
        ``calibrate`` does each log (a driver whose header stamps were 0 and that has been
        fixed since is then matched by its stamps).
        """
        return LiveClocks([c.topic for c in self.choices], [c.headerless for c in self.choices])

    def retype(self, index: int, headerless: bool, topic: str | None = None) -> None:
        """Start input ``index`` anew as a header-less (or header-stamped) type.

        For a node that re-subscribes the input as the type its topic is published as
        (``nodes/thermal_types``), or to another ``topic`` (``nodes/topic_follower``): its
        choice starts again (decided at once for a
        header-less type), and readings of the old type still held are dropped. When no
        input needed the IMU's clock before, its IMU history starts again too (it was not
        kept meanwhile), so a reading published before the next IMU message is left out,
        as before the first.
        """
        was_on = self.on
        self.choices[index] = StampChoice(topic or self.choices[index].topic, headerless)
        self.bare[index] = bool(headerless)
        self.clock.forget(index)
        self.on = any(c.on_imu_clock is not False for c in self.choices)
        if self.on and not was_on:
            left_out = self.clock.left_out
            self.clock = LiveImuClock(len(self.choices), self.clock.history)
            self.clock.left_out = left_out
            self.span = None

    def stamp(self, index: int, readings) -> TemperatureColumns:
        """Return input ``index``'s readings that can be stamped now, (source ns, value) in."""
        for source, value in readings:
            self.clock.add_reading(index, source, value)
        return self.clock.take(index)


def clock_notes(info, imu_topic: str, temperature_topics: Sequence[str]) -> list[str]:
    """Return what ``info`` (a scanned ``LogInfo``) suggests :class:`StampChoice` will do.

    For ``info``: a header-stamped thermal topic whose stamps are all 0, or whose header
    stamp minus log time differs from the IMU's by more than ``OTHER_CLOCK_S`` at their
    first messages (another clock), is named. A preview from the first messages only; the
    choice itself is made while reading (a warning then says it).
    """
    imu = info.topics.get(imu_topic)
    if imu is None or imu.first_stamp_ns is None or imu.first_log_time_ns is None:
        return []
    imu_off = imu.first_stamp_ns - imu.first_log_time_ns
    out = []
    for topic in temperature_topics:
        t = info.topics.get(topic)
        if t is None or t.msgtype in HEADERLESS_MSGTYPES or t.first_stamp_ns is None:
            continue
        if t.stamps_constant and t.first_stamp_ns == 0:
            out.append(f'{topic}: every header stamp is 0, so calibrate puts its readings on '
                       'the IMU\'s clock (each takes the stamp of the IMU message logged '
                       'before it)')
            continue
        off = (t.first_stamp_ns - t.first_log_time_ns - imu_off) * 1e-9
        if abs(off) > OTHER_CLOCK_S:
            out.append(f'{topic}: its header stamps run {off:+.6g} s from the IMU\'s clock '
                       '(header stamp minus log time at the first messages), so calibrate '
                       'will likely put its readings on the IMU\'s clock (each takes the stamp '
                       'of the IMU message logged before it)')
    return out
