"""Offline pipelines over recorded logs: collect windows, compensate, evaluate.

Thin glue between log I/O (io.bag, io.align, io.cdr) and the estimation core; the CLI
prints what these return. Everything streams in column chunks, so memory is bounded by
``chunk_size`` whatever the log length.
"""

from dataclasses import dataclass, field
import os
import sys
import time
from typing import Optional

import numpy as np

from .io import cdr
from .io.align import StreamAligner
from .io.bag import copy_and_stream, open_log
from .io.bag_writer import LogWriter
from .io.log_info import LogError
from .io.output import staging_dir
from .input_units import DEGC, is_temperature, parse_unit_map
from .io.cdr import IMU_MSGTYPE
from .io.columns import TemperatureColumns
from .io.gate import increasing_rows, InputGate
from .collection.outliers import ImuSpikeFilter
from .evaluate import static_metrics, WindowAccumulator, with_signals
from .collection.motion import MotionCollector, offset_holds
from .collection.segments import Windows
from .collection.stationary import StationaryDetector

from .io.topics import resolve_topics


#: temperature samples further apart than this are a gap: the nearest sample is held
DEFAULT_MAX_GAP_S = 5.0
MISSING_POLICIES = ('hold_last', 'passthrough', 'drop')


@dataclass
class Collected:
    """Stationary windows of one log (and the pose changes between them) plus what was read."""

    windows: Windows
    frame_id: str
    imu_messages: int
    seconds: float
    temperature_topics: list
    #: pose changes between consecutive holds (gyro_fit.Transition), with ``motion=True``
    transitions: list = field(default_factory=list)
    #: with ``motion=True``: pose changes dropped by reason and the collector's peak bytes
    motion: Optional[dict] = None
    #: the detector's derived settings (StationaryDetector.settings) and hold records
    detector: Optional[dict] = None
    holds: list = field(default_factory=list)
    #: what the input gate dropped and saw (io.gate.GateReport)
    gate: Optional[object] = None


def _progress(total, desc, enabled):
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit='msg', unit_scale=True, file=sys.stderr,
                leave=False)


def _aligned(reader, imu_topic, temp_topics, chunk_size, max_gap_s, keep_raw=False, bar=None,
             gate=None):
    aligner = StreamAligner(temp_topics, max_gap_s)
    for raw in reader.stream(imu_topic, temp_topics, chunk_size, keep_raw=keep_raw):
        if bar is not None:
            bar.update(len(raw.imu))
        yield from aligner.push(raw if gate is None else gate.push(raw))
    yield from aligner.finish()


def collect_windows(path, imu_topic=None, temperature_topics=None, detector=None,
                    chunk_size=20000, max_gap_s=DEFAULT_MAX_GAP_S, progress=None,
                    motion=False, input_units=None):
    """Run the stationary detector over a log; returns Collected.

    Samples no sensor gives (non-finite, beyond any range, degC inputs outside -80..200,
    IMU stamps that do not increase) are dropped and counted first (``io.gate``,
    ``Collected.gate``); ``input_units`` are ``TOPIC=UNIT`` items (unnamed inputs: degC;
    None: no input is bounded, only finite).

    With ``motion`` a ``gyro_fit.MotionCollector`` also keeps the raw samples of the pose
    changes between holds (``Collected.transitions``; what the ``whole_unit`` gyro rotation
    fit needs); memory stays bounded (see its ``memory_bytes``).
    """
    with open_log(path) as reader:
        imu_topic, temps = resolve_topics(reader, imu_topic, temperature_topics)
        try:
            units = ([''] * len(temps) if input_units is None
                     else parse_unit_map(input_units, temps))
        except ValueError:
            units = [DEGC] * len(temps)  # the caller reports a bad --input-unit itself
        gate = InputGate(dict(zip(temps, units)))
        total = reader.topic_types() and reader.topics()[imu_topic].count
        det = (MotionCollector(detector, len(temps)) if motion
               else StationaryDetector(detector, len(temps)))
        parts, n, frame, peak = [], 0, '', 0
        bar = _progress(total, 'reading', progress)
        t_start = time.perf_counter()
        for ch in _aligned(reader, imu_topic, temps, chunk_size, max_gap_s, bar=bar, gate=gate):
            n += len(ch)
            frame = frame or ch.imu.frame_id
            parts.append(det.update(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps))
            if motion:
                peak = max(peak, det.memory_bytes())
        parts.append(det.finish())
        if bar is not None:
            bar.close()
    sd = det.det if motion else det
    return Collected(Windows.concat(parts) if any(len(p) for p in parts)
                     else Windows.empty(len(temps)), frame, n,
                     time.perf_counter() - t_start, temps,
                     det.transitions if motion else [],
                     {'dropped': dict(det.dropped), 'peak_bytes': peak} if motion else None,
                     sd.settings(), list(sd.holds),
                     gate.report)


def windows_from_columns(imu_chunks, temperatures=(), detector=None,
                         max_gap_s=DEFAULT_MAX_GAP_S):
    """Run the stationary detector over in-memory columns (no log): e.g. a simulation.

    imu_chunks: iterable of ImuColumns in time order; temperatures: one TemperatureColumns
    per input (whole series). Returns the Windows table.
    """
    temperatures = list(temperatures)
    return feed_columns(StationaryDetector(detector, len(temperatures)), imu_chunks,
                        temperatures, max_gap_s)


def feed_columns(det, imu_chunks, temperatures=(), max_gap_s=DEFAULT_MAX_GAP_S):
    """Feed in-memory columns through the temperature aligner into ``det``; return Windows.

    ``det`` is anything with ``update(t, accel, gyro, temps)`` and ``finish()`` returning
    Windows: a StationaryDetector, or a MotionCollector (which keeps the pose changes too).
    """
    temperatures = list(temperatures)
    aligner = StreamAligner(len(temperatures), max_gap_s)
    pending = temperatures
    parts = []
    for ch in imu_chunks:
        for a in aligner.push_columns(ch, pending):
            parts.append(det.update(a.imu.t, a.imu.accel, a.imu.gyro, a.temps))
        pending = [TemperatureColumns.empty() for _ in temperatures]
    for a in aligner.finish():
        parts.append(det.update(a.imu.t, a.imu.accel, a.imu.gyro, a.temps))
    parts.append(det.finish())
    return Windows.concat(parts) if any(len(p) for p in parts) \
        else Windows.empty(len(temperatures))


def hold_offsets(collected):
    """Return what to add to the hold ids of each Collected so merged ids stay distinct."""
    out, offset = [], 0
    for c in collected:
        out.append(offset)
        if len(c.windows):
            offset += int(c.windows.hold.max()) + 1
    return out


def merge_windows(collected):
    """Concatenate windows of several logs, keeping hold ids distinct (``hold_offsets``)."""
    parts = []
    for c, offset in zip(collected, hold_offsets(collected)):
        w = c.windows
        if len(w):
            w = w.select(np.ones(len(w), bool))
            w.hold = w.hold + offset
        parts.append(w)
    return Windows.concat(parts)


def merge_transitions(collected):
    """Concatenate the pose changes of several logs with the hold ids of ``merge_windows``."""
    return [tr for c, offset in zip(collected, hold_offsets(collected))
            for tr in offset_holds(c.transitions, offset)]


def _resolve_missing(temps, ages, timeout_s, policy, last_good):
    """Apply the missing/stale-temperature policy; returns (temps, keep_mask, compensate_mask)."""
    n = temps.shape[0]
    if temps.shape[1] == 0:
        return temps, np.ones(n, bool), np.ones(n, bool)
    stale = np.any(~np.isfinite(temps) | (ages > timeout_s), axis=1)
    keep = np.ones(n, bool)
    comp = np.ones(n, bool)
    if policy == 'drop':
        keep = ~stale
        comp = ~stale
    elif policy == 'passthrough':
        comp = ~stale
    else:  # hold_last: the aligner already holds the nearest sample; NaN only before any
        nan = np.any(~np.isfinite(temps), axis=1)
        comp = ~nan
    temps = np.where(np.isfinite(temps), temps, 0.0)
    return temps, keep, comp


def compensate_log(src, dst, calibration, imu_topic=None, temperature_topics=None,
                   output_topic='/imu/data_compensated', storage='mcap', chunk_size=20000,
                   max_gap_s=DEFAULT_MAX_GAP_S, temperature_timeout=None,
                   on_missing='hold_last', progress=None, despike=False):
    """Copy every message of ``src`` to ``dst`` and add compensated Imu on ``output_topic``.

    Compensated messages keep the input's header (stamp, frame_id), orientation and
    covariances byte for byte; only linear_acceleration and angular_velocity change (and
    nothing else). With ``despike`` a median/MAD gate (estimation.outliers, seed 002 §3.2)
    replaces isolated spikes by the local median before compensation and counts them.
    Returns a stats dict (counts, msgs/s, out-of-range rows, spikes).

    The output is written under a temporary name next to ``dst`` and renamed at the end;
    on any error or interruption (SIGINT, or SIGTERM raised as KeyboardInterrupt by the CLI)
    the temporary is removed, so ``dst`` is either complete or absent.
    """
    if on_missing not in MISSING_POLICIES:
        raise ValueError(f'on_missing must be one of {MISSING_POLICIES}, not {on_missing!r}')
    dst = os.path.abspath(os.fspath(dst))
    if os.path.lexists(dst):
        raise LogError(f'{dst} exists; remove it or choose another output')
    with staging_dir(dst) as tmp:    # a unique temporary beside dst, renamed at the end
        return _compensate(src, tmp, calibration, imu_topic, temperature_topics, output_topic,
                           storage, chunk_size, max_gap_s, temperature_timeout, on_missing,
                           progress, despike)


def _compensate(src, dst, calibration, imu_topic, temperature_topics, output_topic, storage,
                chunk_size, max_gap_s, temperature_timeout, on_missing, progress, despike):
    """Do compensate_log's work into ``dst`` (a temporary name)."""
    timeout = max_gap_s if temperature_timeout is None else temperature_timeout
    with open_log(src) as reader:
        if temperature_topics is None and calibration.inputs:
            temperature_topics = calibration.temperature_topics
            types = reader.topic_types()
            absent = [t for t in temperature_topics if t not in types]
            if absent:
                raise LogError(f'the calibration expects temperature topics {absent} that '
                               f'{src} does not have; pass --temperature-topic (present: '
                               f'{", ".join(sorted(types))})')
        imu_topic, temps = resolve_topics(reader, imu_topic, temperature_topics or [])
        if len(temps) != len(calibration.inputs):
            raise LogError(f'the calibration has {len(calibration.inputs)} temperature inputs '
                           f'({", ".join(calibration.temperature_topics) or "none"}) but '
                           f'{len(temps)} topics were given')
        types = reader.topic_types()
        if output_topic in types:
            raise LogError(f'output topic {output_topic} already exists in {src}; choose '
                           'another --output-topic')
        stats = {'imu_in': 0, 'imu_out': 0, 'dropped': 0, 'passthrough': 0,
                 'out_of_range': 0, 'copied': reader.message_count, 'stamp_jumps': 0,
                 'compensated': 0, 'temp_min': np.full(len(temps), np.inf),
                 'temp_max': np.full(len(temps), -np.inf)}
        newest = [None]     # the newest IMU header stamp so far (ns)
        aligner = StreamAligner(temps, max_gap_s)
        stream = calibration.stream()  # carries the temperature filter state across chunks
        gate = ImuSpikeFilter() if despike else None

        def gated(chunks):
            for ch in chunks:
                yield gate.push(ch) if gate is not None else ch
        bar = _progress(reader.topics()[imu_topic].count, 'compensating', progress)
        t_start = time.perf_counter()
        payloads = _PayloadStore()
        with LogWriter(dst, storage=storage) as writer:
            writer.add_topic(output_topic, IMU_MSGTYPE)
            for raw in copy_and_stream(reader, writer, imu_topic, temps,
                                       chunk_size=chunk_size, keep_raw=True):
                stats['imu_in'] += len(raw.imu)
                if bar is not None:
                    bar.update(len(raw.imu))
                # the payloads wait in the store; the aligner carries their row numbers
                extra = {'imu_log_time_ns': raw.imu_log_time_ns,
                         'imu_row': payloads.add(raw.imu_raw),
                         'stamp_ok': increasing_rows(raw.imu.stamp_ns, newest)}
                for ch in gated(aligner.push_columns(raw.imu, [raw.temps[t] for t in temps],
                                                     extra)):
                    _write_compensated(writer, output_topic, ch, stream, timeout,
                                       on_missing, stats, payloads)
            tail = list(gated(aligner.finish()))
            if gate is not None:
                tail.append(gate.flush())
            for ch in tail:
                _write_compensated(writer, output_topic, ch, stream, timeout, on_missing,
                                   stats, payloads)
        if bar is not None:
            bar.close()
    _refuse_unusable(src, stats, calibration, temps)
    stats['seconds'] = time.perf_counter() - t_start
    stats['spikes'] = gate.counts()['rejected_total'] if despike else 0
    stats['msgs_per_s'] = stats['copied'] / max(stats['seconds'], 1e-9)
    stats['imu_topic'] = imu_topic
    stats['temperature_topics'] = temps
    return stats


class _PayloadStore:
    """Imu payloads read but not yet written, addressed by a running row number.

    Blocks are what the reader gave: an (n, size) uint8 array or a list of bytes.  Rows
    are taken in increasing order, so blocks wholly before a request are dropped.
    """

    def __init__(self):
        self._blocks = []
        self._next = 0

    def add(self, rows) -> np.ndarray:
        """Keep ``rows``; return their row numbers."""
        first = self._next
        self._next += len(rows)
        if len(rows):
            self._blocks.append((first, rows))
        return np.arange(first, self._next, dtype=np.int64)

    def take(self, idx):
        """Return the payloads of row numbers ``idx`` (increasing): array or list."""
        idx = np.asarray(idx, dtype=np.int64)
        if not len(idx):
            return []
        while self._blocks and self._blocks[0][0] + len(self._blocks[0][1]) <= idx[0]:
            self._blocks.pop(0)
        parts = []
        for first, rows in self._blocks:
            if first > idx[-1]:
                break
            sel = idx[(idx >= first) & (idx < first + len(rows))] - first
            if len(sel):
                parts.append(rows[sel] if isinstance(rows, np.ndarray)
                             else [rows[i] for i in sel.tolist()])
        if all(isinstance(p, np.ndarray) for p in parts) and len(
                {p.shape[1] for p in parts}) == 1:
            return parts[0] if len(parts) == 1 else np.concatenate(parts)
        return [bytes(x) for p in parts for x in p]


def _refuse_unusable(src, stats, calibration, topics):
    """Refuse a compensation whose stamps or temperatures say the result would be wrong.

    Like ``calibrate`` (``io.gate.check_report``): IMU header stamps not increasing in more
    than 10 % of the messages. And a log whose temperature readings all lie outside the
    calibrated range (every sample clamped or extrapolated), with a hint at the unit.
    """
    n = stats['imu_in']
    if n and stats['stamp_jumps'] > 0.1 * n:
        raise LogError(f'{src}: {stats["stamp_jumps"]} of {n} IMU header stamps do not increase '
                       '(duplicated or running backwards); the temperature at those samples '
                       'would be taken from another time: fix the driver\'s clock or '
                       're-record (calibrate refuses this log too)')
    if not (stats['compensated'] and stats['out_of_range'] == stats['compensated']):
        return
    vr = calibration.valid_range
    for j, inp in enumerate(calibration.inputs):
        lo, hi = stats['temp_min'][j], stats['temp_max'][j]
        if not (np.isfinite(lo) and (hi < vr[j, 0] or lo > vr[j, 1])):
            continue
        hint = ''
        if is_temperature(inp.unit):
            for name, f in (('Kelvin', lambda v: v - 273.15),
                            ('degF', lambda v: (v - 32.0) / 1.8)):
                if f(hi) >= vr[j, 0] - 20 and f(lo) <= vr[j, 1] + 20:
                    hint = (f'; the values look like {name} ({f(lo):.1f}..{f(hi):.1f} degC '
                            'converted): publish degC')
                    break
        hint = hint or ('; check the unit the topic publishes, or calibrate over this '
                        'temperature range')
        raise LogError(f'{src}: every reading of {topics[j]} ({lo:.2f}..{hi:.2f}) lies outside '
                       f'the calibrated range {vr[j, 0]:.2f}..{vr[j, 1]:.2f} {inp.unit}, so '
                       'every sample would be clamped' + hint)


def _write_compensated(writer, topic, ch, stream, timeout, policy, stats, payloads):
    n = len(ch)
    if n == 0:
        return
    temps, keep, comp = _resolve_missing(ch.temps, ch.temp_age, timeout, policy, None)
    ok = ch.extra['stamp_ok']
    stats['stamp_jumps'] += int((~ok).sum())
    keep |= ~ok               # the span after a jump back passes through uncompensated
    comp &= ok
    if np.any(comp) and temps.shape[1]:
        stats['temp_min'] = np.minimum(stats['temp_min'], temps[comp].min(0))
        stats['temp_max'] = np.maximum(stats['temp_max'], temps[comp].max(0))
    raws = payloads.take(ch.extra['imu_row'])
    accel = ch.imu.accel.copy()
    gyro = ch.imu.gyro.copy()
    if np.any(comp):
        res = stream.apply(ch.imu.t[comp], ch.imu.accel[comp], ch.imu.gyro[comp], temps[comp])
        accel[comp] = res.accel
        gyro[comp] = res.gyro
        stats['out_of_range'] += int(np.sum(res.out_of_range))
        stats['compensated'] += int(np.sum(comp))
    finite = np.all(np.isfinite(accel), axis=1) & np.all(np.isfinite(gyro), axis=1)
    keep &= finite
    stats['passthrough'] += int(np.sum(keep & ~comp))
    stats['dropped'] += int(np.sum(~keep))
    times = ch.extra['imu_log_time_ns']
    idx = np.flatnonzero(keep)
    if isinstance(raws, np.ndarray):
        writer.write_many(topic, times[idx], cdr.patch_imu_rows(raws, accel, gyro)[idx])
    else:
        patched = cdr.patch_imu(raws, accel, gyro)
        writer.write_many(topic, times[idx], [patched[i] for i in idx])
    stats['imu_out'] += len(idx)


def evaluate_log(path, calibrations, imu_topic=None, temperature_topics=None, detector=None,
                 gravity=9.80665, average_s=300.0, chunk_size=20000,
                 max_gap_s=DEFAULT_MAX_GAP_S, progress=None):
    """Compute static metrics of a log, raw and with each calibration (label -> Calibration).

    Pass 1 finds stationary windows on the raw data; pass 2 averages each compensated
    signal over exactly those windows, so every label is judged on the same data.
    """
    if temperature_topics is None:
        for cal in calibrations.values():
            if cal.inputs:
                temperature_topics = cal.temperature_topics
                break
    col = collect_windows(path, imu_topic, temperature_topics, detector, chunk_size,
                          max_gap_s, progress)
    w = col.windows
    if len(w) and any(cal.inputs for cal in calibrations.values()):
        empty = [t for t, bad in zip(col.temperature_topics, np.isnan(w.temp).all(axis=0))
                 if bad]
        if empty:
            raise LogError(f'{path}: {", ".join(empty)} has no usable reading (NaN/Inf or '
                           'none), so no calibration can be applied; check the sensor and its '
                           'driver')
    tcol = _temperature_column(calibrations, col.temperature_topics)
    results = {'raw': static_metrics(w, gravity, average_s, tcol)}
    if len(w) and calibrations:
        acc = WindowAccumulator(w.t0, w.t1)
        streams = {label: cal.stream() for label, cal in calibrations.items()}
        with open_log(path) as reader:
            imu_topic, temps = resolve_topics(reader, imu_topic, col.temperature_topics)
            for ch in _aligned(reader, imu_topic, temps, chunk_size, max_gap_s,
                               gate=InputGate()):
                sig = {}
                for label, cal in calibrations.items():
                    t = np.where(np.isfinite(ch.temps), ch.temps, np.nan)
                    if t.shape[1] and np.any(~np.isfinite(t)):
                        # per input: the columns may be in different units (degC, Hz)
                        t = np.where(np.isfinite(t), t, np.nanmean(w.temp, axis=0))
                    sel = _select_inputs(cal, temps, t)
                    res = streams[label].apply(ch.imu.t, ch.imu.accel, ch.imu.gyro, sel)
                    sig[f'{label}/a'] = res.accel
                    sig[f'{label}/g'] = res.gyro
                acc.add(ch.imu.t, sig)
        for label in calibrations:
            cw = with_signals(w, acc.means(f'{label}/a'), acc.means(f'{label}/g'))
            results[label] = static_metrics(cw, gravity, average_s, tcol)
    return {'path': str(path), 'windows': len(w), 'holds': len(np.unique(w.hold)),
            'temperature_topics': col.temperature_topics, 'results': results,
            'detector': col.detector, 'hold_list': col.holds}


def _temperature_column(calibrations, topics):
    """Return the first topic column the calibrations declare degC (0 if none says).

    None when every input they name is a non-degC proxy (no drift per degC then).
    """
    units = {i.topic.lstrip('/'): i.unit for cal in calibrations.values() for i in cal.inputs}
    cols = [j for j, t in enumerate(topics) if units.get(t.lstrip('/'), 'degC') == 'degC']
    return cols[0] if cols else None


def _select_inputs(cal, topics, temps):
    """Reorder/select temperature columns to the calibration's inputs (by topic name)."""
    if not cal.inputs:
        return np.zeros((temps.shape[0], 0))
    norm = [t.lstrip('/') for t in topics]
    idx = []
    for inp in cal.inputs:
        name = inp.topic.lstrip('/')
        if name not in norm:
            raise LogError(f'calibration input topic {inp.topic} is not among the temperature '
                           f'topics read ({", ".join(topics) or "none"})')
        idx.append(norm.index(name))
    return temps[:, idx]
