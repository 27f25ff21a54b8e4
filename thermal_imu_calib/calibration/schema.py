"""The calibration file's schema: every field, its type, default and check, in one place.

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
      out_of_range: clamp            # or extrapolate, linear, linear_gyro (format 3)
      filter: {kind: lag, tau_s: [300.0], unit: s,   # optional (thermal_input)
               restart_spread: {accel: {value: [...], unit: m/s^2}, gyro: ...}}  # optional
    accel: {kind: field_polynomial, temperature_input: [0, 0, 0], parameters: {...}}
    gyro: {kind: offset_polynomial, temperature_input: [0, 0, 0], parameters: {...}}
    noise: {accel_std: [...], gyro_std: [...], unit: ...}
    gyro_ageing: {rate: {value: [...], unit: rad/s/day}, epoch: {value: ..., unit: s},
                  max_days: {value: ..., unit: day},         # optional (format 4)
                  offset: {value: [...], unit: rad/s}}       # optional (format 5)
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

``SCHEMA`` is that file as a table of fields (the words are in ``spec.py``): their type,
default and bounds. ``RULES`` are the checks that tie fields together, run in order after
the table: a valid range per input in the input's unit, axes mapped to existing inputs of
one unit, each model's own parameter set (``models``) and plausible values. ``load`` runs
both, builds the object and checks what it computes over its valid range
(``plausible.py``). Every refusal is one CalibrationError naming the file and the field.
"""

import numpy as np

from ..gravity import STANDARD_GRAVITY
from ..input_units import check_values, DEGC, normalize_unit
from ..models import model_from_dict
from ..thermal_input import ThermalFilter
from . import plausible
from .base import (CalibrationError, FILE_FORMATS, FORMAT_AGEING, FORMAT_OFFSET, GRAVITY_BOUNDS,
                   NOISE_UNITS, OUT_OF_RANGE_POLICIES, short, TemperatureInput, type_name)
from .spec import (Choice, FreeForm, Indices, ListOf, Mapping, MapOf, Notes, Number, Numbers,
                   REQUIRED, Text, TextOrList, Valued)


def _std_like_value(p, path):
    if p['std'] is not None and p['std'].shape != p['value'].shape:
        raise ValueError(f'{path}.std has shape {p["std"].shape}, value {p["value"].shape}')


PARAMETER = Mapping({'value': Numbers(REQUIRED),
                     'unit': Text(REQUIRED, numbers=False),
                     'std': Numbers(nonnegative=True),
                     'description': Text(None, numbers=False)},
                    what='a mapping with value (numbers) and unit (text)', rule=_std_like_value)
MODEL = Mapping({'kind': Text(REQUIRED, numbers=False, what='a model name'),
                 'sensor': Text(None, numbers=False),
                 'unit': Text(None, numbers=False),
                 'meta': FreeForm(dict, optional=True),
                 'parameters': MapOf(PARAMETER),
                 'temperature_input': Indices(3, default=[0, 0, 0], null=False)},
                what='a mapping with kind and parameters', optional=True)
#: white-noise std and Allan noise model: three values >= 0 per entry (one per axis)
AXES = Valued(Numbers(REQUIRED, size=3, nonnegative=True))
POSITIVE = Valued(Number(REQUIRED, positive=True))
#: the whole file; ``format`` is checked first by ``load``, ``units`` is derived and unread
SCHEMA = Mapping({
    'software': Mapping({'version': Text('')}),
    'created': Text(''),
    'sensor': Mapping({'frame_id': Text('')}),
    'gravity': Mapping({
        'value': Number(STANDARD_GRAVITY, null=False, within=(
            *GRAVITY_BOUNDS, 'a terrestrial value', 'm/s^2',
            'the file is corrupt or not in m/s^2')),
        'source': Text('')}),
    'temperature': Mapping({
        'inputs': ListOf(Mapping({'name': Text(REQUIRED),
                                  'topic': Text('imu/temperature'),
                                  'unit': Text(DEGC, numbers=False)},
                                 what='a mapping with name, topic and unit')),
        'valid_range': Mapping({'min': Numbers(REQUIRED), 'max': Numbers(REQUIRED),
                                'unit': TextOrList()},
                               what='a mapping with min and max', optional=True),
        'out_of_range': Choice(OUT_OF_RANGE_POLICIES, 'clamp', null=False),
        # optional: one sensor's own range, in the inputs' units (a composed calibration)
        'sensor_range': Mapping({s: Mapping({'min': Numbers(REQUIRED),
                                             'max': Numbers(REQUIRED)},
                                            what='a mapping with min and max', optional=True)
                                 for s in ('accel', 'gyro')},
                                what='a mapping of accel and/or gyro ranges', optional=True),
        'filter': Mapping({'kind': Text('lag', numbers=False), 'tau_s': Numbers(REQUIRED),
                           'unit': Text('s', numbers=False),
                           # optional (files before it: no widening after a restart)
                           'restart_spread': Mapping({'accel': AXES, 'gyro': AXES},
                                                     optional=True)},
                          what='a mapping with kind, tau_s and unit', optional=True)}),
    'accel': MODEL,
    'gyro': MODEL,
    'noise': Mapping({'accel_std': AXES, 'gyro_std': AXES,
                      'accel_noise_density': AXES, 'gyro_noise_density': AXES,
                      'accel_random_walk': AXES, 'gyro_random_walk': AXES,
                      'rate_hz': POSITIVE, 'horizon_s': POSITIVE}),
    # optional (format 4): the gyro bias carried forward in time (Calibration.gyro_ageing)
    'gyro_ageing': Mapping({'rate': Valued(Numbers(REQUIRED, size=3)),
                            'epoch': Valued(Number(REQUIRED)),
                            'max_days': Valued(Number(REQUIRED, positive=True)),
                            # optional (format 5): a constant the bias moved by at the epoch
                            'offset': Valued(Numbers(size=3))},
                           what='a mapping with rate, epoch, max_days (and offset)',
                           optional=True),
    'fit': FreeForm(dict),
    'notes': Notes(),
})


def _at(path, fn, *args):
    """Return ``fn(*args)``; its ValueError (or a stray TypeError...) names ``path`` first."""
    try:
        return fn(*args)
    except ValueError as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith(path) else f'{path}: {msg}') from None
    except (KeyError, TypeError, AttributeError, IndexError, OverflowError,
            ArithmeticError) as e:
        raise ValueError(f'{path}: {e.__class__.__name__}: {e}') from None


def _inputs(raw, doc, out):
    out['inputs'] = [_at(f'temperature.inputs[{j}]', TemperatureInput, i['name'], i['topic'],
                         i['unit'])
                     for j, i in enumerate(doc['temperature']['inputs'])]


def _min_max(rng, k, path):
    """Return the (k, 2) [min, max] of a checked range mapping; each must have k values."""
    for key in ('min', 'max'):
        if rng[key].shape != (k,):
            raise ValueError(f'{path}.{key} has shape {rng[key].shape}, expected ({k},): one '
                             'value per input')
    return np.stack([rng['min'], rng['max']], 1)


def _valid_range(raw, doc, out):
    inputs, vr, k = out['inputs'], doc['temperature']['valid_range'], len(out['inputs'])
    out['valid_range'] = None
    if not inputs:
        return
    if vr is None:
        raise ValueError('temperature.valid_range is required when there are inputs: '
                         'min and max of each input, in its unit')
    valid = _min_max(vr, k, 'temperature.valid_range')
    if vr['unit'] is not None:
        units = [vr['unit']] * k if isinstance(vr['unit'], str) else vr['unit']
        if len(units) != k:
            raise ValueError(f'temperature.valid_range.unit has {len(units)} entries for {k} '
                             'inputs')
        for u, inp in zip(units, inputs):
            u = _at('temperature.valid_range.unit', normalize_unit, u,
                    f'valid_range of input {inp.name!r}')
            if u != inp.unit:
                raise ValueError(f'temperature.valid_range of input {inp.name!r} is in {u} but '
                                 f'the input is in {inp.unit}; give the range in the '
                                 'input\'s unit')
    for i, inp in enumerate(inputs):
        _at('temperature.valid_range', check_values, valid[i], inp.unit,
            f'valid_range of input {inp.name!r} ({inp.topic})')
    if np.any(valid[:, 0] > valid[:, 1]):
        raise ValueError('temperature.valid_range: min is above max '
                         f'(min {valid[:, 0].tolist()}, max {valid[:, 1].tolist()})')
    out['valid_range'] = valid


def _sensor_range(raw, doc, out):
    sr, valid, out['sensor_range'] = doc['temperature']['sensor_range'], out['valid_range'], {}
    if sr is None:
        return
    if valid is None:
        raise ValueError('temperature.sensor_range needs temperature inputs and valid_range')
    for name in ('accel', 'gyro'):
        r = sr[name]
        if r is None:
            continue
        rng = _min_max(r, len(valid), f'temperature.sensor_range.{name}')
        if np.any(rng[:, 0] > rng[:, 1]) or np.any(rng[:, 0] < valid[:, 0]) \
                or np.any(rng[:, 1] > valid[:, 1]):
            raise ValueError(f'temperature.sensor_range.{name} ({rng.tolist()}) must have min '
                             f'<= max and lie within valid_range ({valid.tolist()})')
        out['sensor_range'][name] = rng


def _filter(raw, doc, out):
    f = doc['temperature']['filter']
    out['temperature_filter'] = None
    if f is not None:
        if not out['inputs']:
            raise ValueError('temperature.filter needs temperature inputs')
        out['temperature_filter'] = _at('temperature.filter', ThermalFilter.from_dict, f,
                                        len(out['inputs']))


def _models(raw, doc, out):
    inputs = out['inputs']
    for name in ('accel', 'gyro'):
        sec = doc[name]
        out[name], out[f'{name}_input'] = None, [0, 0, 0]
        if sec is None:
            continue
        if sec['sensor'] not in (None, name):
            raise ValueError(f'{name}.sensor is {sec["sensor"]!r}; the {name} section models '
                             f'the {name}')
        model = _at(name, model_from_dict, raw[name], name)   # the family's parameter set
        model.sensor = name          # the section says which sensor (sensor: optional)
        idx = sec['temperature_input']
        if inputs:
            if any(i < 0 or i >= len(inputs) for i in idx):
                raise ValueError(f'{name}.temperature_input {idx} must name 3 of the '
                                 f'{len(inputs)} temperature inputs (0..{len(inputs) - 1})')
            units = {inputs[i].unit for i in idx}
            if len(units) > 1:
                raise ValueError(f'{name}.temperature_input {idx} maps the axes to inputs of '
                                 f'different units {sorted(units)}; map all three axes to '
                                 'inputs of one unit')
            unit = units.pop()
            if model.input_unit != unit:
                raise ValueError(
                    f'{name} parameters are in {model.input_unit} (unit of its reference '
                    f'value) but temperature_input maps it to inputs in {unit}; the file was '
                    'edited inconsistently: recalibrate or fix the units')
        _at(f'{name}.parameters', plausible.check_bounds, name, model)
        out[name], out[f'{name}_input'] = model, idx
    if out['accel'] is None and out['gyro'] is None:
        raise ValueError('neither an accel nor a gyro model is present; a calibration has an '
                         'accel section, a gyro section or both')


def _noise(raw, doc, out):
    noise = doc['noise']
    out['accel_noise_std'], out['gyro_noise_std'] = noise['accel_std'], noise['gyro_std']
    out['noise_model'] = {k: noise[k] for k in NOISE_UNITS if noise[k] is not None}


def _gyro_ageing(raw, doc, out):
    ag, out['gyro_ageing'] = doc['gyro_ageing'], {}
    if ag is None:
        return
    if out['gyro'] is None:
        raise ValueError('gyro_ageing needs a gyro model: remove it or add the gyro section')
    want = FORMAT_OFFSET if ag.get('offset') is not None else FORMAT_AGEING
    if raw.get('format') != want:
        what = 'gyro_ageing.offset' if want == FORMAT_OFFSET else 'gyro_ageing'
        raise ValueError(f'{what} is a field of format {want!r}, the file says '
                         f'{raw.get("format")!r}; the file was edited: recalibrate')
    out['gyro_ageing'] = {'rate': np.asarray(ag['rate'], float), 'epoch': float(ag['epoch']),
                          'max_days': float(ag['max_days'])}
    if ag.get('offset') is not None:
        out['gyro_ageing']['offset'] = np.asarray(ag['offset'], float)


def _plain_fields(raw, doc, out):
    out.update(out_of_range=doc['temperature']['out_of_range'],
               frame_id=doc['sensor']['frame_id'], gravity=doc['gravity']['value'],
               gravity_source=doc['gravity']['source'], fit=doc['fit'], notes=doc['notes'],
               created=doc['created'], software_version=doc['software']['version'])


#: checks across fields, in order, each named by the field it concerns; each adds keyword
#: arguments of Calibration to ``out``
RULES = [('temperature.inputs', _inputs), ('temperature.valid_range', _valid_range),
         ('temperature.sensor_range', _sensor_range),
         ('temperature.filter', _filter), ('accel/gyro', _models),
         ('gyro_ageing', _gyro_ageing), ('noise', _noise), ('the file', _plain_fields)]


def check_format(d, source):
    """Refuse a parsed file that is not a mapping of this format (CalibrationError)."""
    if not isinstance(d, dict):
        raise CalibrationError(f'{source}: expected a YAML mapping at the top level, got '
                               f'{type_name(d)}')
    fmt = d.get('format')
    if not isinstance(fmt, str) or fmt not in FILE_FORMATS:
        known = ' or '.join(repr(f) for f in FILE_FORMATS)
        raise CalibrationError(f'{source}: format {short(fmt)} is not {known}; this is '
                               'not a thermal_imu_calib file or it needs a newer version')


def load(d, source, factory):
    """Check a parsed file against SCHEMA and RULES and return ``factory(**fields)``.

    ``factory`` is the Calibration class; the object built is checked over its valid range
    (``plausible``). Every violation raises CalibrationError '``source``: FIELD ...'.
    """
    check_format(d, source)
    field = 'the file'
    try:
        doc, out = SCHEMA.check(d, ''), {}
        for field, rule in RULES:
            rule(d, doc, out)
        field = 'the file'
        cal = factory(**out)
        field = 'the model output over the valid range'
        plausible.check_thermal_without_inputs(cal)
        plausible.check_output(cal)
    except CalibrationError as e:
        raise CalibrationError(f'{source}: {e}') from None
    except ValueError as e:
        raise CalibrationError(f'{source}: {short(str(e), 300, False)}') from None
    except (KeyError, TypeError, AttributeError, IndexError, OverflowError, ArithmeticError,
            RecursionError, MemoryError) as e:
        msg = f'{e.__class__.__name__}: {e}'
        raise CalibrationError(f'{source}: {field}: {short(msg, 300, False)}') from None
    return cal
