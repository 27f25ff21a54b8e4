"""Fleet steps: what the Dask runner (``fleet.runner``) runs per log and per sensor.

Map (``collect_log``): read one log as ``calibrate`` reads it (``app.calibrate.collect``:
window statistics and pose changes, kilobytes; samples never travel), plus the sensor id
and the log's time span. The map applies the input gate ``calibrate`` applies
(``io.gate.check_report``: no usable IMU data, broken stamps, temperature inputs that
cannot support a thermal fit), so a log ``calibrate`` would refuse never enters its unit's
reduction; what the gate dropped and counted comes back as ``warnings``. A log that cannot
be read or is refused is a ``LogResult`` with ``error`` set, never an exception, so it
cannot stop the job.

Group (``period_key``): the logs of a sensor, split into ``period_days``-long periods.
Reduce (``reduce_unit``): the logs of one unit in time order, estimated by
``calibrate_unit`` (``app.calibrate.calibrate_collected``, the very estimation of
``calibrate``). ``compensate_unit_log``: one log of ``fleet compensate``, with its unit's
calibration valid at the log's start (``fleet.registry.valid_at``). Times in ns.
"""

from dataclasses import dataclass, field
import os
import time

from ..fleet import registry as reg
from ..io.bag import open_log
from ..io.gate import check_report
from ..io.log_info import LogError
from ..io.topics import resolve_topics
from .calibrate import calibrate_collected, CalibrateSettings, collect
from .compensate import compensate_log

NS_PER_DAY = 86400 * 10 ** 9


@dataclass
class LogResult:
    """What the map step returns for one log."""

    path: str
    sensor: str = ''
    start_ns: int = 0
    end_ns: int = 0
    imu_topic: str = ''
    collected: object = None       # pipeline.Collected, None on error
    error: str = ''
    seconds: float = 0.0
    warnings: list = field(default_factory=list)   # the input gate's 'dropped and counted'

    def header(self):
        """Return this result without the windows (what the client needs to group)."""
        return LogResult(self.path, self.sensor, self.start_ns, self.end_ns, self.imu_topic,
                         None, self.error, self.seconds, list(self.warnings))


@dataclass
class UnitResult:
    """What the reduce step returns for one sensor (and period)."""

    sensor: str
    logs: list
    start_ns: int
    end_ns: int
    result: object = None          # estimation.calibrate.CalibrationResult, None on error
    error: str = ''
    excluded: list = field(default_factory=list)   # (path, reason) of this unit's bad logs
    warnings: list = field(default_factory=list)   # (path, warning) of its good logs


#: longest reason shown on one FAILED line (a 10 kB frame_id must not make a 10 kB line)
MAX_REASON = 400


def reason(e, path=None):
    """Return the one-line reason of a failure (the path left out, at most MAX_REASON)."""
    msg = str(e).strip().replace('\n', ' ') or type(e).__name__
    if path is not None and msg.startswith(f'{path}: '):
        msg = msg[len(f'{path}: '):]      # the FAILED line names the path already
    if not (isinstance(e, (ValueError, OSError, LogError)) or 'Error' not in type(e).__name__):
        msg = f'{type(e).__name__}: {msg}'
    return msg if len(msg) <= MAX_REASON else msg[:MAX_REASON - 3] + '...'


def collect_log(path, group, settings=None, imu_topic=None, temperature_topics=None,
                chunk_size=20000):
    """Map task: read one log as ``calibrate`` does and gate it; a LogResult (``error`` set).

    ``settings``: the ``app.calibrate.CalibrateSettings`` of the job (detector, gap,
    ``input_units``; default: every temperature input in degC, bounded to -80..200 as
    ``calibrate`` does). The log is refused, as ``calibrate`` refuses it, when
    ``io.gate.check_report`` raises; its sensor is known by then, so the refusal is
    reported with its unit.
    """
    t = time.perf_counter()
    settings = settings or CalibrateSettings()
    res = LogResult(os.fspath(path))
    try:
        if group.kind in ('path', 'metadata'):   # known even when the log is unreadable
            res.sensor = group.sensor_id(path)
        with open_log(path) as reader:
            res.start_ns, res.end_ns = int(reader.start_ns or 0), int(reader.end_ns or 0)
            res.imu_topic, _ = resolve_topics(reader, imu_topic, temperature_topics)
        c = collect(settings, path, res.imu_topic, temperature_topics, chunk_size,
                    progress=False)
        res.sensor = res.sensor or group.sensor_id(path, c.frame_id, res.imu_topic)
        res.warnings = check_report(os.fspath(path), c.gate, settings.max_gap_s)
        if c.imu_messages == 0:
            raise ValueError('the log has no Imu messages')
        res.collected = c
    except Exception as e:   # noqa: B902 - a bad log is data: reported, never raised
        res.error = reason(e, os.fspath(path))
    res.seconds = time.perf_counter() - t
    return res


def header(res):
    """Small task: the LogResult without its windows."""
    return res.header()


def reduce_unit(sensor, reduce_fn, heads, *results):
    """Reduce task: merge the logs of one unit (in time order) and estimate."""
    good = [r for r in results if not r.error]
    out = UnitResult(sensor, [r.path for r in good], min(h.start_ns for h in heads),
                     max(h.end_ns for h in heads),
                     excluded=[(r.path, r.error) for r in results if r.error],
                     warnings=[(r.path, w) for r in good for w in r.warnings])
    if not good:
        out.error = 'no readable log'
        return out
    try:
        out.result = reduce_fn([r.collected for r in good], [r.path for r in good])
    except Exception as e:   # noqa: B902 - a refused unit is reported, the others go on
        out.error = reason(e)
    return out


def period_key(heads, period_days):
    """Return path -> (sensor, period index) for the logs of each sensor (0 days: one)."""
    first = {}
    for h in heads:
        first[h.sensor] = min(first.get(h.sensor, h.start_ns), h.start_ns)
    step = max(period_days, 0) * NS_PER_DAY
    return {h.path: (h.sensor, int((h.start_ns - first[h.sensor]) // step) if step else 0)
            for h in heads}


def calibrate_unit(settings, imu_topic, collected, paths):
    """Reduce function: the calibration of one unit from its logs' collections.

    ``app.calibrate.calibrate_collected`` with the job's settings: the calibration
    ``calibrate`` gives on the same logs. Returns the CalibrationResult.
    """
    return calibrate_collected(settings, collected, paths, imu_topic)


def registry_entry(unit):
    """Return the registry entry (sensor, calibration, end ns, start ns, logs) of a unit.

    The logs of the unit that could not be used are noted in its calibration.
    """
    cal = unit.result.calibration
    cal.notes.extend(f'fleet: log {p} was not used: {why}' for p, why in unit.excluded)
    return (unit.sensor, cal, unit.end_ns, unit.start_ns, unit.logs)


def compensate_unit_log(path, out_path, registry, group, kw):
    """Task: compensate one log with its unit's calibration; returns (path, text, ok)."""
    try:
        with open_log(path) as reader:
            start = int(reader.start_ns or 0)
            imu_topic, _ = resolve_topics(reader, kw['imu_topic'], [])
            first = next(reader.stream(imu_topic, [], 1), None)
        frame = first.imu.frame_id if first is not None else ''
        sensor = group.sensor_id(path, frame, imu_topic)
        cal_path = reg.valid_at(registry, sensor, start)
        cal = reg.Calibration.load(cal_path)
        st = compensate_log(path, out_path, cal, imu_topic, kw['temperature_topics'],
                            kw['output_topic'], 'mcap', kw['chunk_size'], kw['max_gap_s'],
                            None, kw['on_missing'], False, kw['despike'])
        return (path, f'{out_path}: {st["imu_out"]} compensated with '
                      f'{reg.display_id(sensor)} {os.path.relpath(cal_path, registry)}', True)
    except Exception as e:   # noqa: B902 - one bad log is reported, the others go on
        return (path, reason(e, path), False)
