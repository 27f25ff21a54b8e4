"""Kalibr ``imu.yaml``: the IMU noise model Kalibr's camera-IMU calibration reads.

Kalibr (``aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py``,
``ImuParameters``; wiki page "Supported sensors / IMU") reads ``rostopic``,
``update_rate`` [Hz] and four continuous-time noise figures::

    accelerometer_noise_density  m/s^2/sqrt(Hz)   (white noise)
    accelerometer_random_walk    m/s^3/sqrt(Hz)   (bias random walk)
    gyroscope_noise_density      rad/s/sqrt(Hz)
    gyroscope_random_walk        rad/s^2/sqrt(Hz)

With ``--kalibr-model scale-misalignment`` the intrinsics are added in the layout and
convention of Kalibr's own results (``IccSensors.py``, ``IccScaledMisalignedImu``:
``model: scale-misalignment``, ``accelerometers: {M}``, ``gyroscopes: {M, A, C_gyro_i}``),
whose measurement model is::

    a_meas = M_a a_i + b_a                                  (M_a lower-triangular)
    w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g        (M_g lower-triangular)

with a_i, w_i in the IMU frame (x along the accelerometer's x axis). Kalibr estimates its
biases as splines and writes none; ours (at the export temperature) go under
``thermal_imu_calib: {accelerometer_bias, gyroscope_bias}``. Kalibr has no temperature:
the intrinsics are our model at T0 (or ``--temperature``) and the loss over the valid range
is reported. The figures come from the calibration's ``noise`` section when it
has them (written by ``calibrate`` from the Allan analysis), else from ``--noise FILE``
(``thermal-imu-calib noise -o FILE``, itself a Kalibr imu.yaml); without either the export
is refused. Per-axis figures are reduced to the worst axis, as allan_variance_ros does.
"""

import numpy as np
import yaml

from ..calibration import Calibration
from ..models.whole_unit import WholeUnitAccelModel, WholeUnitGyroModel
from .common import affine_map, Exported, ExportRefused, lq, num, rounded, summarize_loss
from .imu_tk import DIGITS, STATIC_T0

KEYS = ('accelerometer_noise_density', 'accelerometer_random_walk',
        'gyroscope_noise_density', 'gyroscope_random_walk')
UNITS = {'accelerometer_noise_density': 'm/s^2/sqrt(Hz)',
         'accelerometer_random_walk': 'm/s^3/sqrt(Hz)',
         'gyroscope_noise_density': 'rad/s/sqrt(Hz)',
         'gyroscope_random_walk': 'rad/s^2/sqrt(Hz)'}
#: other spellings of the same figures in a calibration's noise section
ALIASES = {'accelerometer_noise_density': ('accel_noise_density', ('accel', 'noise_density')),
           'accelerometer_random_walk': ('accel_random_walk', ('accel', 'random_walk')),
           'gyroscope_noise_density': ('gyro_noise_density', ('gyro', 'noise_density')),
           'gyroscope_random_walk': ('gyro_random_walk', ('gyro', 'random_walk'))}


def yaml_float(x):
    """Return a float as YAML 1.1 reads it (PyYAML needs a dot in 2.0e-05, not 2e-05)."""
    s = num(x, 10)
    mant, e, exp = s.partition('e')
    if '.' not in mant and mant not in ('inf', 'nan'):
        mant += '.0'
    return mant + e + exp


def _value(v):
    """Return the worst-axis float of a scalar, list or {'value': ...}; None if absent."""
    if isinstance(v, dict):
        v = v.get('value')
    if v is None:
        return None
    a = np.asarray(v, float).ravel()
    if a.size == 0 or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f'noise figure {v!r} is not finite and non-negative')
    return float(a.max())


def noise_from_dict(d):
    """Return {key: value} of the Kalibr figures found in a mapping (missing keys left out)."""
    out = {}
    if not isinstance(d, dict):
        return out
    for key in KEYS:
        flat, (sensor, name) = ALIASES[key]
        v = d.get(key, d.get(flat))
        if v is None and isinstance(d.get(sensor), dict):
            v = d[sensor].get(name)
            if v is None and isinstance(d[sensor].get('axes'), dict):
                v = [ax.get(name) for ax in d[sensor]['axes'].values()]
        val = _value(v)
        if val is not None:
            out[key] = val
    return out


def noise_of(cal, raw_dict=None, noise_file_text=None):
    """Return (figures, rostopic, update_rate, source) or refuse with what to do."""
    sources = []
    if noise_file_text is not None:
        nd = yaml.safe_load(noise_file_text) or {}
        sources.append(('--noise file', noise_from_dict(nd), nd))
    if raw_dict is not None:
        sec = raw_dict.get('noise') or {}
        sources.append(('the calibration\'s noise section', noise_from_dict(sec), sec))
    imported = (cal.fit or {}).get('imported') or {}
    if imported.get('format') == 'kalibr':
        sources.append(('the imported Kalibr file', noise_from_dict(imported), imported))
    for where, figs, d in sources:
        if all(k in figs for k in KEYS):
            return figs, d.get('rostopic'), d.get('update_rate'), where
    have = ', '.join(f'{w}: {sorted(f) or "none"}' for w, f, _ in sources) or 'no source'
    raise ExportRefused('Kalibr needs the four noise figures (' + ', '.join(KEYS) + f'); found '
                        f'{have}. Run `thermal-imu-calib noise LOG -o noise.yaml` on a still '
                        'recording and pass --noise noise.yaml')


def intrinsics(cal, temperature=None):
    """Return (Kalibr intrinsics dict, theirs(acc, gyr) -> (a_i, w_i)) of our models at T."""
    if cal.accel is None or cal.gyro is None:
        raise ExportRefused('the scale-misalignment intrinsics need an accelerometer and a '
                            'gyro model; this calibration lacks one')
    maps = {}
    for which in ('accel', 'gyro'):
        model = getattr(cal, which)
        t = np.full(3, temperature) if temperature is not None else model.t0
        maps[which] = affine_map(model, t, which)
    ma, ba, _, _ = maps['accel']
    mg, bg, cg, _ = maps['gyro']
    m_acc, q = lq(np.linalg.inv(ma))             # raw = L Q a_ours + B: Kalibr frame = Q ours
    n = np.linalg.inv(mg) @ q.T                  # raw = N w_i - mg^-1 C Q^T a_i + B
    m_gyr, c_gi = lq(n)
    a_g = -np.linalg.inv(mg) @ cg @ q.T @ c_gi.T
    d = {'M_a': rounded(m_acc, DIGITS), 'M_g': rounded(m_gyr, DIGITS),
         'A': rounded(a_g, DIGITS), 'C_gyro_i': rounded(c_gi, DIGITS),
         'b_a': rounded(ba, DIGITS), 'b_g': rounded(bg, DIGITS)}
    return d


def apply_intrinsics(d, acc, gyr):
    """Invert Kalibr's scale-misalignment measurement model: return (a_i, w_i)."""
    a_i = (np.asarray(acc) - d['b_a']) @ np.linalg.inv(d['M_a']).T
    rhs = np.asarray(gyr) - d['b_g'] - a_i @ (d['A'] @ d['C_gyro_i']).T
    w_i = rhs @ (d['C_gyro_i'].T @ np.linalg.inv(d['M_g'])).T
    return a_i, w_i


def export(cal, raw_dict=None, noise_file_text=None, rostopic=None, update_rate=None,
           model='calibrated', temperature=None, smp=None):
    """Return ``Exported`` with the imu.yaml text (noise model, optionally intrinsics)."""
    if model not in ('calibrated', 'scale-misalignment'):
        raise ExportRefused(f'Kalibr IMU model {model!r} is not calibrated or '
                            'scale-misalignment')
    figs, topic, rate, where = noise_of(cal, raw_dict, noise_file_text)
    topic = rostopic or topic
    rate = update_rate or rate
    if not topic:
        raise ExportRefused('Kalibr needs the IMU topic: pass --rostopic /imu/data_raw')
    if not rate or float(rate) <= 0:
        raise ExportRefused('Kalibr needs the IMU rate: pass --update-rate HZ')
    lines = ['# Kalibr IMU configuration (imu.yaml), written by thermal_imu_calib export',
             '#Accelerometers']
    for key in KEYS[:2]:
        lines.append(f'{key}: {yaml_float(figs[key])}  # [{UNITS[key]}]')
    lines.append('#Gyroscopes')
    for key in KEYS[2:]:
        lines.append(f'{key}: {yaml_float(figs[key])}  # [{UNITS[key]}]')
    lines.append(f'rostopic: {topic}')
    lines.append(f'update_rate: {yaml_float(rate)}  # [Hz]')
    notes, loss = [f'noise figures from {where}'], {}
    if model == 'scale-misalignment':
        d = intrinsics(cal, temperature)
        body = {'model': 'scale-misalignment',
                'accelerometers': {'M': d['M_a'].tolist()},
                'gyroscopes': {'M': d['M_g'].tolist(), 'A': d['A'].tolist(),
                               'C_gyro_i': d['C_gyro_i'].tolist()},
                'thermal_imu_calib': {'accelerometer_bias': d['b_a'].tolist(),
                                      'gyroscope_bias': d['b_g'].tolist(),
                                      'units': {'accelerometer_bias': 'm/s^2',
                                                'gyroscope_bias': 'rad/s',
                                                'A': 'rad/s/(m/s^2)'}}}
        lines.append('# scale-misalignment intrinsics at one temperature (Kalibr has none):')
        lines.append('# a_meas = M_a a_i + b_a;  w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g')
        lines += yaml.safe_dump(body, sort_keys=False, default_flow_style=None,
                                width=100).splitlines()
        if smp is not None:
            a_i, w_i = apply_intrinsics(d, smp.accel_raw, smp.gyro_raw)
            _, q = lq(np.linalg.inv(affine_map(cal.accel, cal.accel.t0 if temperature is None
                                               else np.full(3, temperature), 'accel')[0]))
            loss['accel'] = summarize_loss('accel', a_i - smp.accel_ours @ q.T,
                                           f'static vs ours on {smp.what}')
            loss['gyro'] = summarize_loss('gyro', w_i - smp.gyro_ours @ q.T,
                                          f'static vs ours on {smp.what}')
    return Exported({'': '\n'.join(lines) + '\n'}, notes, loss)


def read(text, source='Kalibr imu.yaml'):
    """Return a Calibration of a Kalibr imu.yaml: the noise model, plus the intrinsics if any.

    Scale-misalignment intrinsics become seed 002 whole-unit models without temperature
    terms in Kalibr's IMU frame (biases from the ``thermal_imu_calib`` keys, else zero).
    """
    d = yaml.safe_load(text)
    figs = noise_from_dict(d)
    missing = [k for k in KEYS if k not in figs]
    if missing:
        raise ValueError(f'{source}: not a Kalibr imu.yaml, missing {", ".join(missing)}')
    imported = {'format': 'kalibr', 'source': source, **figs,
                'rostopic': d.get('rostopic'), 'update_rate': d.get('update_rate')}
    accel = gyro = None
    if d.get('model') == 'scale-misalignment':
        extra = d.get('thermal_imu_calib') or {}
        m_a = np.asarray(d['accelerometers']['M'], float)
        g = d['gyroscopes']
        m_g, a_g, c = (np.asarray(g[k], float) for k in ('M', 'A', 'C_gyro_i'))
        b_a = np.asarray(extra.get('accelerometer_bias', [0.0] * 3), float)
        b_g = np.asarray(extra.get('gyroscope_bias', [0.0] * 3), float)
        om1 = c.T @ np.linalg.inv(m_g)
        accel = WholeUnitAccelModel(np.full(3, STATIC_T0), b_a.reshape(1, 3),
                                    m1=np.linalg.inv(m_a),
                                    convention='imported from Kalibr scale-misalignment')
        gyro = WholeUnitGyroModel(np.full(3, STATIC_T0), b_g.reshape(1, 3), m1=om1,
                                  coupling=-om1 @ a_g @ c,
                                  convention='imported from Kalibr scale-misalignment')
    return Calibration(accel=accel, gyro=gyro, fit={'imported': imported},
                       notes=[f'imported from Kalibr ({source})'])
