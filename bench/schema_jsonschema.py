"""The calibration file's schema as JSON Schema (jsonschema 4.26): a measured prototype.

Not used by the package: ``schema_messages.py --jsonschema`` prints what this schema says
on each broken field next to the loader's message (docs/architecture.md, "The calibration
file's schema"). What JSON Schema cannot say (a valid_range as long as the inputs, axis
indices below the number of inputs, units that agree, a model's parameter set, plausible
values) would stay hand-written beside it.
"""

import datetime
import math

import jsonschema
from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match

FORMAT = 'thermal_imu_calib/1'


def _finite(validator, value, instance, schema):
    if value and isinstance(instance, float) and not math.isfinite(instance):
        yield jsonschema.ValidationError(f'{instance!r} is not finite')


#: YAML gives dates for unquoted ``created: 2026-11-22``; numbers exclude YAML's booleans
_TYPES = Draft202012Validator.TYPE_CHECKER.redefine(
    'string', lambda c, x: isinstance(x, (str, datetime.date)))
Validator = jsonschema.validators.extend(Draft202012Validator, {'finite': _finite},
                                         type_checker=_TYPES)

TEXT = {'type': ['string', 'number']}
NUMBER = {'type': 'number', 'finite': True}
VEC3 = {'type': 'array', 'items': {'type': 'number', 'finite': True, 'minimum': 0},
        'minItems': 3, 'maxItems': 3}
NOISE_ENTRY = {'anyOf': [VEC3, {'type': 'object', 'required': ['value'],
                                'properties': {'value': VEC3, 'unit': TEXT}}]}
POSITIVE = {'anyOf': [{'type': 'number', 'finite': True, 'exclusiveMinimum': 0},
                      {'type': 'object', 'required': ['value'],
                       'properties': {'value': {'type': 'number', 'finite': True,
                                                'exclusiveMinimum': 0}}}]}
SCHEMA = {
    '$defs': {
        'numbers': {'anyOf': [NUMBER, {'type': 'array', 'items': {'$ref': '#/$defs/numbers'}}]},
        'param': {'type': 'object', 'required': ['value', 'unit'],
                  'properties': {'value': {'$ref': '#/$defs/numbers'},
                                 'std': {'anyOf': [{'type': 'null'},
                                                   {'$ref': '#/$defs/numbers'}]},
                                 'unit': {'type': 'string'},
                                 'description': {'type': ['string', 'null']}}},
        'model': {'type': 'object', 'required': ['kind', 'parameters'],
                  'properties': {
                      'kind': {'type': 'string'}, 'sensor': {'type': 'string'},
                      'unit': {'type': 'string'}, 'meta': {'type': 'object'},
                      'parameters': {'type': 'object', 'minProperties': 1,
                                     'additionalProperties': {'$ref': '#/$defs/param'}},
                      'temperature_input': {'type': 'array', 'minItems': 3, 'maxItems': 3,
                                            'items': {'type': 'integer', 'minimum': 0}}}},
    },
    'type': 'object',
    'required': ['format'],
    'properties': {
        'format': {'const': FORMAT},
        'created': TEXT,
        'software': {'type': 'object', 'properties': {'version': TEXT}},
        'sensor': {'type': 'object', 'properties': {'frame_id': TEXT}},
        'gravity': {'type': 'object', 'properties': {
            'value': {'type': 'number', 'finite': True, 'minimum': 9.7, 'maximum': 9.9},
            'source': TEXT}},
        'temperature': {'type': 'object', 'properties': {
            'inputs': {'type': 'array', 'items': {
                'type': 'object', 'required': ['name'],
                'properties': {'name': TEXT, 'topic': TEXT, 'unit': TEXT}}},
            'valid_range': {'type': 'object', 'required': ['min', 'max'], 'properties': {
                'min': {'type': 'array', 'items': NUMBER},
                'max': {'type': 'array', 'items': NUMBER},
                'unit': {'anyOf': [{'type': 'string'},
                                   {'type': 'array', 'items': {'type': 'string'}}]}}},
            'out_of_range': {'enum': ['clamp', 'extrapolate']},
            'filter': {'type': 'object', 'required': ['tau_s'], 'properties': {
                'kind': {'type': 'string'}, 'unit': {'const': 's'},
                'tau_s': {'type': 'array', 'items': {'type': 'number', 'finite': True,
                                                     'minimum': 0, 'maximum': 86400}}}}}},
        'accel': {'$ref': '#/$defs/model'},
        'gyro': {'$ref': '#/$defs/model'},
        'noise': {'type': 'object', 'properties': {
            'accel_std': NOISE_ENTRY, 'gyro_std': NOISE_ENTRY,
            'accel_noise_density': NOISE_ENTRY, 'gyro_noise_density': NOISE_ENTRY,
            'accel_random_walk': NOISE_ENTRY, 'gyro_random_walk': NOISE_ENTRY,
            'rate_hz': POSITIVE, 'horizon_s': POSITIVE}},
        'fit': {'type': 'object'},
        'notes': {'type': ['array', 'string']},
    },
}
VALIDATOR = Validator(SCHEMA)


def check(d, source='calibration'):
    """Return None, or the one line the loader would print for the best-matching error."""
    err = best_match(VALIDATOR.iter_errors(d))
    if err is None:
        return None
    where = '.'.join(str(p) for p in err.absolute_path) or 'the file'
    return f'{source}: {where}: {err.message}'


def messages(cases):
    """Return {case: 'raw: ... | line: ...' or 'ACCEPTED'} for [(case, dict)]."""
    out = {}
    for name, d in cases:
        err = best_match(VALIDATOR.iter_errors(d))
        out[name] = 'ACCEPTED (left to the hand-written checks)' if err is None else \
            f'{check(d, "x.yaml")}   [validator {err.validator}]'
    return out
