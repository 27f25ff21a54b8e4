"""The calibration file's schema as JSON Schema (jsonschema 4.26): the measured alternative.

Not used by the package. It is what ``calibration/schema.py`` would be with jsonschema: the
same fields in a JSON Schema (``SCHEMA``), the loader's wording made from jsonschema's
best-matching error (``message``: a field's ``title`` says what it must be), defaults and
conversions applied by a walk of the same schema (``normalize``), then the same
cross-field ``RULES`` and plausibility checks (``load``). ``schema_messages.py
--jsonschema`` prints its message next to the loader's on every case; docs/architecture.md
("The calibration file's schema") reports the comparison and the line counts.

What JSON Schema cannot say is code here too: finite numbers (a ``finite`` keyword),
dates read by YAML as text, regular (not ragged) arrays, a std shaped like its value.
"""

import copy
import datetime
import math

import jsonschema
from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match
import numpy as np

from thermal_imu_calib.calibration import plausible, schema
from thermal_imu_calib.calibration.base import (CalibrationError, GRAVITY_BOUNDS,
                                                short, type_name)
from thermal_imu_calib.gravity import STANDARD_GRAVITY


def _finite(validator, value, instance, sch):
    if value and isinstance(instance, float) and not math.isfinite(instance):
        yield jsonschema.ValidationError('not finite')


#: YAML gives dates for unquoted ``created: 2026-11-22``
_TYPES = Draft202012Validator.TYPE_CHECKER.redefine(
    'string', lambda c, x: isinstance(x, (str, datetime.date)))
Validator = jsonschema.validators.extend(Draft202012Validator, {'finite': _finite},
                                         type_checker=_TYPES)


def _text(default='', names=False):
    return {'type': ['string', 'null'] if names else ['string', 'number', 'null'],
            'title': 'text', 'x-kind': 'text', 'default': default}


def _obj(props, title='a mapping', default=None, required=(), **kw):
    return {'type': ['object', 'null'], 'title': title, 'properties': props,
            'default': {} if default is None else default, 'required': list(required), **kw}


NUMBER = {'type': 'number', 'finite': True}
NUMBERS = {'$ref': '#/$defs/numbers', 'title': 'numbers', 'x-kind': 'numbers'}
VEC3 = {'type': 'array', 'title': 'three numbers >= 0', 'minItems': 3, 'maxItems': 3,
        'items': {**NUMBER, 'minimum': 0}, 'x-kind': 'numbers'}
POSITIVE = {**NUMBER, 'title': 'a number > 0', 'exclusiveMinimum': 0, 'x-kind': 'number'}
REQ = {'default': None, 'x-required': True}


def _valued(item):
    return {'anyOf': [{'type': 'null'}, item, _obj({'value': {**item, **REQ}},
                                                   required=['value'])],
            'title': f'{item["title"]} or a mapping with value', 'x-valued': True,
            'default': None}


PARAMETER = _obj({'value': {**NUMBERS, **REQ}, 'unit': {**_text(None, True), **REQ},
                  'std': {'anyOf': [{'type': 'null'}, NUMBERS], 'title': 'numbers',
                          'x-kind': 'numbers', 'default': None, 'x-nonnegative': True},
                  'description': _text(None, True)},
                 'a mapping with value (numbers) and unit (text)', required=['value', 'unit'])
MODEL = _obj({'kind': {**_text(None, True), 'title': 'a model name', **REQ},
              'sensor': _text(None, True), 'unit': _text(None, True),
              'meta': {'type': ['object', 'null'], 'title': 'a mapping', 'default': None},
              'parameters': {'type': 'object', 'title': 'a non-empty mapping',
                             'minProperties': 1, 'propertyNames': {'type': 'string'},
                             'additionalProperties': PARAMETER, **REQ},
              'temperature_input': {'type': 'array', 'title': 'a list of 3 input indices',
                                    'minItems': 3, 'maxItems': 3,
                                    'items': {'type': 'integer'}, 'default': [0, 0, 0]}},
             'a mapping with kind and parameters', required=['kind', 'parameters'],
             **{'x-optional': True})
SCHEMA = _obj({
    'software': _obj({'version': _text()}),
    'created': _text(),
    'sensor': _obj({'frame_id': _text()}),
    'gravity': _obj({'value': {**NUMBER, 'title': 'a number', 'x-kind': 'number',
                               'default': STANDARD_GRAVITY, 'minimum': GRAVITY_BOUNDS[0],
                               'maximum': GRAVITY_BOUNDS[1],
                               'x-why': 'is not a terrestrial value (9.7..9.9); the file is '
                                        'corrupt or not in m/s^2'},
                     'source': _text()}),
    'temperature': _obj({
        'inputs': {'type': ['array', 'null'], 'title': 'a list', 'default': [], 'items': _obj(
            {'name': {**_text(None), **REQ}, 'topic': _text('imu/temperature'),
             'unit': _text('degC', True)}, 'a mapping with name, topic and unit',
            required=['name'])},
        'valid_range': _obj({'min': {**NUMBERS, **REQ}, 'max': {**NUMBERS, **REQ},
                             'unit': {'anyOf': [{'type': ['string', 'null']}, {
                                 'type': 'array', 'items': {'type': 'string'}}],
                                 'title': 'text or a list of text', 'default': None}},
                            'a mapping with min and max', required=['min', 'max'],
                            **{'x-optional': True}),
        'out_of_range': {'enum': ['clamp', 'extrapolate', 'linear', 'linear_gyro'],
                         'default': 'clamp'},
        'filter': _obj({'kind': _text('lag', True), 'tau_s': {**NUMBERS, **REQ},
                        'unit': _text('s', True),
                        'restart_spread': _obj({'accel': _valued(VEC3),
                                                'gyro': _valued(VEC3)},
                                               **{'x-optional': True})},
                       'a mapping with kind, tau_s and unit',
                       required=['tau_s'], **{'x-optional': True})}),
    'accel': MODEL,
    'gyro': MODEL,
    'noise': _obj({k: _valued(VEC3) for k in (
        'accel_std', 'gyro_std', 'accel_noise_density', 'gyro_noise_density',
        'accel_random_walk', 'gyro_random_walk')}
        | {k: _valued(POSITIVE) for k in ('rate_hz', 'horizon_s')}),
    'fit': {'type': ['object', 'null'], 'title': 'a mapping', 'default': {}},
    'notes': {'type': ['array', 'string', 'null'], 'title': 'a list or text', 'default': [],
              'x-kind': 'notes'},
}, 'the file', **{'$defs': {'numbers': {'anyOf': [NUMBER, {
    'type': 'array', 'items': {'$ref': '#/$defs/numbers'}}]}}})
VALIDATOR = Validator(SCHEMA)


def _path(parts):
    out = ''
    for p in parts:
        out += f'[{p}]' if isinstance(p, int) else (f'.{p}' if out else str(p))
    return out


def message(err):
    """Return the loader's one-line wording of a jsonschema error (without the source)."""
    while err.validator == 'anyOf' and err.context and 'title' not in err.schema:
        err = best_match(err.context)
    path, x, v, sch = _path(err.absolute_path), err.instance, err.validator, err.schema
    got = type_name(x) if x is None else f'{type_name(x)} {short(x)}'
    if v == 'required':
        key = next(k for k in err.validator_value if k not in x)
        return f'{path}.{key} is missing; it must be {sch["properties"][key]["title"]}' \
            .lstrip('.')
    if v == 'enum':
        return f'{path} {short(x)} is not one of {tuple(err.validator_value)}'
    if v == 'finite':
        return f'{path} {short(x)} is not finite (non-finite values are refused)'
    if v in ('minimum', 'maximum', 'exclusiveMinimum'):
        why = sch.get('x-why') or f'must be {"> 0" if v == "exclusiveMinimum" else ">= 0"}'
        return f'{path} {x} {why}'
    return f'{path} must be {sch.get("title", "a " + str(sch.get("type")))}, got {got}'


def _resolve(sch):
    return VALIDATOR.schema['$defs']['numbers'] if sch.get('$ref') else sch


def normalize(sch, x, path=''):
    """Return ``x`` with the schema's defaults filled and text, numbers, arrays converted."""
    if x is None:
        if sch.get('x-optional') or sch.get('x-valued'):
            return None
        x = copy.copy(sch.get('default'))
    if isinstance(x, dict) and sch.get('x-valued'):
        x = x['value']
    kind = sch.get('x-kind') or (sch.get('anyOf', [{}])[1].get('x-kind')
                                 if sch.get('x-valued') else None)
    if x is None or kind is None:
        pass
    elif kind == 'text':
        return str(x)
    elif kind == 'number':
        return float(x)
    elif kind == 'notes':
        return [x] if isinstance(x, str) else [str(n) for n in x]
    elif kind == 'numbers':
        try:
            a = np.asarray(x, float)
        except ValueError:
            raise ValueError(f'{path} is not a regular array of numbers (ragged lists?)') \
                from None
        if sch.get('x-nonnegative') and np.any(a < 0):
            raise ValueError(f'{path} {short(a.tolist())} is negative; it must be >= 0')
        return a
    if isinstance(x, dict) and 'properties' in sch:
        return {k: normalize(s, x.get(k), f'{path}.{k}' if path else k)
                for k, s in sch['properties'].items()}
    if isinstance(x, dict) and 'additionalProperties' in sch:
        return {k: normalize(sch['additionalProperties'], v, f'{path}.{k}')
                for k, v in x.items()}
    if isinstance(x, list) and isinstance(sch.get('items'), dict) and 'properties' in \
            sch['items']:
        return [normalize(sch['items'], v, f'{path}[{j}]') for j, v in enumerate(x)]
    return x


def load(d, source, factory):
    """``calibration.schema.load`` with jsonschema in place of the spec table."""
    schema.check_format(d, source)
    err = best_match(VALIDATOR.iter_errors(d))
    if err is not None:
        raise CalibrationError(f'{source}: {message(err)}')
    try:
        doc, out = normalize(SCHEMA, d), {}
        for model in ('accel', 'gyro'):
            for key, p in ((doc[model] or {}).get('parameters') or {}).items():
                if p['std'] is not None and p['std'].shape != p['value'].shape:
                    raise ValueError(f'{model}.parameters.{key}.std has shape '
                                     f'{p["std"].shape}, value {p["value"].shape}')
        for _, rule in schema.RULES:
            rule(d, doc, out)
        cal = factory(**out)
        plausible.check_thermal_without_inputs(cal)
        plausible.check_output(cal)
    except ValueError as e:
        raise CalibrationError(f'{source}: {short(str(e), 300, False)}') from None
    return cal


def messages(cases):
    """Return {case: message of the jsonschema loader, or 'ACCEPTED'} for [(case, dict)]."""
    from thermal_imu_calib.calibration import Calibration
    out = {}
    for name, d in cases:
        try:
            load(d, 'x.yaml', Calibration)
            out[name] = 'ACCEPTED'
        except CalibrationError as e:
            out[name] = str(e)
    return out
