"""Evaluate calibrations on a recorded log: static errors raw and with each calibration.

The use case behind ``thermal-imu-calib evaluate``: pass 1 collects the stationary windows
(``app.collect.collect_windows``), pass 2 averages each compensated signal over exactly
those windows (``collection.metrics.WindowAccumulator``), so every label is judged on the
same data; the figures are ``collection.metrics.static_metrics`` (micro-g, rad/s).
"""

import os

import numpy as np

from ..calibration import Calibration
from ..collection.feed import DEFAULT_MAX_GAP_S
from ..collection.metrics import static_metrics, WindowAccumulator, with_signals
from ..io.bag import open_log
from ..io.gate import InputGate
from ..io.log_info import LogError
from ..io.topics import resolve_topics
from .collect import aligned_chunks, collect_windows


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
    # an input without a usable reading: its samples were not collected (no window has it)
    unusable = [t for t in col.temperature_topics if col.gate is not None
                and not sum(map(len, col.gate.temp_stamps.get(t, [])))]
    if unusable and any(cal.inputs for cal in calibrations.values()):
        raise LogError(f'{path}: {", ".join(unusable)} has no usable reading (NaN/Inf or '
                       'none), so no calibration can be applied; check the sensor and its '
                       'driver')
    tcol = _temperature_column(calibrations, col.temperature_topics)
    results = {'raw': static_metrics(w, gravity, average_s, tcol)}
    if len(w) and calibrations:
        acc = WindowAccumulator(w.t0, w.t1)
        streams = {label: cal.stream() for label, cal in calibrations.items()}
        with open_log(path) as reader:
            imu_topic, temps = resolve_topics(reader, imu_topic, col.temperature_topics)
            for ch in aligned_chunks(reader, imu_topic, temps, chunk_size, max_gap_s,
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


def evaluate_files(path, calibration_files, imu_topic=None, temperature_topics=None,
                   detector=None, gravity=9.80665, average_s=300.0, chunk_size=20000,
                   max_gap_s=DEFAULT_MAX_GAP_S, progress=None):
    """Evaluate the calibration files on a log: ``evaluate_log`` labelled by file name.

    A label is the file's name without extension (``'`` added to tell equal names apart).
    Refused (LogError) when the log has no stationary hold to judge on.
    """
    cals = {}
    for file in calibration_files:
        label = os.path.splitext(os.path.basename(file))[0]
        while label in cals:
            label += "'"
        cals[label] = Calibration.load(file)
    res = evaluate_log(path, cals, imu_topic, temperature_topics, detector, gravity, average_s,
                       chunk_size, max_gap_s, progress)
    if res['holds'] == 0:
        raise LogError(f'{path}: no stationary holds found, so there is nothing to '
                       'evaluate; evaluate needs a log with the IMU held still in several '
                       'poses, each for at least the minimum hold (derived from the log; '
                       f'`thermal-imu-calib info {path} --holds` shows it and what the '
                       'detector finds, --min-hold S overrides it)')
    return res
