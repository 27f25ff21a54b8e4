"""The Calibration object: one IMU's models, thermal inputs and validity, applied and written.

``Calibration.apply`` is the one vectorised entry point the CLI and both nodes use;
``to_yaml``/``save`` write the versioned file and ``load``/``from_yaml``/``from_dict`` read
it back through its schema (``schema.py``: every field and check of the file).
"""

import datetime
import hashlib
import os
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import yaml

from .. import __version__
from ..gravity import STANDARD_GRAVITY
from ..input_units import DEGC, is_temperature
from ..models import SensorModel
from ..thermal_input import CalibrationStream, ThermalFilter
from . import schema
from .base import (CalibrationError, DAY_S, FORMAT, FORMAT_AGEING, FORMAT_LINEAR, FORMAT_OFFSET,
                   FORMAT_SENSOR_RANGE, LINEAR_STEP_DEGC, LINEAR_STEP_FRACTION, NOISE_UNITS,
                   OUT_OF_RANGE_V1, TemperatureInput)
from .yaml_text import parse_yaml, read_file

#: libyaml's emitter when PyYAML has it, 4x faster: the same text as the pure-Python one on
#: the 493 calibrations of the tests and benches compared; a long double-quoted string (a
#: note with non-ASCII text) may be folded at other places, and reads back the same.
#: ``Calibration.id`` keeps the pure-Python emitter, so ids do not depend on libyaml.
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


@dataclass
class Compensated:
    """Result of ``Calibration.apply``: corrected columns plus per-row flags."""

    accel: np.ndarray
    gyro: np.ndarray
    #: (n,) bool, True where a temperature was outside the valid range (clamped, extrapolated
    #: or continued)
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
    #: optional {'accel'|'gyro': (k, 2)} valid range of one sensor's model, in the inputs'
    #: units, when it differs from ``valid_range`` (a calibration composed of two sensors'
    #: models fitted on different holds, ``lifelong.compose``); ``valid_range`` then spans
    #: both, and each model is clamped to its own range
    sensor_range: dict = field(default_factory=dict)
    #: optional gyro bias ageing carried forward in time: ``rate`` (3,) rad/s per day,
    #: ``epoch`` (s, the stamps' clock: UNIX time for header stamps) when the gyro model is
    #: the bias, ``max_days`` (> 0) the most it is carried either way. ``apply`` with
    #: ``stamps`` takes ``rate * clip((t - epoch) / day, -max_days, max_days)`` off the gyro;
    #: without stamps, the model as at ``epoch``. Optional ``offset`` (3,) rad/s (format 5):
    #: the bias moved by that constant at the epoch (taken off with or without stamps; a
    #: lifelong node's offset follower, ``lifelong.follower``). Empty: none (a lifelong
    #: estimate fitted with the ageing removed writes it, ``lifelong.variants.with_ageing``);
    #: always empty without a gyro model
    gyro_ageing: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.gyro is None:
            self.gyro_ageing = {}    # a term of the gyro model: none without one
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
    def own_range(self, which):
        """Return the (k, 2) range 'accel'/'gyro' is valid over (None: no inputs).

        ``sensor_range[which]`` when that sensor's model has its own (narrower) range, else
        ``valid_range``.
        """
        return self.sensor_range.get(which, self.valid_range)

    def range_policy(self, which):
        """Return what "accel"/"gyro" does outside its range: clamp, extrapolate or linear."""
        if self.out_of_range == 'linear_gyro':
            return 'linear' if which == 'gyro' else 'clamp'
        return self.out_of_range

    def linear_step(self, which):
        """Return the (k,) step inside the edge a linear continuation takes its slope over.

        ``LINEAR_STEP_DEGC`` for a temperature input, ``LINEAR_STEP_FRACTION`` of the
        range for another unit; at most half the sensor's range.
        """
        vr = self.own_range(which)
        width = vr[:, 1] - vr[:, 0]
        step = np.array([LINEAR_STEP_DEGC if is_temperature(i.unit) else
                         LINEAR_STEP_FRACTION * w for i, w in zip(self.inputs, width)])
        return np.minimum(step, 0.5 * width)

    def axis_temperatures(self, temps, which, inset=None):
        """Map (n, k) thermal inputs to (n, 3) per-axis inputs for 'accel'/'gyro'.

        Returns (per_axis, out_of_range_mask). With no inputs the model's reference
        temperature is used (temperature-independent calibration). ``inset``: (k,) the
        range is narrowed by it at both ends before clamping (a linear continuation's
        inner point).
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
        vr = self.own_range(which)
        lo, hi = vr[:, 0], vr[:, 1]
        oor = np.any((temps < lo) | (temps > hi), axis=1)
        if self.range_policy(which) != 'extrapolate':
            if inset is not None:
                lo, hi = lo + inset, hi - inset
            temps = np.clip(temps, lo, hi)
        return temps[:, idx], oor

    def _correct(self, which, x, temps, history, aux):
        """Return (corrected (n, 3), model std (n, 3) or None, out-of-range mask) of one sensor.

        A 'linear' sensor beyond its range: the value at the edge plus the slope between the
        edge and the step inside it (readings and lagged readings clamped to the narrowed
        range), times the excess in steps, per axis from the axis' input. The excess counts
        no further than the range's own width: a slope measured over a range W wide says
        nothing about the sensor more than W beyond it, so beyond that the continued value
        is held (docs/lifelong.md, seed 38).
        """
        model = getattr(self, which)
        t, oor = self.axis_temperatures(temps, which)
        hist = self._axis_history(history, model, which)
        out = model.correct(x, t, aux={**aux, **(hist or {})})
        std = _model_std(model, t, hist)
        if self.range_policy(which) == 'linear' and np.any(oor):
            idx = self.accel_input if which == 'accel' else self.gyro_input
            vr = self.own_range(which)
            step = self.linear_step(which)
            excess = np.maximum(temps - vr[:, 1], 0.0) + np.maximum(vr[:, 0] - temps, 0.0)
            k = (np.minimum(excess, vr[:, 1] - vr[:, 0]) / step)[:, idx]
            t_in, _ = self.axis_temperatures(temps, which, inset=step)
            h_in = self._axis_history(history, model, which, inset=step)
            inner = model.correct(x, t_in, aux={**aux, **(h_in or {})})
            out = out + (out - inner) * k
        return out, std, oor

    def ageing_offset(self, stamps, n=None):
        """Return the (n, 3) gyro bias change (rad/s) since the model's fit, or None.

        ``gyro_ageing``'s ``offset`` (if any) plus its rate carried from the epoch to
        ``stamps`` ((n,) s on the epoch's clock; None: at the epoch, ``n`` rows). None
        without an ageing term, or with only a rate and no stamps.
        """
        ag = self.gyro_ageing
        if not ag:
            return None
        offset = ag.get('offset')
        if stamps is None:
            return None if offset is None or n is None else \
                np.broadcast_to(np.asarray(offset, float), (n, 3))
        days = (np.asarray(stamps, float).reshape(-1) - float(ag['epoch'])) / DAY_S
        cap = float(ag['max_days'])
        drift = np.clip(days, -cap, cap)[:, None] * np.asarray(ag['rate'], float)
        return drift if offset is None else drift + np.asarray(offset, float)

    def apply(self, accel, gyro, temps=None, history=None, filter_age=None, stamps=None):
        """Compensate (n, 3) accel [m/s^2] and gyro [rad/s] at (n, k) thermal inputs.

        Column j of ``temps`` is input j in its unit (degC, or a proxy's unit such as Hz).

        NaN temperatures are not allowed here; resolve missing temperature first (hold or
        passthrough). Returns a ``Compensated`` with the out-of-range mask. With a
        ``temperature_filter``, ``temps`` are the models' (lagged) inputs: stream data
        through ``stream().apply``; raw readings here mean thermal equilibrium.
        ``history``: ``{key: (n, k)}`` lagged readings for history-dependent models
        (``thermal_input.HistoryStream``, filled by ``stream().apply``); None: equilibrium.
        ``filter_age``: (n,) s since the stream's filter (re)started in equilibrium (filled
        by ``stream().apply``): the 1-sigma adds the filter's ``restart_spread`` decaying
        ``exp(-age / tau)``; None: no restart term. ``stamps``: (n,) s (header stamps, filled
        by ``stream().apply``): with a ``gyro_ageing`` term the gyro bias is carried to them
        (``ageing_offset``); None: the bias at the term's epoch (its ``offset`` included).
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
            a_out, m_std, o = self._correct('accel', accel, temps, history, {})
            oor |= o
            a_std = _combine_std(m_std, self.noise_std('accel'), n,
                                 self.restart_std('accel', filter_age))
        if self.gyro is not None:
            g_out, m_std, o = self._correct('gyro', gyro, temps, history, {'accel': a_out})
            drift = self.ageing_offset(stamps, n)
            if drift is not None:
                g_out = g_out - drift
            oor |= o
            g_std = _combine_std(m_std, self.noise_std('gyro'), n,
                                 self.restart_std('gyro', filter_age))
        return Compensated(a_out, g_out, oor, a_std, g_std)

    def _axis_history(self, history, model, which, inset=None):
        """Return ``{'history': {key: (n, 3)}}`` for a history-dependent model, else None.

        The lagged readings are mapped to axes and clamped like the readings themselves.
        """
        keys = getattr(model, 'history_keys', ())
        if not keys or not history or not self.inputs:
            return None
        out = {k: self.axis_temperatures(history[k], which, inset)[0]
               for k in keys if k in history}
        if '_age_s' in history:
            out['_age_s'] = history['_age_s']
        return {'history': out}

    def restart_std(self, which, age):
        """Return the (n, 3) 1-sigma a (re)started filter adds to 'accel'/'gyro', or None.

        The restarted lag starts at the reading instead of the lagged state it should have;
        that difference decays as exp(-age / tau) (tau of each axis' input), and so does the
        output error it makes, at most the filter's ``restart_spread`` (sensor unit).
        """
        f = self.temperature_filter
        spread = (f.restart_spread or {}).get(which) if f is not None else None
        if spread is None or age is None:
            return None
        idx = self.accel_input if which == 'accel' else self.gyro_input
        tau = f.tau_s[idx]
        age = np.asarray(age, float)[:, None]
        mem = np.where(tau > 0, np.exp(-age / np.where(tau > 0, tau, 1.0)), 0.0)
        return mem * spread

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
            'format': (FORMAT_OFFSET if self.gyro_ageing.get('offset') is not None else
                       FORMAT_AGEING if self.gyro_ageing else
                       FORMAT_LINEAR if self.out_of_range not in OUT_OF_RANGE_V1 else
                       FORMAT_SENSOR_RANGE if self.sensor_range else FORMAT),
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
        if self.sensor_range:
            d['temperature']['sensor_range'] = {
                k: {'min': v[:, 0].tolist(), 'max': v[:, 1].tolist()}
                for k, v in sorted(self.sensor_range.items())}
        for name, model, idx in (('accel', self.accel, self.accel_input),
                                 ('gyro', self.gyro, self.gyro_input)):
            if model is not None:
                sec = model.to_dict()
                sec['temperature_input'] = [int(i) for i in idx]
                d[name] = sec
        if self.gyro_ageing:
            ag = self.gyro_ageing
            d['gyro_ageing'] = {
                'rate': {'value': np.asarray(ag['rate'], float).tolist(), 'unit': 'rad/s/day'},
                'epoch': {'value': float(ag['epoch']), 'unit': 's',
                          'description': 'when the gyro model is the bias (IMU stamps)'},
                'max_days': {'value': float(ag['max_days']), 'unit': 'day',
                             'description': 'carried at most this far either way'}}
            if ag.get('offset') is not None:
                d['gyro_ageing']['offset'] = {
                    'value': np.asarray(ag['offset'], float).tolist(), 'unit': 'rad/s',
                    'description': 'the bias moved by this at the epoch (recent holds)'}
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
        return yaml.dump(self.to_dict(), Dumper=_DUMPER, sort_keys=False,
                         default_flow_style=None, width=100)

    def save(self, path):
        """Write atomically (``io.output.write_atomic``: temporary + rename); return path."""
        from ..io.output import write_atomic
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
        return Calibration.from_dict(parse_yaml(text, source), source)

    @staticmethod
    def load(path):
        """Load and validate a calibration file."""
        return Calibration.from_yaml(read_file(path), os.fspath(path))

    @staticmethod
    def from_dict(d, source='calibration'):
        """Validate a parsed file and build the object (``schema.load``).

        Every schema violation (wrong type, missing key, implausible value, a model that
        misbehaves somewhere in the valid range) raises CalibrationError naming the field.
        """
        return schema.load(d, source, Calibration)


def spanning_range(ranges):
    """Return (valid_range, sensor_range) of per-sensor ranges {'accel'|'gyro': (k, 2)}.

    The valid range spans them all; a sensor whose range differs from that span keeps it
    as its own (``Calibration.sensor_range``, ``own_range``).
    """
    rs = [np.asarray(r, float) for r in ranges.values()]
    valid = np.stack([np.min([r[:, 0] for r in rs], 0), np.max([r[:, 1] for r in rs], 0)], 1)
    return valid, {w: np.array(r, float) for w, r in ranges.items()
                   if not np.array_equal(r, valid)}


def _model_std(model, temps, aux):
    """Return the model's predict_std, with its history terms when it has them."""
    if aux is None:
        return model.predict_std(temps)
    return model.predict_std(temps, aux=aux)


def _combine_std(model_std, noise_std, n, restart_std=None):
    if model_std is None and noise_std is None and restart_std is None:
        return None
    var = np.zeros((n, 3))
    for std in (model_std, noise_std, restart_std):
        if std is not None:
            var = var + np.asarray(std) ** 2
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
