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

Cohesive: the calibration object and its versioned file format: one schema, read,
validated, applied and written in one place.
"""

import datetime
import hashlib
import os
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

    def apply(self, accel, gyro, temps=None, history=None):
        """Compensate (n, 3) accel [m/s^2] and gyro [rad/s] at (n, k) thermal inputs.

        Column j of ``temps`` is input j in its unit (degC, or a proxy's unit such as Hz).

        NaN temperatures are not allowed here; resolve missing temperature first (hold or
        passthrough). Returns a ``Compensated`` with the out-of-range mask. With a
        ``temperature_filter``, ``temps`` are the models' (lagged) inputs: stream data
        through ``stream().apply``; raw readings here mean thermal equilibrium.
        ``history``: ``{key: (n, k)}`` lagged readings for history-dependent models
        (``thermal_input.HistoryStream``, filled by ``stream().apply``); None: equilibrium.
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
            ha = self._axis_history(history, self.accel, 'accel')
            a_out = self.accel.correct(accel, ta, aux=ha)
            a_std = _combine_std(_model_std(self.accel, ta, ha), self.noise_std('accel'), n)
        if self.gyro is not None:
            tg, o = self.axis_temperatures(temps, 'gyro')
            oor |= o
            hg = self._axis_history(history, self.gyro, 'gyro')
            g_out = self.gyro.correct(gyro, tg, aux={'accel': a_out, **(hg or {})})
            g_std = _combine_std(_model_std(self.gyro, tg, hg), self.noise_std('gyro'), n)
        return Compensated(a_out, g_out, oor, a_std, g_std)

    def _axis_history(self, history, model, which):
        """Return ``{'history': {key: (n, 3)}}`` for a history-dependent model, else None.

        The lagged readings are mapped to axes and clamped like the readings themselves.
        """
        keys = getattr(model, 'history_keys', ())
        if not keys or not history or not self.inputs:
            return None
        out = {k: self.axis_temperatures(history[k], which)[0] for k in keys if k in history}
        if '_age_s' in history:
            out['_age_s'] = history['_age_s']
        return {'history': out}

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
        d = self._core_dict()
        d['fit'] = _plain(self.fit)
        d['notes'] = list(self.notes)
        return d

    def _core_dict(self):
        """Return the file content without the free-form ``fit`` and ``notes``."""
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
        return d

    def to_yaml(self):
        """Return the file text."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=100)

    def save(self, path):
        """Write atomically (``io.output.write_atomic``: temporary + rename); return path."""
        from .io.output import write_atomic
        return write_atomic(os.fspath(path), self.to_yaml())

    @property
    def id(self):
        """Return a short content hash identifying this calibration (for diagnostics).

        It covers what compensates (models, inputs, ranges, gravity, noise), not the
        free-form ``fit`` and ``notes``: those never enter the hot path.
        """
        d = self._core_dict()
        d.pop('created', None)
        return hashlib.sha1(yaml.safe_dump(d, sort_keys=True).encode()).hexdigest()[:10]

    @staticmethod
    def from_yaml(text, source='calibration'):
        """Parse and validate file text (str or UTF-8 bytes); raises CalibrationError.

        Size, nesting depth and alias expansion are limited (``MAX_FILE_BYTES``,
        ``MAX_DEPTH``, ``MAX_NODES``) before anything walks the document.
        """
        text = decode_text(text, source)
        check_yaml_shape(text, source)
        try:
            d = yaml.load(text, Loader=_SAFE_LOADER)
        except yaml.YAMLError as e:
            raise CalibrationError(f'{source}: not valid YAML ({e.__class__.__name__}: '
                                   f'{str(e).splitlines()[0]})') from None
        except Exception as e:  # noqa: B902 - e.g. an unhashable key: still a bad file
            raise CalibrationError(f'{source}: not a usable YAML document '
                                   f'({e.__class__.__name__}: {e})') from None
        return Calibration.from_dict(d, source)

    @staticmethod
    def load(path):
        """Load and validate a calibration file."""
        path = os.fspath(path)
        if os.path.isdir(path):
            raise CalibrationError(f'calibration file {path!r} is a directory; pass the '
                                   'calibration YAML file')
        if not os.path.isfile(path):
            raise CalibrationError(f'calibration file {path!r} does not exist; create one with '
                                   '`thermal-imu-calib calibrate ... -o FILE`')
        try:
            size = os.path.getsize(path)
            if size > MAX_FILE_BYTES:
                raise CalibrationError(f'{path}: {size} bytes is too large for a calibration '
                                       f'file (limit {MAX_FILE_BYTES}); is it the right file?')
            with open(path, 'rb') as f:
                data = f.read(MAX_FILE_BYTES + 1)
        except OSError as e:
            raise CalibrationError(f'cannot read calibration file {path!r}: '
                                   f'{e.strerror or e}') from None
        return Calibration.from_yaml(data, path)

    @staticmethod
    def from_dict(d, source='calibration'):
        """Validate a parsed file and build the object.

        Every schema violation (wrong type, missing key, implausible value, a model that
        misbehaves somewhere in the valid range) raises CalibrationError naming the field.
        """
        if not isinstance(d, dict):
            raise CalibrationError(f'{source}: expected a YAML mapping at the top level, got '
                                   f'{_type_name(d)}')
        fmt = d.get('format')
        if not isinstance(fmt, str) or fmt != FORMAT:
            raise CalibrationError(f'{source}: format {_short(fmt)} is not {FORMAT!r}; this is '
                                   'not a thermal_imu_calib file or it needs a newer version')
        where = ['the file']
        try:
            cal = _build(d, where)
        except CalibrationError as e:
            raise CalibrationError(f'{source}: {e}') from None
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError,
                ArithmeticError, RecursionError, MemoryError) as e:
            if isinstance(e, KeyError):
                msg = f'missing key {e}'
            else:
                msg = str(e) or e.__class__.__name__
            if not isinstance(e, ValueError):
                msg = f'{e.__class__.__name__}: {msg}'
            raise CalibrationError(f'{source}: {where[0]}: {_short(msg, 300, False)}') \
                from None
        return cal


def _build(d, where):
    """Build a Calibration from a file mapping; ``where[0]`` names the field being read."""
    where[0] = 'temperature'
    temp = _mapping(d, 'temperature')
    where[0] = 'temperature.inputs'
    raw_inputs = _list(temp, 'inputs', 'temperature')
    inputs = []
    for j, i in enumerate(raw_inputs):
        where[0] = f'temperature.inputs[{j}]'
        if not isinstance(i, dict):
            raise ValueError(f'expected a mapping with name/topic/unit, got {_type_name(i)}')
        inputs.append(TemperatureInput(_text(i, 'name', None, where[0]),
                                       _text(i, 'topic', 'imu/temperature', where[0]),
                                       _text(i, 'unit', DEGC, where[0])))
    where[0] = 'temperature.valid_range'
    vr = temp.get('valid_range')
    valid = None
    if inputs:
        if not vr:
            raise ValueError('temperature.valid_range is required when there are inputs')
        if not isinstance(vr, dict):
            raise ValueError(f'expected a mapping with min/max, got {_type_name(vr)}')
        valid = np.stack([_numbers(vr['min'], 'valid_range.min', (len(inputs),)),
                          _numbers(vr['max'], 'valid_range.max', (len(inputs),))], 1)
        _check_range_units(vr.get('unit'), inputs)
        for i, inp in enumerate(inputs):
            check_values(valid[i], inp.unit,
                         f'valid_range of input {inp.name!r} ({inp.topic})')
        if np.any(valid[:, 0] > valid[:, 1]):
            raise ValueError('valid_range min is above max')
    where[0] = 'temperature.out_of_range'
    oor = temp.get('out_of_range', 'clamp')
    if not isinstance(oor, str) or oor not in OUT_OF_RANGE_POLICIES:
        raise ValueError(f'out_of_range {_short(oor)} is not one of {OUT_OF_RANGE_POLICIES}')
    where[0] = 'temperature.filter'
    filt = None
    if temp.get('filter') is not None:
        if not inputs:
            raise ValueError('temperature.filter needs temperature inputs')
        filt = ThermalFilter.from_dict(temp['filter'], len(inputs))
        if not np.all(np.isfinite(filt.tau_s)) or np.any(filt.tau_s < 0):
            raise ValueError(f'tau_s {filt.tau_s.tolist()} must be finite and >= 0 s')
    models, idx = {}, {}
    for name in ('accel', 'gyro'):
        where[0] = name
        sec = d.get(name)
        if sec is None:
            models[name], idx[name] = None, [0, 0, 0]
            continue
        _check_model_section(sec, name)
        models[name] = model_from_dict(sec, name)
        models[name].sensor = name       # the section says which sensor (sensor: optional)
        where[0] = f'{name}.temperature_input'
        raw_idx = sec.get('temperature_input', [0, 0, 0])
        if not isinstance(raw_idx, list) or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in raw_idx):
            raise ValueError(f'{name}.temperature_input must be a list of 3 input indices, '
                             f'got {_short(raw_idx)}')
        idx[name] = [int(i) for i in raw_idx]
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
        where[0] = f'{name}.parameters'
        _check_bounds(name, models[name])
    where[0] = 'accel/gyro'
    if models['accel'] is None and models['gyro'] is None:
        raise ValueError('neither an accel nor a gyro model is present')
    where[0] = 'gravity'
    g = _mapping(d, 'gravity')
    gravity = _number(g.get('value', STANDARD_GRAVITY), 'gravity.value')
    if not GRAVITY_BOUNDS[0] <= gravity <= GRAVITY_BOUNDS[1]:
        raise ValueError(f'gravity.value {gravity} m/s^2 is not a terrestrial value '
                         f'({GRAVITY_BOUNDS[0]}..{GRAVITY_BOUNDS[1]}); the file is corrupt or '
                         'not in m/s^2')
    where[0] = 'noise'
    noise = _mapping(d, 'noise')
    noise_std = {}
    for key in ('accel_std', 'gyro_std'):
        where[0] = f'noise.{key}'
        noise_std[key] = _opt_vec(noise.get(key))
    where[0] = 'noise (Allan model)'
    noise_model = _noise_model(noise)
    where[0] = 'fit'
    fit = _free_form(d.get('fit') or {}, 'fit', dict)
    where[0] = 'notes'
    notes = d.get('notes') or []
    notes = [notes] if isinstance(notes, str) else _free_form(notes, 'notes', list)
    notes = [str(n) for n in notes]
    where[0] = 'sensor'
    frame_id = _text(_mapping(d, 'sensor'), 'frame_id', '', 'sensor')
    where[0] = 'software'
    version = _text(_mapping(d, 'software'), 'version', '', 'software')
    where[0] = 'the file'
    cal = Calibration(
        accel=models['accel'], gyro=models['gyro'], inputs=inputs, valid_range=valid,
        out_of_range=oor, accel_input=idx['accel'], gyro_input=idx['gyro'],
        frame_id=frame_id, gravity=gravity,
        gravity_source=_text(g, 'source', '', 'gravity'),
        accel_noise_std=noise_std['accel_std'], gyro_noise_std=noise_std['gyro_std'],
        noise_model=noise_model, fit=fit, notes=notes,
        created=_text(d, 'created', '', 'the file'),
        software_version=version, temperature_filter=filt)
    where[0] = 'temperature.inputs'
    _check_thermal_without_inputs(cal)
    where[0] = 'the model output over the valid range'
    _check_output(cal)
    return cal


#: a calibration file is a few kB; these bound what a hostile one can cost before it is read
MAX_FILE_BYTES = 4 * 2 ** 20
#: deepest nesting of YAML mappings/sequences accepted (a real file nests < 10 deep)
MAX_DEPTH = 64
#: most YAML nodes after alias expansion (an alias bomb expands to billions)
MAX_NODES = 200_000
#: gravity values a file may carry, m/s^2 (cf. gravity.resolve_gravity)
GRAVITY_BOUNDS = (9.7, 9.9)
_SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def decode_text(text, source):
    """Return ``text`` as str: UTF-8 bytes decoded, size checked; CalibrationError otherwise."""
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = bytes(text)
        if len(text) > MAX_FILE_BYTES:
            raise CalibrationError(f'{source}: {len(text)} bytes is too large for a '
                                   f'calibration (limit {MAX_FILE_BYTES})')
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as e:
            raise CalibrationError(f'{source}: not UTF-8 text (invalid byte 0x{text[e.start]:02x} '
                                   f'at offset {e.start}); a calibration is a YAML text file: '
                                   'is it the right file?') from None
    if not isinstance(text, str):
        raise CalibrationError(f'{source}: expected YAML text, got {_type_name(text)}')
    if len(text) > MAX_FILE_BYTES:
        raise CalibrationError(f'{source}: {len(text)} characters is too large for a '
                               f'calibration (limit {MAX_FILE_BYTES})')
    return text


def check_yaml_shape(text, source):
    """Refuse YAML nested deeper than MAX_DEPTH or expanding to more than MAX_NODES nodes.

    Walks the parser's event stream (no recursion, no objects built), so a deeply nested
    or alias-bomb document costs time linear in its text.
    """
    stack, sizes = [], {}

    def done(anchor, n):
        if anchor is not None:
            sizes[anchor] = n
        if stack:
            stack[-1][1] += n
        if n > MAX_NODES or (stack and stack[-1][1] > MAX_NODES):
            raise CalibrationError(f'{source}: the YAML expands to more than {MAX_NODES} '
                                   'values (aliases/anchors repeating content?); a calibration '
                                   'file is a few kB: is it the right file?')
    try:
        for ev in yaml.parse(text, Loader=_SAFE_LOADER):
            if isinstance(ev, yaml.CollectionStartEvent):
                stack.append([ev.anchor, 1])
                if len(stack) > MAX_DEPTH:
                    raise CalibrationError(f'{source}: YAML nested deeper than {MAX_DEPTH} '
                                           'levels; a calibration file nests a few levels: is '
                                           'it the right file?')
            elif isinstance(ev, yaml.CollectionEndEvent):
                anchor, n = stack.pop()
                done(anchor, n)
            elif isinstance(ev, yaml.ScalarEvent):
                done(ev.anchor, 1)
            elif isinstance(ev, yaml.AliasEvent):
                done(None, sizes.get(ev.anchor, 1))
    except yaml.YAMLError as e:
        if 'flow level' in str(e) or 'nesting' in str(e):   # libyaml's own depth limit
            raise CalibrationError(f'{source}: YAML nested deeper than libyaml accepts; a '
                                   'calibration file nests a few levels: is it the right '
                                   'file?') from None
        raise CalibrationError(f'{source}: not valid YAML ({e.__class__.__name__}: '
                               f'{str(e).splitlines()[0]})') from None


def _type_name(x):
    return 'nothing' if x is None else f'a {type(x).__name__}'


def _short(x, n=60, use_repr=True):
    s = repr(x) if use_repr else str(x)
    return s if len(s) <= n else s[:n] + '...'


def _mapping(d, key):
    """Return ``d[key]`` as a mapping ({} when absent); ValueError naming it otherwise."""
    v = d.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ValueError(f'{key} must be a mapping, got {_type_name(v)} {_short(v)}')
    return v


def _list(d, key, where):
    v = d.get(key)
    if v is None:
        return []
    if not isinstance(v, list):
        raise ValueError(f'{where}.{key} must be a list, got {_type_name(v)} {_short(v)}')
    return v


def _text(d, key, default, where):
    """Return ``d[key]`` as a string (numbers are written as text; others refused)."""
    v = d.get(key, default)
    if v is None and default is not None:
        v = default
    if v is None:
        raise KeyError(f'{where}.{key}')
    if isinstance(v, bool) or not isinstance(v, (str, int, float, datetime.date)):
        raise ValueError(f'{where}.{key} must be text, got {_type_name(v)} {_short(v)}')
    return str(v)


def _number(v, what):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f'{what} must be a number, got {_type_name(v)} {_short(v)}')
    v = float(v)
    if not np.isfinite(v):
        raise ValueError(f'{what} is {v}, not a finite number')
    return v


def _numbers(v, what, shape=None):
    """Return a finite float array from a number or nested list of numbers; ValueError else."""
    stack, seen = [v], 0
    while stack:                       # iterative: a list nested 10^5 deep is refused, fast
        x = stack.pop()
        seen += 1
        if seen > MAX_NODES:
            raise ValueError(f'{what} has too many values')
        if isinstance(x, list):
            stack.extend(x)
        elif isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ValueError(f'{what} must be numbers, found {_type_name(x)} {_short(x)}')
    try:
        a = np.asarray(v, float)
    except (ValueError, TypeError, OverflowError):
        raise ValueError(f'{what} is not a regular array of numbers (ragged lists?)') from None
    if a.ndim > 4:
        raise ValueError(f'{what} has {a.ndim} dimensions')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{what} {_short(a.tolist())} is not finite (non-finite values are '
                         'refused)')
    if shape is not None and a.shape != shape:
        raise ValueError(f'{what} has shape {a.shape}, expected {shape}')
    return a


def _check_model_section(sec, name):
    """Refuse a model section whose structure or numbers are unusable, naming the field."""
    if not isinstance(sec, dict):
        raise ValueError(f'{name} must be a mapping with kind and parameters, got '
                         f'{_type_name(sec)} {_short(sec)}')
    kind = sec.get('kind')
    if not isinstance(kind, str):
        raise ValueError(f'{name}.kind must be a model name, got {_type_name(kind)} '
                         f'{_short(kind)}')
    for key in ('sensor', 'unit'):
        if key in sec and not isinstance(sec[key], str):
            raise ValueError(f'{name}.{key} must be text, got {_short(sec[key])}')
    if sec.get('sensor', name) != name:
        raise ValueError(f'{name}.sensor is {sec["sensor"]!r}; the {name} section models the '
                         f'{name}')
    meta = sec.get('meta')
    if meta is not None:
        if not isinstance(meta, dict):
            raise ValueError(f'{name}.meta must be a mapping, got {_type_name(meta)} '
                             f'{_short(meta)}')
        _free_form(meta, f'{name}.meta', dict)
    params = sec.get('parameters')
    if not isinstance(params, dict) or not params:
        raise ValueError(f'{name}.parameters must be a non-empty mapping, got '
                         f'{_type_name(params)} {_short(params)}')
    for key, p in params.items():
        where = f'{name}.parameters.{key}'
        if not isinstance(key, str):
            raise ValueError(f'{name}.parameters: key {_short(key)} is not a name')
        if not isinstance(p, dict) or 'value' not in p or not isinstance(p.get('unit'), str):
            raise ValueError(f'{where} needs "value" (numbers) and "unit" (text)')
        value = _numbers(p['value'], f'{where}.value')
        if p.get('std') is not None:
            std = _numbers(p['std'], f'{where}.std')
            if np.any(std < 0):
                raise ValueError(f'{where}.std is negative')
            if std.shape != value.shape:
                raise ValueError(f'{where}.std has shape {std.shape}, value {value.shape}')
        if 'description' in p and not isinstance(p['description'], (str, type(None))):
            raise ValueError(f'{where}.description must be text')


def _free_form(x, what, kind):
    """Check a free-form section (fit, notes, meta): its type and a bounded plain content.

    Returns it unchanged. Iterative, so a bomb of shared references or deep nesting is
    refused after at most MAX_NODES steps.
    """
    if not isinstance(x, kind):
        raise ValueError(f'{what} must be a {"mapping" if kind is dict else "list"}, got '
                         f'{_type_name(x)} {_short(x)}')
    stack, seen = [(x, 0)], 0
    while stack:
        v, depth = stack.pop()
        seen += 1
        if seen > MAX_NODES or depth > MAX_DEPTH:
            raise ValueError(f'{what} is too large or too deeply nested')
        if isinstance(v, dict):
            stack.extend((w, depth + 1) for kv in v.items() for w in kv)
        elif isinstance(v, (list, tuple)):
            stack.extend((w, depth + 1) for w in v)
        elif not isinstance(v, (str, int, float, bool, type(None), datetime.date,
                                np.generic, np.ndarray)):
            raise ValueError(f'{what} holds {_type_name(v)}, not plain data')
    return x


def _check_thermal_without_inputs(cal):
    """Refuse a model that changes with temperature in a calibration with no thermal input.

    With ``temperature.inputs: []`` every model is evaluated at its reference value
    (``axis_temperatures``), so thermal terms would silently do nothing: the output would
    be the same at 22 and 34 degC. Probed per model at T0 and T0 +- 10 (input units).
    """
    if cal.inputs:
        return
    for name in ('accel', 'gyro'):
        model = getattr(cal, name)
        if model is None:
            continue
        t0 = np.broadcast_to(np.asarray(getattr(model, 't0', np.zeros(3)), float), (3,))
        raw = np.vstack([np.eye(3), -np.eye(3)]) * (cal.gravity if name == 'accel' else 1.0)
        temps = [np.tile(t0 + dt, (6, 1)) for dt in (0.0, -10.0, 10.0)]
        with np.errstate(all='ignore'):
            aux = {'accel': raw}
            out = [np.asarray(model.correct(raw, t, aux=aux), float) for t in temps]
        scale = np.max(np.abs(out[0])) or 1.0
        if any(not np.allclose(o, out[0], rtol=0, atol=1e-12 * scale) for o in out[1:]):
            raise ValueError(f'the {name} model has thermal terms but there is no temperature '
                             'input: it would run at its reference temperature whatever the '
                             'real one; add the input(s) it was fitted on (inputs, '
                             'valid_range) or refit without thermal terms')


def _check_output(cal):
    """Refuse a model whose output is unusable anywhere in its valid input range.

    Each axis sees +-g (accel) and +-1 rad/s (gyro) at 17 points spanning the valid range
    of every input; the corrected output must be finite with a scale factor 0.25..4 and a
    bias below 100 m/s^2 / 10 rad/s (a corrupt coefficient such as k2 = 1e300 erases the
    output at the range edges while the mid-range looks fine).
    """
    if cal.inputs:
        f = np.linspace(0.0, 1.0, 17)[:, None]
        lo, hi = cal.valid_range[:, 0], cal.valid_range[:, 1]
        grid = lo + f * (hi - lo)
    else:
        grid = np.zeros((1, 0))
    m = grid.shape[0]
    eye = np.vstack([np.eye(3), -np.eye(3)])               # +x +y +z -x -y -z
    temps = np.repeat(grid, 6, axis=0)
    accel = np.tile(eye * cal.gravity, (m, 1))
    gyro = np.tile(eye * 1.0, (m, 1))
    with np.errstate(all='ignore'):
        res = cal.apply(accel, gyro, temps)
        for name, out, amp, bias_lim, std in (
                ('accel', res.accel, cal.gravity, 100.0, res.accel_std),
                ('gyro', res.gyro, 1.0, 10.0, res.gyro_std)):
            if getattr(cal, name) is None:
                continue
            out = np.asarray(out, float).reshape(m, 6, 3)
            if not np.all(np.isfinite(out)):
                raise ValueError(f'the {name} model gives NaN/Inf inside the valid range')
            if std is not None and not np.all(np.isfinite(std)):
                raise ValueError(f'the {name} model\'s uncertainty is NaN/Inf inside the '
                                 'valid range')
            scale = (out[:, :3] - out[:, 3:]) / (2 * amp)      # (m, axis, component)
            diag = np.abs(np.einsum('mii->mi', scale))
            bias = np.abs(out[:, :3] + out[:, 3:]) / 2
            if np.any(diag < 0.25) or np.any(diag > 4.0) or np.any(bias > bias_lim):
                j = int(np.argmax(np.any((diag < 0.25) | (diag > 4.0), 1)
                                  | np.any(bias > bias_lim, (1, 2))))
                at = grid[j].round(3).tolist() if cal.inputs else 'any input'
                raise ValueError(
                    f'the {name} model is implausible inside the valid range: at input '
                    f'{at} its scale factor is {diag[j].tolist()} (expected 0.25..4) and its '
                    f'bias up to {float(bias[j].max()):.3g} {out_unit(name)}; a coefficient '
                    'is corrupt (e.g. a huge k2): recalibrate or restore the file')


def out_unit(name):
    """Return the SI unit of the accel or gyro output."""
    return 'm/s^2' if name == 'accel' else 'rad/s'


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
    v = _numbers(sec['value'] if isinstance(sec, dict) else sec, 'noise std value')
    if v.size != 3 or np.any(v < 0):
        raise ValueError(f'noise std {v.tolist()} must be 3 finite non-negative values')
    return v.reshape(3)


def _model_std(model, temps, aux):
    """Return the model's predict_std, with its history terms when it has them."""
    if aux is None:
        return model.predict_std(temps)
    return model.predict_std(temps, aux=aux)


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
