"""Compensate a recorded log: copy every message and add the compensated Imu messages.

The use case behind ``thermal-imu-calib compensate`` and ``fleet compensate``: the log is
streamed in column chunks (``io.bag.copy_and_stream``, aligned by ``io.align``), each IMU
row compensated with the calibration's stream (``calibration.Calibration.stream``) and
written by patching the original CDR payload (``io.cdr``), so everything but the two
vectors stays byte for byte.
Units: seconds (gaps, timeouts), SI in the messages.
"""

import os
import time

import numpy as np

from ..collection.feed import DEFAULT_MAX_GAP_S
from ..collection.outliers import ImuSpikeFilter
from ..input_units import is_temperature
from ..io import cdr
from ..io.align import StreamAligner
from ..io.bag import copy_and_stream, open_log
from ..io.bag_writer import LogWriter
from ..io.cdr import IMU_MSGTYPE
from ..io.gate import JUMP_S, behind_newest
from ..io.log_info import LogError
from ..io.output import staging_dir
from ..io.topics import in_log, resolve_topics
from .collect import progress_bar

#: what to do with IMU rows whose temperature is missing or stale
MISSING_POLICIES = ('hold_last', 'passthrough', 'drop')


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
            temperature_topics = [in_log(types, t) for t in temperature_topics]
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
                 'stamp_jumped_back': 0,
                 'compensated': 0, 'temp_min': np.full(len(temps), np.inf),
                 'temp_max': np.full(len(temps), -np.inf), 'notes': []}
        newest = [None]     # the newest IMU header stamp so far (ns)
        aligner = StreamAligner(temps, max_gap_s)
        stream = calibration.stream()  # carries the temperature filter state across chunks
        gate = ImuSpikeFilter() if despike else None

        def gated(chunks):
            for ch in chunks:
                yield gate.push(ch) if gate is not None else ch
        bar = progress_bar(reader.topics()[imu_topic].count, 'compensating', progress)
        t_start = time.perf_counter()
        payloads = _PayloadStore()
        with LogWriter(dst, storage=storage) as writer:
            writer.add_topic(output_topic, IMU_MSGTYPE)
            for raw in copy_and_stream(reader, writer, imu_topic, temps,
                                       chunk_size=chunk_size, keep_raw=True):
                stats['imu_in'] += len(raw.imu)
                stats['notes'] += raw.notes       # a thermal input put on the IMU's clock
                if bar is not None:
                    bar.update(len(raw.imu))
                # the payloads wait in the store; the aligner carries their row numbers
                extra = {'imu_log_time_ns': raw.imu_log_time_ns,
                         'imu_row': payloads.add(raw.imu_raw),
                         'behind_ns': behind_newest(raw.imu.stamp_ns, newest)}
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
    behind = ch.extra['behind_ns']
    stats['stamp_jumps'] += int((behind >= 0).sum())   # not increasing, as calibrate drops
    # a repeated or jittered stamp (up to JUMP_S behind) is compensated at its own stamp,
    # as compensator_node does; the span after a jump further back is another timeline,
    # for which compensator_node has cleared its temperatures: passed through
    jumped = behind > int(JUMP_S * 1e9)
    if jumped.any():
        stream.reset()        # compensator_node restarts its stream at such a jump too
    stats['stamp_jumped_back'] += int(jumped.sum())
    keep |= jumped
    comp &= ~jumped
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
