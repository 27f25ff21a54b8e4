"""What a log holds: topics, per-topic statistics, raw chunks, LogError.

Plain data shared by the reader (``bag``) and the writer
(``bag_writer``); stamps are int64 nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..input_units import TEMPERATURE_BOUNDS
from . import cdr
from .cdr import IMU_MSGTYPE, SCALAR_MSGTYPES, TEMPERATURE_MSGTYPE
from .columns import ImuColumns, TemperatureColumns
from .headerless import decode_values, HEADERLESS_MSGTYPES


_IDL_PREFIX = '=' * 80 + '\nIDL: '
_STORAGE_SUFFIXES = ('.mcap', '.db3')


class LogError(Exception):
    """A log cannot be read or written as asked; the message says why and what to do."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log.

    ``first_log_time_ns`` / ``last_log_time_ns`` are None until the log has been scanned
    (``LogReader.topics(scan=True)`` or ``LogReader.info()``), because the storage indexes
    only know them for the whole log.
    """

    name: str
    msgtype: str
    count: int
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None


@dataclass
class TopicStats:
    """Per-topic statistics gathered by :meth:`LogReader.info`.

    Stamp statistics are filled for Imu and Temperature topics only (header stamps);
    ``rate_hz`` is the median-interval rate, ``mean_rate_hz`` the count over the stamp
    span, ``max_gap_s`` the largest stamp step and ``stamps_backwards`` how many steps
    went back in time. A header-less thermal topic (std_msgs/Float32, Float64) has its
    value range and, as ``rate_hz``, the mean rate over its log times.
    """

    name: str
    msgtype: str
    count: int = 0
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None
    first_stamp_ns: int | None = None
    last_stamp_ns: int | None = None
    rate_hz: float | None = None
    mean_rate_hz: float | None = None
    max_gap_s: float | None = None
    stamps_backwards: int = 0
    frame_id: str | None = None
    temperature_min: float | None = None
    temperature_max: float | None = None
    #: every header stamp equal (0: never set): the rate is over log times, and the
    #: readings go on the IMU's clock when far from its stamps (``headerless.StampChoice``)
    stamps_constant: bool = False


@dataclass
class LogInfo:
    """Summary of a log for the ``info`` command."""

    path: str
    storage: str
    message_count: int
    start_ns: int | None
    end_ns: int | None
    topics: dict[str, TopicStats]
    #: the index's (metadata.yaml's) total when it differs from the messages read
    index_count: int | None = None

    @property
    def duration_s(self) -> float:
        """Log-time span in seconds (0 for an empty log)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * 1e-9

    def topics_of_type(self, msgtype: str) -> list[str]:
        """Return the names of topics carrying ``msgtype``."""
        return [name for name, t in self.topics.items() if t.msgtype == msgtype]

    def format(self) -> str:
        """Render a human-readable multi-line summary."""
        lines = [f'log:      {self.path} ({self.storage})',
                 f'messages: {self.message_count}   duration: {self.duration_s:.3f} s'
                 + (f'   (the index says {self.index_count}: it is out of date; the counts '
                    'here are the messages read)' if self.index_count is not None else '')]
        width = max([len(n) for n in self.topics] + [5])
        for name, t in sorted(self.topics.items()):
            line = f'  {name:<{width}}  {t.msgtype:<30} {t.count:>9}'
            if t.rate_hz:
                line += f'  {t.rate_hz:9.2f} Hz'
            if t.stamps_constant:
                line += (f'  header stamps all {t.first_stamp_ns} (rate over log times; '
                         'put on the IMU\'s clock when far from its stamps)')
            elif t.max_gap_s is not None:
                line += f'  max gap {t.max_gap_s:.3f} s'
            if t.stamps_backwards:
                line += f'  {t.stamps_backwards} stamps backwards'
            if t.temperature_min is not None:
                lo, hi = TEMPERATURE_BOUNDS
                plausible = lo <= t.temperature_min and t.temperature_max <= hi
                named = t.msgtype == TEMPERATURE_MSGTYPE or t.msgtype in HEADERLESS_MSGTYPES
                unit = (' degC' if named and plausible else
                        ' (not degC: a thermal proxy? declare its unit with --input-unit)'
                        if named else '')
                line += f'  {t.temperature_min:.2f}..{t.temperature_max:.2f}{unit}'
            lines.append(line)
        return '\n'.join(lines)


@dataclass
class RawChunk:
    """A span of the log: IMU columns plus the temperature samples that arrived meanwhile."""

    imu: ImuColumns
    imu_log_time_ns: np.ndarray
    temps: dict[str, TemperatureColumns]
    #: the Imu payloads when asked for: a list of bytes, or from the bulk MCAP reader an
    #: (n, size) uint8 array when every payload of the chunk has one size
    imu_raw: list[bytes] | np.ndarray | None = None
    #: what the reader decided on the way, for the summary (e.g. a thermal input put on the
    #: IMU's clock: ``headerless.StampChoice``)
    notes: list[str] = field(default_factory=list)

    def __len__(self):
        return len(self.imu)


class _StatsBuilder:
    """Accumulate TopicStats over a scan, decoding stamps in batches."""

    BATCH = 20000

    def __init__(self, name: str, msgtype: str):
        self.stats = TopicStats(name, msgtype)
        self.stamped = msgtype == IMU_MSGTYPE or msgtype in SCALAR_MSGTYPES
        self.values_only = msgtype in HEADERLESS_MSGTYPES     # a range, no stamps
        self.raws: list[bytes] = []
        self.medians: list[float] = []
        self.n_stamps = 0

    def add(self, t: int, raw: bytes) -> None:
        st = self.stats
        if st.first_log_time_ns is None:
            st.first_log_time_ns = t
        st.first_log_time_ns = min(st.first_log_time_ns, t)
        st.last_log_time_ns = t if st.last_log_time_ns is None else max(st.last_log_time_ns, t)
        st.count += 1
        if self.stamped or self.values_only:
            self.raws.append(raw)
            if len(self.raws) >= self.BATCH:
                self._flush()

    def _flush(self) -> None:
        if not self.raws:
            return
        st = self.stats
        try:
            if st.msgtype == IMU_MSGTYPE:
                cols = cdr.decode_imu(self.raws)
            else:
                cols = None if self.values_only else cdr.decode_temperature(self.raws)
                values = (decode_values(self.raws, st.msgtype) if cols is None
                          else cols.temperature)
                lo, hi = np.nanmin(values), np.nanmax(values)
                st.temperature_min = lo if st.temperature_min is None else min(
                    st.temperature_min, lo)
                st.temperature_max = hi if st.temperature_max is None else max(
                    st.temperature_max, hi)
        except ValueError as err:
            raise LogError(f'topic {st.name!r}: {err}') from err
        finally:
            self.raws = []
        if cols is None:
            return
        s = cols.stamp_ns
        frame = cols.frame_id
        st.frame_id = frame if st.frame_id is None or st.frame_id == frame else ''
        if st.last_stamp_ns is not None:
            s = np.concatenate([[st.last_stamp_ns], s])
        else:
            st.first_stamp_ns = int(s[0])
        d = np.diff(s)
        if d.size:
            st.stamps_backwards += int(np.count_nonzero(d < 0))
            gap = float(d.max()) * 1e-9
            st.max_gap_s = gap if st.max_gap_s is None else max(st.max_gap_s, gap)
            pos = d[d > 0]
            if pos.size:
                self.medians.append(float(np.median(pos)))
        st.last_stamp_ns = int(s[-1])
        self.n_stamps += len(cols)

    def finish(self) -> TopicStats:
        self._flush()
        st = self.stats
        if self.medians:
            st.rate_hz = 1e9 / float(np.median(self.medians))
        if self.n_stamps > 1 and st.last_stamp_ns != st.first_stamp_ns:
            st.mean_rate_hz = (self.n_stamps - 1) * 1e9 / (st.last_stamp_ns - st.first_stamp_ns)
        span = (st.last_log_time_ns or 0) - (st.first_log_time_ns or 0)
        st.stamps_constant = (st.msgtype != IMU_MSGTYPE and self.n_stamps > 1
                              and st.last_stamp_ns == st.first_stamp_ns and not self.medians)
        if (self.values_only or st.stamps_constant) and st.count > 1 and span > 0:
            st.rate_hz = (st.count - 1) * 1e9 / span
        if st.temperature_min is not None:
            st.temperature_min, st.temperature_max = (float(st.temperature_min),
                                                      float(st.temperature_max))
        return st
