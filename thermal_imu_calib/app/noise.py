"""Noise of a recorded log: the ``noise`` use case and the random walk ``calibrate`` adds.

``noise_from_log`` reads the IMU of a log (``read_imu``) and analyses its still parts
(``estimation.noise_model.analyse``): what ``thermal-imu-calib noise`` prints and writes.
``add_random_walk`` re-reads the long holds of calibration logs, compensated with the new
calibration, and stores the random walk K in its noise model (``app.calibrate`` calls it).
Units are SI (see ``estimation.allan``).
"""

import numpy as np

from ..collection.feed import DEFAULT_MAX_GAP_S
from ..estimation import allan
from ..estimation.noise_model import analyse, MIN_SEGMENT_S, sample_rate
from ..io.bag import open_log
from ..io.log_info import LogError
from ..io.topics import resolve_topics
from .collect import aligned_chunks


def read_imu(path, imu_topic=None, chunk_size=50000, relative=True):
    """Return (imu_topic, t [s], accel (n,3) m/s^2, gyro (n,3) rad/s) of a log, stamp-sorted.

    ``t`` starts at 0 with ``relative``, else it is the header stamp in seconds.
    """
    ts, acc, gyr = [], [], []
    with open_log(path) as reader:
        imu_topic, _ = resolve_topics(reader, imu_topic, [])
        for raw in reader.stream(imu_topic, [], chunk_size):
            ts.append(raw.imu.stamp_ns)
            acc.append(raw.imu.accel)
            gyr.append(raw.imu.gyro)
    if not ts or not sum(len(t) for t in ts):
        raise LogError(f'{path}: no messages on {imu_topic}')
    stamp = np.concatenate(ts)
    order = np.argsort(stamp, kind='stable')
    t0 = stamp[order][0] if relative else 0
    return (imu_topic, (stamp[order] - t0) * 1e-9, np.concatenate(acc)[order],
            np.concatenate(gyr)[order])


def noise_from_log(path, imu_topic=None, detector=None):
    """Read a log and return (imu_topic, result of ``analyse``)."""
    topic, t, accel, gyro = read_imu(path, imu_topic)
    return topic, analyse(t, accel, gyro, detector=detector)


def _compensated(path, imu_topic, cal, chunk_size=50000):
    """Return (t [s], accel, gyro) of a log compensated with ``cal`` (its thermal inputs)."""
    ts, acc, gyr = [], [], []
    stream = cal.stream()
    with open_log(path) as reader:
        imu_topic, temps = resolve_topics(reader, imu_topic, cal.temperature_topics or None)
        for ch in aligned_chunks(reader, imu_topic, temps, chunk_size, DEFAULT_MAX_GAP_S):
            ok = np.all(np.isfinite(ch.temps), axis=1) if ch.temps.size else np.ones(
                len(ch), bool)
            if not ok.any():
                continue
            t = ch.imu.t[ok]
            res = stream.apply(t, ch.imu.accel[ok], ch.imu.gyro[ok],
                               ch.temps[ok] if cal.inputs else None)
            ts.append(t)
            acc.append(res.accel)
            gyr.append(res.gyro)
    if not ts:
        raise LogError(f'{path}: no IMU samples with a temperature to compensate')
    return np.concatenate(ts), np.concatenate(acc), np.concatenate(gyr)


#: ``calibrate`` looks for the random walk K only when a hold is at least this long (s)
K_MIN_HOLD_S = 1200.0


def add_random_walk(cal, paths, windows, imu_topic=None):
    """Add K (and the horizon) to ``cal.noise_model`` from the holds of long logs.

    Only when the longest hold lasts ``K_MIN_HOLD_S``; the samples are compensated with
    ``cal`` first, so the thermal drift of a warm-up is not taken for a random walk; per
    sensor only when all three axes show the +1/2 slope. Returns a note for people, or ''
    when nothing was looked for.
    """
    if not len(windows):
        return ''
    _, start, end = windows.hold_spans()
    if np.max(end - start) < K_MIN_HOLD_S:
        return ''
    acc_segs, gyr_segs, rate = [], [], None
    for path in paths:
        t, acc, gyr = _compensated(path, imu_topic, cal)
        rate = rate or sample_rate(t)
        for a, b in zip(start, end):
            i0, i1 = np.searchsorted(t, a), np.searchsorted(t, b, 'right')
            if (i1 - i0) / rate >= MIN_SEGMENT_S:
                acc_segs.append(acc[i0:i1])
                gyr_segs.append(gyr[i0:i1])
    model = allan.noise_model(acc_segs, gyr_segs, rate)
    found = []
    for sensor, axes in model.items():
        if all(a.k_observable for a in axes):
            cal.noise_model[f'{sensor}_random_walk'] = np.array([a.K for a in axes])
            found.append(sensor)
    if not found:
        return ('noise: the holds are long but show no random-walk slope; no random walk '
                'stored (see `thermal-imu-calib noise`)')
    cal.noise_model['horizon_s'] = round(float(windows.t1.max() - windows.t0.min()), 1)
    return (f'noise: {" and ".join(found)} random walk K from the Allan deviation of the '
            'holds stored; the covariance adds K^2 horizon_s / 3')
