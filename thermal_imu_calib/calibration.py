"""The calibration object and its versioned, self-describing YAML file.

A file looks like::

    format: thermal_imu_calib/1
    software: {name: thermal_imu_calib, version: 0.1.0}
    created: '2026-11-22T01:00:00+00:00'
    sensor: {frame_id: imu_link}
    units: {accel: m/s^2, gyro: rad/s, temperature: degC, time: s}
    gravity: {value: 9.80665, unit: m/s^2, source: ...}
    temperature:
      inputs: [{name: t0, topic: imu/temperature, unit: degC}]
      valid_range: {min: [20.1], max: [41.7], unit: degC}
      out_of_range: clamp            # or extrapolate
      filter: {kind: lag, tau_s: [300.0], unit: s}   # optional (thermal_input)
    accel: {kind: field_polynomial, temperature_input: [0, 0, 0], parameters: {...}}
    gyro: {kind: offset_polynomial, temperature_input: [0, 0, 0], parameters: {...}}
    noise: {accel_std: [...], gyro_std: [...], unit: ...}
    fit: {...}
    notes: [...]

Thermal inputs need not be temperatures: each input carries its unit (``degC``, or a
thermal proxy's unit such as ``Hz`` for a gyro's resonance frequency, see
``input_units``), e.g. a die temperature for the accelerometer and a proxy for the gyro::

    temperature:
      inputs: [{name: die, topic: imu/temperature, unit: degC},
               {name: gyro_resonance, topic: imu/gyro_resonance, unit: Hz}]
      valid_range: {min: [21.0, 24950.2], max: [40.1, 24979.0], unit: [degC, Hz]}
    accel: {..., temperature_input: [0, 0, 0]}
    gyro: {..., temperature_input: [1, 1, 1], meta: {input_unit: Hz, ...}}

``valid_range.unit`` is one string when every input has that unit (as in files written
before proxies), else a list aligned with the inputs. A model's reference value and
coefficients are in the unit of the inputs its axes are mapped to (``T0`` in Hz, ``c1`` in
rad/s/Hz); files without units are degC.

``Calibration.apply`` is the one vectorised entry point the CLI and both nodes use.
"""

import datetime
import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import yaml

from . import __version__
from .gravity import STANDARD_GRAVITY
from .input_units import (check_values, DEGC, is_temperature, normalize_unit,
                          TEMPERATURE_BOUNDS)
from .models import model_from_dict, SensorModel
from .thermal_input import CalibrationStream, ThermalFilter

FORMAT = 'thermal_imu_calib/1'
OUT_OF_RANGE_POLICIES = ('clamp', 'extrapolate')
__all__ = ['Calibration', 'CalibrationError', 'Compensated', 'FORMAT', 'TemperatureInput',
           'TEMPERATURE_BOUNDS']


class CalibrationError(ValueError):
    """A calibration file or object that cannot be used; the message says why and what to do."""


@dataclass
class TemperatureInput:
    """One thermal input the models use (a topic in ROS, a column offline).

    ``unit`` is degC for a temperature, or a proxy's unit (e.g. Hz); Kelvin and Fahrenheit
    raise ValueError (convert to degC).
    """

    name: str
    topic: str = 'imu/temperature'
    unit: str = DEGC

    def __post_init__(self):
        self.unit = normalize_unit(self.unit, f'temperature input {self.name!r}')


@dataclass
class Compensated:
    """Result of ``Calibration.apply``: corrected columns plus per-row flags."""

    accel: np.ndarray
    gyro: np.ndarray
    #: (n,) bool, True where a temperature was outside the valid range (clamped or extrapolated)
    out_of_range: np.ndarray
    #: (n, 3) 1-sigma accel uncertainty in m/s^2 (model + white noise) or None
    accel_std: Optional[np.ndarray] = None
    #: (n, 3) 1-sigma gyro uncertainty in rad/s or None
    gyro_std: Optional[np.ndarray] = None


@dataclass
class Calibration:
    """A thermal calibration: models for accel and/or gyro, their inputs and validity."""

    accel: Optional[SensorModel] = None
    gyro: Optional[SensorModel] = None
    inputs: List[TemperatureInput] = field(default_factory=list)
    #: (k, 2) valid range per input, in each input's unit (degC, or a proxy's unit)
    valid_range: Optional[np.ndarray] = None
    out_of_range: str = 'clamp'
    accel_input: List[int] = field(default_factory=lambda: [0, 0, 0])
    gyro_input: List[int] = field(default_factory=lambda: [0, 0, 0])
    frame_id: str = ''
    gravity: float = STANDARD_GRAVITY
    gravity_source: str = 'standard gravity 9.80665 m/s^2'
    #: white-noise 1-sigma per sample, per axis: accel m/s^2, gyro rad/s
    accel_noise_std: Optional[np.ndarray] = None
    gyro_noise_std: Optional[np.ndarray] = None
    fit: dict = field(default_factory=dict)
    notes: List[str] = field(default_factory=list)
    created: str = ''
    software_version: str = __version__
    #: optional lag of the temperature inputs (thermal_input); None: the reading is the input
    temperature_filter: Optional[ThermalFilter] = None
    #: Allan noise model (``estimation.allan``): per axis ``{accel,gyro}_noise_density`` N
    #: (unit/sqrt(Hz)) and ``{accel,gyro}_random_walk`` K (unit/s/sqrt(Hz)), plus
    #: ``rate_hz`` and ``horizon_s``; see ``noise_std``
    noise_model: dict = field(default_factory=dict)

    def __post_init__(self):
        for which in ('accel', 'gyro'):
            model = getattr(self, which)
            if model is None or not self.inputs:
                continue
            unit = self.model_input_unit(which)
            if model.input_unit != unit:
                if model.input_unit != DEGC:
                    raise CalibrationError(
                        f'the {which} model is a function of an input in '
                        f'{model.input_unit} but its axes are mapped to inputs in {unit}; '
                        'map it to inputs of its unit')
                model.input_unit = unit   # fitted on these inputs: their unit is its unit

    @property
    def input_units(self):
        """Return the unit of each input, in input order."""
        return [i.unit for i in self.inputs]

    def model_input_unit(self, which):
        """Return the unit of the inputs the 'accel' or 'gyro' axes are mapped to.

        Raises CalibrationError when the three axes are mapped to inputs of different units.
        """
        idx = self.accel_input if which == 'accel' else self.gyro_input
        if not self.inputs:
            return DEGC
        units = sorted({self.inputs[i].unit for i in idx if 0 <= i < len(self.inputs)})
        if len(units) != 1:
            raise CalibrationError(f'the {which} axes are mapped to inputs of different units '
                                   f'({", ".join(units) or "none"}); map all three axes to '
                                   'inputs of one unit')
        return units[0]

    # ------------------------------------------------------------------ apply
    def axis_temperatures(self, temps, which):
        """Map (n, k) thermal inputs to (n, 3) per-axis inputs for 'accel'/'gyro'.

        Returns (per_axis, out_of_range_mask). With no inputs the model's reference
        temperature is used (temperature-independent calibration).
        """
        model = self.accel if which == 'accel' else self.gyro
        idx = self.accel_input if which == 'accel' else self.gyro_input
        temps = np.asarray(temps, float)
        n = temps.shape[0]
        if not self.inputs:
            t0 = getattr(model, 't0', np.zeros(3))
            return np.broadcast_to(t0, (n, 3)).copy(), np.zeros(n, bool)
        if temps.ndim != 2 or temps.shape[1] != len(self.inputs):
            raise CalibrationError(
                f'got {temps.shape[1] if temps.ndim == 2 else "?"} temperature columns, the '
                f'calibration expects {len(self.inputs)} '
                f'({", ".join(i.topic for i in self.inputs)})')
        lo, hi = self.valid_range[:, 0], self.valid_range[:, 1]
        oor = np.any((temps < lo) | (temps > hi), axis=1)
        if self.out_of_range == 'clamp':
            temps = np.clip(temps, lo, hi)
        return temps[:, idx], oor

    def apply(self, accel, gyro, temps=None):
        """Compensate (n, 3) accel [m/s^2] and gyro [rad/s] at (n, k) thermal inputs.

        Column j of ``temps`` is input j in its unit (degC, or a proxy's unit such as Hz).

        NaN temperatures are not allowed here; resolve missing temperature first (hold or
        passthrough). Returns a ``Compensated`` with the out-of-range mask. With a
        ``temperature_filter``, ``temps`` are the models' (lagged) inputs: stream data
        through ``stream().apply``; raw readings here mean thermal equilibrium.
        """
        accel = np.asarray(accel, float)
        gyro = np.asarray(gyro, float)
        n = accel.shape[0]
        if temps is None:
            temps = np.zeros((n, 0))
        temps = np.asarray(temps, float).reshape(n, -1)
        if temps.size and not np.all(np.isfinite(temps)):
            raise CalibrationError('temperature contains NaN/Inf; resolve missing samples first')
        oor = np.zeros(n, bool)
        a_out, g_out, a_std, g_std = accel, gyro, None, None
        if self.accel is not None:
            ta, o = self.axis_temperatures(temps, 'accel')
            oor |= o
            a_out = self.accel.correct(accel, ta)
            a_std = _combine_std(self.accel.predict_std(ta), self.noise_std('accel'), n)
        if self.gyro is not None:
            tg, o = self.axis_temperatures(temps, 'gyro')
            oor |= o
            g_out = self.gyro.correct(gyro, tg, aux={'accel': a_out})
            g_std = _combine_std(self.gyro.predict_std(tg), self.noise_std('gyro'), n)
        return Compensated(a_out, g_out, oor, a_std, g_std)

    def noise_std(self, which):
        """Return the (3,) per-sample noise std of 'accel'/'gyro' the covariance uses, or None.

        White part: ``noise.<which>_std``, else N sqrt(rate_hz). With a random walk K the
        bias wander over ``horizon_s`` (the span of the calibration data: what the thermal
        model could not follow) is added: sqrt(white^2 + K^2 horizon_s / 3), the Allan
        variance of a random walk at that tau.
        """
        white = self.accel_noise_std if which == 'accel' else self.gyro_noise_std
        nm = self.noise_model or {}
        dens = nm.get(f'{which}_noise_density')
        if white is None and dens is not None and nm.get('rate_hz'):
            white = np.asarray(dens, float) * np.sqrt(float(nm['rate_hz']))
        walk = nm.get(f'{which}_random_walk')
        if walk is None or not nm.get('horizon_s'):
            return white
        var = np.asarray(walk, float) ** 2 * float(nm['horizon_s']) / 3.0
        return np.sqrt(var + (0.0 if white is None else np.asarray(white, float) ** 2))

    def stream(self):
        """Return a ``CalibrationStream``: ``apply`` batch after batch with the filter state."""
        return CalibrationStream(self)

    # ------------------------------------------------------------------ file
    @property
    def temperature_topics(self):
        """Return the topics of the temperature inputs, in input order."""
        return [i.topic for i in self.inputs]

    def to_dict(self):
        """Return the file content as plain Python types."""
        units = self.input_units
        d = {
            'format': FORMAT,
            'software': {'name': 'thermal_imu_calib', 'version': self.software_version},
            'created': self.created or _now(),
            'sensor': {'frame_id': self.frame_id},
            'units': {'accel': 'm/s^2', 'gyro': 'rad/s', 'temperature': 'degC', 'time': 's',
                      **({} if all(map(is_temperature, units)) else
                         {'thermal_inputs': 'per input, see temperature.inputs[].unit'})},
            'gravity': {'value': float(self.gravity), 'unit': 'm/s^2',
                        'source': self.gravity_source},
            'temperature': {
                'inputs': [{'name': i.name, 'topic': i.topic, 'unit': i.unit}
                           for i in self.inputs],
                'valid_range': None if self.valid_range is None else {
                    'min': self.valid_range[:, 0].tolist(),
                    'max': self.valid_range[:, 1].tolist(),
                    'unit': units[0] if len(set(units)) == 1 else units},
                'out_of_range': self.out_of_range,
            },
        }
        if self.temperature_filter is not None:
            d['temperature']['filter'] = self.temperature_filter.to_dict()
        for name, model, idx in (('accel', self.accel, self.accel_input),
                                 ('gyro', self.gyro, self.gyro_input)):
            if model is not None:
                sec = model.to_dict()
                sec['temperature_input'] = [int(i) for i in idx]
                d[name] = sec
        noise = {}
        if self.accel_noise_std is not None:
            noise['accel_std'] = {'value': np.asarray(self.accel_noise_std).tolist(),
                                  'unit': 'm/s^2', 'description': 'white noise 1-sigma per sample'}
        if self.gyro_noise_std is not None:
            noise['gyro_std'] = {'value': np.asarray(self.gyro_noise_std).tolist(),
                                 'unit': 'rad/s', 'description': 'white noise 1-sigma per sample'}
        for key, value in (self.noise_model or {}).items():
            noise[key] = {'value': _plain(value), 'unit': NOISE_UNITS.get(key, '')}
        if noise:
            d['noise'] = noise
        d['fit'] = _plain(self.fit)
        d['notes'] = list(self.notes)
        return d

    def to_yaml(self):
        """Return the file text."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=100)

    def save(self, path):
        """Write atomically (temp file + rename); returns the path."""
        text = self.to_yaml()
        path = os.fspath(path)
        d = os.path.dirname(os.path.abspath(path))
        os.makedirs(d, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix='.calib-', suffix='.yaml', dir=d)
        try:
            with os.fdopen(fd, 'w') as f:
                f.write(text)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; a calibration is not secret
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return path

    @property
    def id(self):
        """Return a short content hash identifying this calibration (for diagnostics)."""
        d = self.to_dict()
        d.pop('created', None)
        return hashlib.sha1(yaml.safe_dump(d, sort_keys=True).encode()).hexdigest()[:10]

    @staticmethod
    def from_yaml(text, source='calibration'):
        """Parse and validate file text; raises CalibrationError with the reason."""
        try:
            d = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise CalibrationError(f'{source}: not valid YAML ({e.__class__.__name__}: '
                                   f'{str(e).splitlines()[0]})') from None
        return Calibration.from_dict(d, source)

    @staticmethod
    def load(path):
        """Load and validate a calibration file."""
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise CalibrationError(f'calibration file {path!r} does not exist; create one with '
                                   '`thermal-imu-calib calibrate ... -o FILE`')
        with open(path) as f:
            return Calibration.from_yaml(f.read(), path)

    @staticmethod
    def from_dict(d, source='calibration'):
        """Validate a parsed file and build the object."""
        if not isinstance(d, dict):
            raise CalibrationError(f'{source}: expected a YAML mapping at the top level')
        fmt = d.get('format')
        if fmt != FORMAT:
            raise CalibrationError(f'{source}: format {fmt!r} is not {FORMAT!r}; this is not a '
                                   'thermal_imu_calib file or it needs a newer version')
        try:
            temp = d.get('temperature') or {}
            inputs = [TemperatureInput(str(i['name']), str(i.get('topic', 'imu/temperature')),
                                       str(i.get('unit', DEGC)))
                      for i in temp.get('inputs') or []]
            vr = temp.get('valid_range')
            valid = None
            if inputs:
                if not vr:
                    raise ValueError('temperature.valid_range is required when there are inputs')
                valid = np.stack([np.asarray(vr['min'], float), np.asarray(vr['max'], float)], 1)
                if valid.shape != (len(inputs), 2):
                    raise ValueError(f'valid_range has {valid.shape[0]} entries for '
                                     f'{len(inputs)} inputs')
                _check_range_units(vr.get('unit'), inputs)
                for i, inp in enumerate(inputs):
                    check_values(valid[i], inp.unit,
                                 f'valid_range of input {inp.name!r} ({inp.topic})')
                if np.any(valid[:, 0] > valid[:, 1]):
                    raise ValueError('valid_range min is above max')
            oor = temp.get('out_of_range', 'clamp')
            if oor not in OUT_OF_RANGE_POLICIES:
                raise ValueError(f'out_of_range {oor!r} is not one of {OUT_OF_RANGE_POLICIES}')
            filt = None
            if temp.get('filter') is not None:
                if not inputs:
                    raise ValueError('temperature.filter needs temperature inputs')
                filt = ThermalFilter.from_dict(temp['filter'], len(inputs))
            models, idx = {}, {}
            for name in ('accel', 'gyro'):
                sec = d.get(name)
                if sec is None:
                    models[name], idx[name] = None, [0, 0, 0]
                    continue
                models[name] = model_from_dict(sec, name)
                idx[name] = [int(i) for i in sec.get('temperature_input', [0, 0, 0])]
                if len(idx[name]) != 3 or (inputs and any(
                        i < 0 or i >= len(inputs) for i in idx[name])):
                    raise ValueError(f'{name}.temperature_input {idx[name]} must name 3 of the '
                                     f'{len(inputs)} temperature inputs')
                if inputs:
                    units = {inputs[i].unit for i in idx[name]}
                    if len(units) > 1:
                        raise ValueError(f'{name}.temperature_input {idx[name]} maps the axes '
                                         f'to inputs of different units {sorted(units)}; map '
                                         'all three axes to inputs of one unit')
                    unit = units.pop()
                    if models[name].input_unit != unit:
                        raise ValueError(
                            f'{name} parameters are in {models[name].input_unit} (unit of its '
                            f'reference value) but temperature_input maps it to inputs in '
                            f'{unit}; the file was edited inconsistently: recalibrate or fix '
                            'the units')
                _check_bounds(name, models[name])
            if models['accel'] is None and models['gyro'] is None:
                raise ValueError('neither an accel nor a gyro model is present')
            g = d.get('gravity') or {}
            noise = d.get('noise') or {}
            cal = Calibration(
                accel=models['accel'], gyro=models['gyro'], inputs=inputs, valid_range=valid,
                out_of_range=oor, accel_input=idx['accel'], gyro_input=idx['gyro'],
                frame_id=str((d.get('sensor') or {}).get('frame_id', '')),
                gravity=float(g.get('value', STANDARD_GRAVITY)),
                gravity_source=str(g.get('source', '')),
                accel_noise_std=_opt_vec(noise.get('accel_std')),
                gyro_noise_std=_opt_vec(noise.get('gyro_std')),
                noise_model=_noise_model(noise),
                fit=d.get('fit') or {}, notes=list(d.get('notes') or []),
                created=str(d.get('created', '')),
                software_version=str((d.get('software') or {}).get('version', '')),
                temperature_filter=filt)
        except (KeyError, TypeError, ValueError) as e:
            msg = str(e) if not isinstance(e, KeyError) else f'missing key {e}'
            raise CalibrationError(f'{source}: {msg}') from None
        return cal


def _check_bounds(name, model):
    """Refuse parameters no real IMU has (a corrupt or mis-united file)."""
    p = {k: v.value for k, v in model.params().items()}
    if 'k0' in p:
        k = p['k0'] + p.get('dk0', 0)
        if np.any(np.abs(k - 1) > 0.5):
            raise ValueError(f'{name}: scale factor {k.tolist()} is not within 0.5..1.5; '
                             'the file is corrupt or not in SI units')
    lim = 50.0 if model.sensor == 'accel' else 5.0
    for key in ('b0', 'db0', 'c0'):
        if key in p and np.any(np.abs(p[key]) > lim):
            raise ValueError(f'{name}: {key} = {p[key].tolist()} exceeds {lim} {model.unit}; '
                             'the file is corrupt or not in SI units')
    unit = model.input_unit
    if is_temperature(unit) and 'T0' in p and np.any((p['T0'] < TEMPERATURE_BOUNDS[0])
                                                     | (p['T0'] > TEMPERATURE_BOUNDS[1])):
        raise ValueError(f'{name}: T0 = {p["T0"].tolist()} degC is implausible (outside '
                         f'{TEMPERATURE_BOUNDS[0]}..{TEMPERATURE_BOUNDS[1]} degC; Kelvin or '
                         'Fahrenheit by mistake?)')


def _check_range_units(unit, inputs):
    """Refuse a valid_range unit (string or per-input list) that contradicts the inputs'."""
    if unit is None:
        return
    units = [unit] * len(inputs) if isinstance(unit, str) else list(unit)
    if len(units) != len(inputs):
        raise ValueError(f'valid_range.unit has {len(units)} entries for {len(inputs)} inputs')
    for u, inp in zip(units, inputs):
        u = normalize_unit(u, f'valid_range of input {inp.name!r}')
        if u != inp.unit:
            raise ValueError(f'valid_range of input {inp.name!r} is in {u} but the input is in '
                             f'{inp.unit}; give the range in the input\'s unit')


#: units of the Allan noise-model entries of the ``noise`` section
NOISE_UNITS = {'accel_noise_density': 'm/s^2/sqrt(Hz)', 'gyro_noise_density': 'rad/s/sqrt(Hz)',
               'accel_random_walk': 'm/s^3/sqrt(Hz)', 'gyro_random_walk': 'rad/s^2/sqrt(Hz)',
               'rate_hz': 'Hz', 'horizon_s': 's'}


def _noise_model(noise):
    """Return the Allan noise-model entries of a ``noise`` section (validated)."""
    out = {}
    for key in NOISE_UNITS:
        if noise.get(key) is None:
            continue
        sec = noise[key]
        v = sec['value'] if isinstance(sec, dict) else sec
        if key in ('rate_hz', 'horizon_s'):
            v = float(v)
            if not v > 0:
                raise ValueError(f'noise.{key} must be > 0')
        else:
            v = _opt_vec(v)
        out[key] = v
    return out


def _opt_vec(sec):
    if sec is None:
        return None
    v = np.asarray(sec['value'] if isinstance(sec, dict) else sec, float).reshape(3)
    if np.any(v < 0) or not np.all(np.isfinite(v)):
        raise ValueError('noise std must be finite and non-negative')
    return v


def _combine_std(model_std, noise_std, n):
    if model_std is None and noise_std is None:
        return None
    var = np.zeros((n, 3))
    if model_std is not None:
        var = var + np.asarray(model_std) ** 2
    if noise_std is not None:
        var = var + np.asarray(noise_std) ** 2
    return np.sqrt(var)


def _now():
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()


def _plain(x):
    """Convert numpy scalars/arrays inside nested containers to plain Python for YAML."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x
