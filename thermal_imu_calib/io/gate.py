"""Input validation at the door of the offline pipelines: drop and count what no sensor gives.

The offline ``calibrate`` drops them here, before the stationary detector, and also keeps
what it needs to warn about inputs that would make a thermal fit unreliable (temperature
gaps, stamps that never move, IMU stamps that run backwards). ``calibrator_node`` drops
the same samples as they arrive, by the same rules (``imu_row_checks``,
``temperature_checks``), so live and offline collect the same holds.

Limits (SI): accelerometer beyond ``ACCEL_LIMIT`` m/s^2 (about 200 g, the largest MEMS
range) or gyro beyond ``GYRO_LIMIT`` rad/s (about 5700 deg/s) is no sensor's output; degC
inputs outside ``input_units.TEMPERATURE_BOUNDS`` are garbage or the wrong unit.
"""

from dataclasses import dataclass, field, replace
import datetime

import numpy as np

from .columns import TemperatureColumns
from .log_info import LogError
from ..input_units import is_temperature, TEMPERATURE_BOUNDS

#: largest specific force any accelerometer reports, m/s^2 (~200 g)
ACCEL_LIMIT = 2000.0
#: largest angular rate any gyro reports, rad/s (~5700 deg/s)
GYRO_LIMIT = 100.0


#: a gyro value between ``GYRO_LIMIT`` and this (rad/s) with the accelerometer in range is
#: a turn in deg/s (any MEMS range, up to 4000 deg/s); beyond it, a corrupt value
GYRO_DEG_RANGE = 5000.0
#: so many such samples mean the gyro is in deg/s, not a glitch
GYRO_UNIT_ROWS = 10
#: what to do about a gyro in deg/s (``gyro_unit_problem``)
GYRO_UNIT_FIX = ("publish the IMU in rad/s (for deg/s, multiply by pi/180 = 0.0174533; check "
                 "the driver's unit parameters)")


def gyro_unit_rows(accel, gyro):
    """Return the (n,) rows that read like a gyro in deg/s: |w| of a turn in deg/s taken as rad/s.

    Finite rows whose largest gyro axis lies in (``GYRO_LIMIT``, ``GYRO_DEG_RANGE``] rad/s
    (more than any gyroscope gives, as much as a hand turns in deg/s) while the
    accelerometer is within ``ACCEL_LIMIT``.
    """
    accel, gyro = np.asarray(accel, float), np.asarray(gyro, float)
    with np.errstate(invalid='ignore', over='ignore'):
        w = np.abs(gyro).max(axis=1)
        return (np.isfinite(accel).all(1) & np.isfinite(w) & (np.abs(accel) <= ACCEL_LIMIT).all(1)
                & (w > GYRO_LIMIT) & (w <= GYRO_DEG_RANGE))


def gyro_unit_problem(n):
    """Return None, or (what was seen, the rule it breaks, what to do) for ``n`` such rows.

    ``n``: ``gyro_unit_rows`` counted; fewer than ``GYRO_UNIT_ROWS`` is no problem.
    """
    if n < GYRO_UNIT_ROWS:
        return None
    return (f'{n} IMU samples read |w| above {GYRO_LIMIT:g} rad/s '
            f'({np.degrees(GYRO_LIMIT):.0f} deg/s, beyond any gyroscope) while the '
            'accelerometer was in range: the gyro values look in deg/s',
            'while sensor_msgs/Imu angular_velocity is in rad/s (REP 145)', GYRO_UNIT_FIX)


def unit_refusal(problem):
    """Return the one-line refusal of a (seen, rule, fix) unit problem of a recording."""
    seen, rule, fix = problem
    return f'{seen}, {rule}. {fix[:1].upper()}{fix[1:]}, then record or replay again'


@dataclass
class GateReport:
    """What ``InputGate`` dropped and saw, for the summary and the warnings (counts)."""

    imu_in: int = 0
    imu_nonfinite: int = 0
    imu_out_of_range: int = 0
    #: of those, rows that read like a gyro in deg/s (``gyro_unit_rows``)
    imu_gyro_unit: int = 0
    imu_zero: int = 0
    imu_stamp_not_increasing: int = 0
    imu_stamp_zero: int = 0
    #: IMU samples not collected: no reading of every thermal input within the max gap
    #: (``io.align.fresh_rows``); counted by the collection, not by the gate
    imu_no_temperature: int = 0
    #: first and last kept IMU header stamp, ns (None before any)
    imu_first_ns: int = None
    imu_last_ns: int = None
    temp_in: dict = field(default_factory=dict)
    temp_nonfinite: dict = field(default_factory=dict)
    temp_out_of_range: dict = field(default_factory=dict)
    temp_stamp_zero: dict = field(default_factory=dict)
    #: per topic: kept stamps (int64 ns) to judge the sampling interval afterwards
    temp_stamps: dict = field(default_factory=dict)
    #: how the inputs were chosen, e.g. the IMU's among several Temperature topics
    notes: list = field(default_factory=list)

    @property
    def imu_dropped(self):
        """Return the IMU samples dropped for any reason."""
        return (self.imu_nonfinite + self.imu_out_of_range + self.imu_zero
                + self.imu_stamp_not_increasing)

    def dropped_text(self, max_gap_s=5.0):
        """Return e.g. '3 non-finite IMU samples, 1 -300 degC reading dropped' ('' if none).

        ``max_gap_s``: the collection's ``--max-gap`` (s), named with the samples it left out.
        """
        parts = [f'{n} {what}' for n, what in (
            (self.imu_nonfinite, 'non-finite IMU samples'),
            (self.imu_out_of_range, f'IMU samples beyond any sensor\'s range (|a| > '
                                    f'{ACCEL_LIMIT:g} m/s^2 or |w| > {GYRO_LIMIT:g} rad/s)'),
            (self.imu_zero, 'IMU samples with an all-zero accelerometer vector'),
            (self.imu_stamp_not_increasing, 'IMU samples whose header stamp does not '
                                            'increase (duplicated or running backwards)'),
            (self.imu_no_temperature, f'IMU samples with no temperature reading within '
                                      f'{max_gap_s:g} s (--max-gap) of their stamp, '
                                      'not collected')) if n]
        for topic in self.temp_in:
            bad = self.temp_nonfinite.get(topic, 0)
            oor = self.temp_out_of_range.get(topic, 0)
            if bad:
                parts.append(f'{bad} non-finite readings of {topic}')
            if oor:
                parts.append(f'{oor} readings of {topic} outside {TEMPERATURE_BOUNDS[0]:g}..'
                             f'{TEMPERATURE_BOUNDS[1]:g} degC')
        return ', '.join(parts)


class InputGate:
    """Drop and count invalid samples of RawChunks (``io.bag.RawChunk``), in stream order.

    ``units`` maps temperature topic -> unit; degC topics are bounded, proxies and topics
    not named need only be finite. Raw buffers, if any, are filtered along.
    """

    def __init__(self, units=None, keep_stamps=20000):
        self.units = dict(units or {})
        self.report = GateReport()
        self._last_ns = None
        self._keep = keep_stamps

    def push(self, raw):
        """Return ``raw`` with invalid rows removed (a new RawChunk; counts in ``report``)."""
        r = self.report
        r.notes.extend(raw.notes)     # e.g. a thermal input put on the IMU's clock
        imu = raw.imu
        n = len(imu)
        r.imu_in += n
        ok = np.ones(n, bool)
        if n:
            finite, big, zero = imu_row_checks(imu.accel, imu.gyro)
            r.imu_nonfinite += int((~finite).sum())
            r.imu_out_of_range += int(big.sum())
            if big.any():
                r.imu_gyro_unit += int(gyro_unit_rows(imu.accel, imu.gyro).sum())
            r.imu_zero += int(zero.sum())
            ok = finite & ~big & ~zero
            r.imu_stamp_zero += int((imu.stamp_ns == 0).sum())
            # keep strictly increasing stamps only (duplicates and jumps back are dropped)
            st = imu.stamp_ns
            newest = [self._last_ns]
            inc = increasing_rows(np.where(ok, st, np.iinfo(np.int64).min), newest)
            r.imu_stamp_not_increasing += int((ok & ~inc).sum())
            ok &= inc
            if ok.any():
                self._last_ns = newest[0]
                r.imu_last_ns = self._last_ns
                if r.imu_first_ns is None:
                    r.imu_first_ns = int(st[ok].min())
        temps = {}
        for topic, tc in raw.temps.items():
            v = np.asarray(tc.temperature, float)
            fin, oor = temperature_checks(v, self.units.get(topic, ''))
            keep = fin & ~oor
            r.temp_in[topic] = r.temp_in.get(topic, 0) + len(v)
            r.temp_nonfinite[topic] = r.temp_nonfinite.get(topic, 0) + int((~fin).sum())
            r.temp_out_of_range[topic] = r.temp_out_of_range.get(topic, 0) + int(oor.sum())
            r.temp_stamp_zero[topic] = (r.temp_stamp_zero.get(topic, 0)
                                        + int((tc.stamp_ns == 0).sum()))
            kept = r.temp_stamps.setdefault(topic, [])
            if sum(map(len, kept)) < self._keep:
                kept.append(np.asarray(tc.stamp_ns[keep], np.int64))
            temps[topic] = (tc if keep.all() else
                            TemperatureColumns(tc.stamp_ns[keep], v[keep], tc.frame_id))
        if ok.all():
            return replace(raw, temps=temps)
        return replace(raw, imu=imu.slice(ok), imu_log_time_ns=raw.imu_log_time_ns[ok],
                       imu_raw=None if raw.imu_raw is None else
                       [b for b, k in zip(raw.imu_raw, ok.tolist()) if k],
                       temps=temps)


def imu_row_checks(accel, gyro):
    """Return (finite, out_of_range, zero) row masks (n,) of IMU samples (n, 3) in SI units.

    The rules every path drops a sample by (``InputGate`` for the offline commands, the
    nodes as samples arrive): a non-finite value; a finite value beyond ``ACCEL_LIMIT``
    m/s^2 or ``GYRO_LIMIT`` rad/s (no sensor's output); an all-zero accelerometer vector
    (a driver's placeholder). The masks do not overlap.
    """
    accel, gyro = np.asarray(accel, float), np.asarray(gyro, float)
    finite = np.isfinite(accel).all(1) & np.isfinite(gyro).all(1)
    with np.errstate(invalid='ignore', over='ignore'):
        big = ((np.abs(accel) > ACCEL_LIMIT).any(1) | (np.abs(gyro) > GYRO_LIMIT).any(1)) & finite
    zero = finite & ~big & (accel == 0).all(1)
    return finite, big, zero


def temperature_checks(values, unit):
    """Return (finite, out_of_range) masks of temperature-input readings in ``unit``.

    A degC input outside ``input_units.TEMPERATURE_BOUNDS`` is garbage or the wrong unit;
    proxies (any other unit) need only be finite. The masks do not overlap.
    """
    v = np.asarray(values, float)
    fin = np.isfinite(v)
    if not is_temperature(unit):
        return fin, np.zeros(v.shape, bool)
    with np.errstate(invalid='ignore'):
        return fin, fin & ((v < TEMPERATURE_BOUNDS[0]) | (v > TEMPERATURE_BOUNDS[1]))


#: header stamps stepping back by more than this (s) start a new timeline (a replay from
#: the start, a reset clock) in a live stream, instead of being dropped as a step back
JUMP_S = 10.0


class LiveImuFilter:
    """The IMU rules of ``InputGate`` for a live stream, where a replay may start over.

    ``push`` drops invalid rows (``imu_row_checks``) and valid rows whose stamp does not
    increase (``increasing_rows``), as ``calibrate`` drops them; a valid stamp more than
    ``jump_s`` behind the newest starts a new timeline, judged from there on. ``reset``
    forgets the newest stamp (detection restarted). Counts: ``invalid``, ``not_increasing``.
    """

    def __init__(self, jump_s=JUMP_S):
        self.jump_ns = int(jump_s * 1e9)
        self.invalid = 0
        self.not_increasing = 0
        #: invalid rows that read like a gyro in deg/s (``gyro_unit_rows``)
        self.gyro_unit = 0
        self.reset()

    def reset(self):
        """Forget the newest stamp: the next row starts a timeline."""
        self._newest = [None]

    def push(self, imu):
        """Return the kept rows of ImuColumns ``imu`` (the same object if all are kept)."""
        finite, big, zero = imu_row_checks(imu.accel, imu.gyro)
        valid = finite & ~big & ~zero
        if big.any():
            self.gyro_unit += int(gyro_unit_rows(imu.accel, imu.gyro).sum())
        low = np.iinfo(np.int64).min
        st = np.where(valid, imu.stamp_ns, low)
        inc = np.zeros(len(st), bool)
        i = 0
        while i < len(st):
            before = low if self._newest[0] is None else self._newest[0]
            run = np.maximum.accumulate(np.concatenate([[before], st[i:]]))[:-1]
            jump = valid[i:] & (run > st[i:] + self.jump_ns)      # no overflow at ``low``
            j = i + int(np.argmax(jump)) if jump.any() else len(st)
            inc[i:j] = increasing_rows(st[i:j], self._newest)
            if j < len(st):
                self._newest = [None]             # a new timeline starts at row j
            i = j
        keep = valid & inc
        self.invalid += int((~valid).sum())
        self.not_increasing += int((valid & ~inc).sum())
        return imu if keep.all() else imu.slice(keep)


def increasing_rows(stamps, newest):
    """Return the rows whose stamp is above every earlier one; ``newest`` = [ns or None].

    ``newest[0]`` (the newest stamp before these rows) is updated. The rows after a step
    back, until the stamps pass the newest before it, are the span ``calibrate`` drops
    (and refuses above 10 %).
    """
    stamps = np.asarray(stamps, np.int64)
    return stamps > _newest_before(stamps, newest)


def behind_newest(stamps, newest):
    """Return how far (ns) each stamp lies behind the newest before it; ``newest`` as above.

    -1 where the stamp increases, 0 where it repeats the newest. ``newest[0]`` is updated.
    ``compensate`` compensates a row up to ``JUMP_S`` behind (a repeated or jittered stamp,
    as ``compensator_node`` does) and passes a row further behind through (a new timeline,
    for which ``compensator_node`` has cleared its temperatures).
    """
    stamps = np.asarray(stamps, np.int64)
    prev = _newest_before(stamps, newest)
    # where the stamp increases prev - stamps may wrap (prev is int64 min before any): -1
    return np.where(stamps > prev, np.int64(-1), prev - stamps)


def _newest_before(stamps, newest):
    """Return the running newest stamp before each row (int64 minimum before any)."""
    if not len(stamps):
        return np.zeros(0, np.int64)
    low = np.iinfo(np.int64).min
    prev = np.maximum.accumulate(np.concatenate([[low if newest[0] is None else newest[0]],
                                                 stamps]))[:-1]
    newest[0] = int(max(prev[-1], stamps[-1]))
    return prev


def _utc(ns):
    """Return a header stamp (ns) as UTC text to the second."""
    if ns is None:
        return '?'
    return datetime.datetime.fromtimestamp(int(ns) // 10 ** 9, datetime.timezone.utc).strftime(
        '%Y-%m-%d %H:%M:%S')


def thermal_problems(report, max_gap_s):
    """Return reasons the thermal inputs cannot support a thermal fit (empty: fine).

    Each reason says what was found and what to do: temperature stamps that are all 0
    (or never change), and a median interval longer than ``max_gap_s`` (most IMU samples
    would see a held reading: the fit follows the sampling, not the temperature).
    """
    out = []
    imu_seconds = (0.0 if report.imu_first_ns is None
                   else (report.imu_last_ns - report.imu_first_ns) * 1e-9)
    for topic, parts in report.temp_stamps.items():
        st = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        n = report.temp_in.get(topic, 0)
        if len(st) == 0:
            out.append(f'{topic} has no usable reading ({n} read, '
                       f'{report.temp_nonfinite.get(topic, 0)} NaN/Inf, '
                       f'{report.temp_out_of_range.get(topic, 0)} outside '
                       f'{TEMPERATURE_BOUNDS[0]:g}..{TEMPERATURE_BOUNDS[1]:g} degC); check the '
                       'sensor and its driver, or leave the topic out (--temperature-topic)')
            continue
        if n and report.temp_stamp_zero.get(topic, 0) == n:
            out.append(f'every reading of {topic} has header stamp 0, so none can be matched '
                       'to the IMU samples in time and the thermal terms would be lost; fix the '
                       'driver to stamp its readings (header.stamp), then record again')
            continue
        if len(st) >= 2 and np.unique(st).size == 1:
            out.append(f'every reading of {topic} has the same header stamp; fix the driver to '
                       'stamp its readings, then record again')
            continue
        if len(st) == 1 and imu_seconds > max_gap_s:
            out.append(f'{topic} has a single reading in {imu_seconds:.0f} s of IMU data: a '
                       'thermal fit needs the temperature through the log; record it at >= 1 Hz')
            continue
        if len(st) >= 2 and imu_seconds > 0:
            dt = np.diff(np.sort(st)) * 1e-9
            med = float(np.median(dt))
            if med > max_gap_s:
                out.append(f'{topic} is sampled every {med:.3g} s (median), longer than '
                           f'--max-gap {max_gap_s:g} s: nearly every IMU sample would use a '
                           'held reading and the fit would follow the sampling, not the '
                           'temperature; record it at >= 1 Hz, or pass --max-gap '
                           f'{med * 1.5:.3g} to interpolate between readings')
    return out


def check_report(path, r, max_gap_s=5.0):
    """Refuse a log no calibration can come from, from its GateReport ``r``; return warnings.

    Refused (LogError, saying what to do): no IMU message, IMU stamps all 0 or mostly not
    increasing, every sample dropped, and thermal inputs that cannot support a thermal fit
    (``thermal_problems``). Warned: what the input gate dropped and counted.
    """
    if r is None:
        return []
    if r.imu_in == 0:
        raise LogError(f'{path}: the IMU topic has 0 messages, so there is nothing to '
                       f'calibrate; check --imu-topic (`thermal-imu-calib info {path}` lists '
                       'the topics and counts)')
    if r.imu_stamp_zero == r.imu_in:
        raise LogError(f'{path}: every IMU header stamp is 0, so holds cannot be timed; fix the '
                       'driver to stamp its messages (header.stamp), then record again')
    if r.imu_stamp_not_increasing > 0.1 * r.imu_in:
        raise LogError(f'{path}: {r.imu_stamp_not_increasing} of {r.imu_in} IMU header stamps '
                       'do not increase (duplicated or running backwards); the stamps are '
                       'broken: fix the driver\'s clock or re-record')
    gyro_unit = gyro_unit_problem(r.imu_gyro_unit)
    if gyro_unit:
        raise LogError(f'{path}: {unit_refusal(gyro_unit)}')
    if r.imu_dropped == r.imu_in:
        units = ('; values this large are raw counts or another unit: sensor_msgs/Imu is in '
                 'm/s^2 and rad/s (REP 145), so convert in the driver and record again'
                 if r.imu_out_of_range > r.imu_in // 2 else '')
        raise LogError(f'{path}: every IMU sample was dropped '
                       f'({r.dropped_text(max_gap_s)}); the log has no usable IMU data{units}')
    problems = thermal_problems(r, max_gap_s)
    if problems:
        raise LogError(f'{path}: the thermal inputs cannot support a thermal fit: '
                       + '; '.join(problems))
    kept = r.imu_in - r.imu_dropped
    if kept and r.imu_no_temperature >= kept:
        spans = []
        for topic, parts in r.temp_stamps.items():
            st = np.concatenate(parts) if parts else np.zeros(0, np.int64)
            if len(st):
                spans.append(f'{topic} {_utc(st.min())}..{_utc(st.max())}')
        raise LogError(f'{path}: no IMU sample has a temperature reading within {max_gap_s:g} s '
                       f'of its stamp (IMU stamps {_utc(r.imu_first_ns)}..'
                       f'{_utc(r.imu_last_ns)}; ' + ('; '.join(spans) or 'no readings')
                       + '): are they stamped by different clocks? Stamp both with one '
                       "clock, or pass --temperature-topic '' to calibrate without a "
                       'temperature')
    dropped = r.dropped_text(max_gap_s)
    return list(r.notes) + ([f'dropped and counted: {dropped}'] if dropped else [])
