"""Noise model of a log: still segments -> Allan deviation per axis -> N, K, B; Kalibr file.

Glue between the log reader, the stationary detector and ``estimation.allan``. A long still
recording is one segment; a calibration log gives one segment per stationary hold (the
holds' Allan variances are averaged per tau). Units are SI (see ``estimation.allan``).
"""

import numpy as np
import yaml

from .estimation import allan
from .collection.stationary import DetectorConfig, StationaryDetector
from .io.bag import open_log
from .io.log_info import LogError
from .io.topics import resolve_topics

#: a still recording: the detector's holds cover this much of the log in one orientation
STILL_COVERAGE = 0.9
#: ... and their gravity directions agree within this angle (deg)
STILL_ANGLE_DEG = 2.0
#: segments shorter than this (s) are left out (their Allan deviation says nothing new)
MIN_SEGMENT_S = 5.0
#: a log is one still recording when every 1-s mean stays this close to the log's median:
#: accel (m/s^2, ~50 mg: ~3 deg of tilt, far from a pose change) and gyro (rad/s,
#: ~1.1 deg/s); this test needs no noise floor, so it also holds for coarsely quantised
#: outputs where the stationary detector's floor is 0
STILL_ACCEL_BAND = 0.5
STILL_GYRO_BAND = 0.02


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


def still_segments(t, accel, gyro, detector=None):
    """Return (segments [(i0, i1)], kind) of the still parts of (n,) stamps and (n,3) data.

    ``kind`` is 'still recording' when every 1-s mean stays in the still bands of the
    log's median, or the stationary holds cover most of the log in one orientation (the
    whole log is then one segment, so the longest taus are kept), else 'holds'. Segments
    are split at stamp gaps (> 3 sample periods).
    """
    if _is_still(t, accel, gyro):
        spans, kind = [(t[0], t[-1])], 'still recording'
        return _cut(t, spans), kind
    det = StationaryDetector(detector or DetectorConfig(), 0)
    win = det.update(t, accel, gyro, np.zeros((len(t), 0)))
    win = win.concat([win, det.finish()])
    span = t[-1] - t[0]
    if not len(win):
        return [], 'none'
    ids, means = win.hold_means()
    spans = [(win.t0[win.hold == h].min(), win.t1[win.hold == h].max()) for h in ids]
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(u @ u[0], -1, 1))).max()
    covered = sum(b - a for a, b in spans)
    if covered >= STILL_COVERAGE * span and angle <= STILL_ANGLE_DEG:
        spans, kind = [(t[0], t[-1])], 'still recording'
    else:
        kind = 'holds'
    return _cut(t, spans), kind


def _is_still(t, accel, gyro):
    """Return True when every 1-s block mean stays within the still bands of the median."""
    rate = sample_rate(t)
    m = max(int(round(rate)), 1)
    nb = len(t) // m
    if nb < 2:
        return False
    for x, band in ((accel, STILL_ACCEL_BAND), (gyro, STILL_GYRO_BAND)):
        means = x[:nb * m].reshape(nb, m, 3).mean(1)
        if np.abs(means - np.median(means, axis=0)).max() > band:
            return False
    return True


def _cut(t, spans):
    """Return (i0, i1) index ranges of the spans, split at stamp gaps, long enough."""
    dt = np.median(np.diff(t))
    gaps = np.flatnonzero(np.diff(t) > 3 * dt) + 1
    out = []
    for a, b in spans:
        i0, i1 = np.searchsorted(t, a), np.searchsorted(t, b, 'right')
        cuts = [i0] + [g for g in gaps if i0 < g < i1] + [i1]
        out.extend((c0, c1) for c0, c1 in zip(cuts[:-1], cuts[1:])
                   if (c1 - c0) * dt >= MIN_SEGMENT_S)
    return out


def sample_rate(t):
    """Return the sample rate (Hz) from the median stamp interval."""
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise LogError('IMU header stamps do not increase; cannot derive a sample rate')
    return 1.0 / dt


def analyse(t, accel, gyro, rate_hz=None, detector=None):
    """Return the noise result dict of still data (see ``format_noise``, ``kalibr_dict``)."""
    rate = rate_hz or sample_rate(t)
    segs, kind = still_segments(t, accel, gyro, detector)
    if not segs:
        raise LogError('no stationary segment of at least '
                       f'{MIN_SEGMENT_S:.0f} s found; record the IMU lying still')
    model = allan.noise_model([accel[a:b] for a, b in segs], [gyro[a:b] for a, b in segs],
                              rate)
    return {'rate_hz': rate, 'kind': kind, 'segments': len(segs),
            'still_seconds': float(sum(b - a for a, b in segs) / rate), 'axes': model}


def noise_from_log(path, imu_topic=None, detector=None):
    """Read a log and return (imu_topic, result of ``analyse``)."""
    topic, t, accel, gyro = read_imu(path, imu_topic)
    return topic, analyse(t, accel, gyro, detector=detector)


def _k_bound(ax):
    """Return K, or when it is not observable the largest K the curve allows (upper bound)."""
    if ax.k_observable:
        return ax.K, False
    c = ax.curve
    return float(np.min(c.adev * np.sqrt(3.0 / c.tau))), True


def per_axis(result):
    """Return the per-axis figures as plain dicts, with units."""
    out = {}
    for sensor, axes in result['axes'].items():
        u = allan.UNITS[sensor]
        rows = {}
        for name, ax in zip('xyz', axes):
            k, bound = _k_bound(ax)
            rows[name] = {'noise_density': ax.N, 'random_walk': k,
                          'random_walk_is_upper_bound': bound,
                          'bias_instability': ax.B, 'bias_instability_tau_s': ax.tau_B}
        out[sensor] = {'units': {'noise_density': u['N'], 'random_walk': u['K'],
                                 'bias_instability': u['B'], 'bias_instability_tau_s': 's'},
                       'axes': rows}
    return out


def kalibr_dict(result, topic):
    """Return a Kalibr ``imu.yaml`` dict: the six keys from the worst axis, extras after."""
    pa = per_axis(result)

    def worst(sensor, key):
        return float(max(r[key] for r in pa[sensor]['axes'].values()))
    d = {'accelerometer_noise_density': worst('accel', 'noise_density'),
         'accelerometer_random_walk': worst('accel', 'random_walk'),
         'gyroscope_noise_density': worst('gyro', 'noise_density'),
         'gyroscope_random_walk': worst('gyro', 'random_walk'),
         'rostopic': topic, 'update_rate': float(round(result['rate_hz'], 3))}
    d['thermal_imu_calib'] = {
        'method': 'overlapping Allan deviation (allantools.oadev), log-spaced tau; N at '
                  'tau=1 s on the fitted -1/2 line, K at tau=3 s on the fitted +1/2 line, '
                  'B = flat minimum / 0.664; Kalibr keys = worst axis',
        'source': result['kind'], 'still_segments': result['segments'],
        'still_seconds': round(result['still_seconds'], 1),
        'random_walk_upper_bound': any(r['random_walk_is_upper_bound']
                                       for s in pa.values() for r in s['axes'].values()),
        **pa}
    return d


def kalibr_yaml(result, topic):
    """Return the text of the Kalibr ``imu.yaml``."""
    head = ('# Kalibr IMU noise model (imu.yaml), written by thermal-imu-calib noise.\n'
            '# accelerometer: noise density m/s^2/sqrt(Hz), random walk m/s^3/sqrt(Hz);\n'
            '# gyroscope: noise density rad/s/sqrt(Hz), random walk rad/s^2/sqrt(Hz).\n')
    return head + yaml.safe_dump(_plain(kalibr_dict(result, topic)), sort_keys=False,
                                 width=100)


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x


def format_noise(result, topic):
    """Return the per-axis table for people."""
    pa = per_axis(result)
    out = [f'{topic}: {result["kind"]}, {result["segments"]} still segment(s), '
           f'{result["still_seconds"]:.0f} s at {result["rate_hz"]:.1f} Hz']
    for sensor, sec in pa.items():
        u = sec['units']
        out.append(f'{sensor}:  N [{u["noise_density"]}]  K [{u["random_walk"]}]  '
                   f'B [{u["bias_instability"]}] (tau)')
        for name, r in sec['axes'].items():
            k = (f'<{r["random_walk"]:.3g}' if r['random_walk_is_upper_bound']
                 else f'{r["random_walk"]:.3g}')
            out.append(f'  {name}: N {r["noise_density"]:.3g}  K {k}  '
                       f'B {r["bias_instability"]:.3g} ({r["bias_instability_tau_s"]:.3g} s)')
    if any(r['random_walk_is_upper_bound'] for s in pa.values() for r in s['axes'].values()):
        out.append('  <: the record is too short to see the +1/2 slope; K is an upper bound '
                   '(the steepest +1/2 line under the curve). Record >= 1-2 h still for K.')
    return '\n'.join(out)


def _compensated(path, imu_topic, cal, chunk_size=50000):
    """Return (t [s], accel, gyro) of a log compensated with ``cal`` (its thermal inputs)."""
    from .pipeline import _aligned, DEFAULT_MAX_GAP_S
    ts, acc, gyr = [], [], []
    stream = cal.stream()
    with open_log(path) as reader:
        imu_topic, temps = resolve_topics(reader, imu_topic, cal.temperature_topics or None)
        for ch in _aligned(reader, imu_topic, temps, chunk_size, DEFAULT_MAX_GAP_S):
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
    spans = [(windows.t0[windows.hold == h].min(), windows.t1[windows.hold == h].max())
             for h in windows.hold_ids]
    if max(b - a for a, b in spans) < K_MIN_HOLD_S:
        return ''
    acc_segs, gyr_segs, rate = [], [], None
    for path in paths:
        t, acc, gyr = _compensated(path, imu_topic, cal)
        rate = rate or sample_rate(t)
        for a, b in spans:
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
