"""The report use case: the windows a calibration report draws, from logs or a saved file.

``report_windows`` collects the calibration logs as ``calibrate`` does (``app.collect``,
merged with distinct hold ids) or reads the windows ``calibrate --save-windows`` wrote;
``report.build`` draws the page from them. Times in s, temperatures in the inputs' units.
"""

import os

import numpy as np

from ..collection.collected import merge_windows
from ..collection.segments import Windows
from ..io.bag import open_log
from ..io.topics import resolve_topics
from .collect import collect_windows


def report_windows(cal, logs=(), windows_file=None, imu_topic=None):
    """Return (Windows or None, temperature series or None, source text) for a report.

    From the calibration ``logs`` (collected as ``calibrate`` does, merged), else from a
    ``windows_file`` written by ``calibrate --save-windows``, else nothing (the
    calibration file alone). ValueError when the windows file is missing or has other
    thermal inputs than ``cal``.
    """
    if logs:
        topics = cal.temperature_topics or None
        collected = [collect_windows(p, imu_topic, topics) for p in logs]
        return (merge_windows(collected), _series(logs[0], topics), ', '.join(logs))
    if windows_file:
        if not os.path.isfile(windows_file):
            raise ValueError(f'--windows {windows_file!r} does not exist; write it with '
                             'calibrate --save-windows FILE')
        with open(windows_file) as f:
            w = Windows.from_jsonl(f.read(), len(cal.inputs))
        if len(w) and w.n_inputs != len(cal.inputs):
            raise ValueError(f'{windows_file} has {w.n_inputs} thermal inputs, the '
                             f'calibration {len(cal.inputs)}; pass the windows of this '
                             'calibration')
        return w, None, windows_file
    return None, None, ''


def _series(path, topics):
    """Return [(t [s], value)] per temperature topic of the first log (None on failure)."""
    with open_log(path) as reader:
        imu, topics = resolve_topics(reader, None, topics)
        parts = {t: ([], []) for t in topics}
        for raw in reader.stream(imu, topics):
            for t, col in raw.temps.items():
                parts[t][0].append(col.stamp_ns)
                parts[t][1].append(col.temperature)
    return [(np.concatenate(parts[t][0]) * 1e-9 if parts[t][0] else np.zeros(0),
             np.concatenate(parts[t][1]) if parts[t][1] else np.zeros(0)) for t in topics]
