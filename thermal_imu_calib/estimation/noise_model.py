"""Noise model of still IMU data: still segments -> Allan deviation per axis -> N, K, B.

Pure functions over arrays (``app.noise`` reads the logs): ``still_segments`` finds the
still parts (a long still recording is one segment; a calibration log gives one per
stationary hold, whose Allan variances are averaged per tau), ``analyse`` fits the noise
figures (``estimation.allan``), ``kalibr_yaml`` / ``format_noise`` write them for Kalibr and
for people. Units are SI (see ``estimation.allan``).
"""

import numpy as np
import yaml

from ..collection.stationary import DetectorConfig, StationaryDetector
from ..io.log_info import LogError
from . import allan

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
    _, start, end = win.hold_spans()
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(u @ u[0], -1, 1))).max()
    covered = float(np.sum(end - start))
    if covered >= STILL_COVERAGE * span and angle <= STILL_ANGLE_DEG:
        spans, kind = [(t[0], t[-1])], 'still recording'
    else:
        spans, kind = list(zip(start, end)), 'holds'
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
