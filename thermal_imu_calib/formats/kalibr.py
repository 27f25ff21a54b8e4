"""Kalibr ``imu.yaml``: the IMU noise model Kalibr's camera-IMU calibration reads.

Kalibr (``aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py``,
``ImuParameters``; wiki page "Supported sensors / IMU") reads ``rostopic``,
``update_rate`` [Hz] and four continuous-time noise figures::

    accelerometer_noise_density  m/s^2/sqrt(Hz)   (white noise)
    accelerometer_random_walk    m/s^3/sqrt(Hz)   (bias random walk)
    gyroscope_noise_density      rad/s/sqrt(Hz)
    gyroscope_random_walk        rad/s^2/sqrt(Hz)

Kalibr has no thermal model and reads no intrinsics from imu.yaml (with
``--imu-models scale-misalignment`` it estimates M, A and C_gyro_i itself), so the export
is the noise model only. The figures come from the calibration's ``noise`` section when it
has them (written by ``calibrate`` from the Allan analysis), else from ``--noise FILE``
(``thermal-imu-calib noise -o FILE``, itself a Kalibr imu.yaml); without either the export
is refused. Per-axis figures are reduced to the worst axis, as allan_variance_ros does.
"""

import numpy as np
import yaml

from ..calibration import Calibration
from .common import Exported, ExportRefused, num

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


def export(cal, raw_dict=None, noise_file_text=None, rostopic=None, update_rate=None,
           model='calibrated'):
    """Return ``Exported`` with the imu.yaml text."""
    if model != 'calibrated':
        raise ExportRefused('Kalibr reads no intrinsics from imu.yaml: with --imu-models '
                            'scale-misalignment it estimates M, A and C_gyro_i itself; '
                            'export imu_tk or json for the scale and misalignment instead')
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
    return Exported({'': '\n'.join(lines) + '\n'}, [f'noise figures from {where}'], {})


def read(text, source='Kalibr imu.yaml'):
    """Return a Calibration holding only the noise model of a Kalibr imu.yaml (no models)."""
    d = yaml.safe_load(text)
    figs = noise_from_dict(d)
    missing = [k for k in KEYS if k not in figs]
    if missing:
        raise ValueError(f'{source}: not a Kalibr imu.yaml, missing {", ".join(missing)}')
    imported = {'format': 'kalibr', 'source': source, **figs,
                'rostopic': d.get('rostopic'), 'update_rate': d.get('update_rate')}
    return Calibration(fit={'imported': imported},
                       notes=[f'imported noise model from Kalibr ({source})'])
