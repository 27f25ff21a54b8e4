"""The calibration file's schema: every field it declares is checked, and named when wrong.

The schema is a table (``calibration/schema.py``); these tests walk that table, so a field
added to it is tested without a line here: each field given a value of the wrong type is
refused with one CalibrationError that names the file and the field's path and says what
it must be. A file with every optional section round trips unchanged.
"""

import copy
import dataclasses
import re

import numpy as np
import pytest
import yaml

from _hostile import good_calibration
from thermal_imu_calib.calibration import Calibration, CalibrationError
from thermal_imu_calib.calibration import schema, spec
from thermal_imu_calib.thermal_input import ThermalFilter


def full_calibration():
    """Return a valid calibration with every optional section of the file filled."""
    good = good_calibration()
    vr = good.valid_range
    return dataclasses.replace(
        good,
        sensor_range={'accel': vr.copy(), 'gyro': np.stack([vr[:, 0] + 1.0, vr[:, 1]], 1)},
        noise_model={'accel_noise_density': np.array([1e-4] * 3),
                     'gyro_noise_density': np.array([1e-5] * 3),
                     'accel_random_walk': np.array([1e-6] * 3),
                     'gyro_random_walk': np.array([1e-7] * 3), 'rate_hz': 100.0,
                     'horizon_s': 3600.0},
        temperature_filter=ThermalFilter(np.array([120.0]), restart_spread={
            'accel': [1e-3, 2e-3, 3e-3], 'gyro': [1e-4, 2e-4, 3e-4]}),
        gyro_ageing={'rate': np.array([1e-6, -2e-6, 3e-7]), 'epoch': 1.7e9, 'max_days': 5.0},
        created='2026-11-27T00:00:00+00:00')


#: a value of the wrong type for each kind of field
WRONG = {spec.Text: [1], spec.Number: 'x', spec.Numbers: 'x', spec.Choice: 5,
         spec.Indices: 'x', spec.Mapping: 'x', spec.MapOf: [1, 2], spec.ListOf: 7,
         spec.TextOrList: 5, spec.FreeForm: 7, spec.Notes: 5}


def _fields(node, path, doc):
    """Yield (path, keys into the document, spec) for every field under ``node``.

    A list is entered at its first item, a mapping of names (parameters) at its first name
    present in the document ``doc``.
    """
    if isinstance(node, spec.Mapping):
        for key, sub in node.fields.items():
            p = f'{path}.{key}' if path else key
            if isinstance(sub, spec.Valued):        # {value: ..., unit: ...}
                yield f'{p}.value', (key, 'value'), sub.item
                continue
            yield p, (key,), sub
            inner = doc.get(key) if isinstance(doc, dict) else None
            for q, keys, leaf in _fields(sub, p, inner):
                yield q, (key,) + keys, leaf
    elif isinstance(node, spec.ListOf) and doc:
        for q, keys, leaf in _fields(node.item, f'{path}[0]', doc[0]):
            yield q, (0,) + keys, leaf
    elif isinstance(node, spec.MapOf) and doc:
        name = next(iter(doc))
        for q, keys, leaf in _fields(node.item, f'{path}.{name}', doc[name]):
            yield q, (name,) + keys, leaf


GOOD = full_calibration().to_dict()
FIELDS = list(_fields(schema.SCHEMA, '', GOOD))


def test_the_walk_covers_every_section_of_the_file():
    paths = {p for p, _, _ in FIELDS}
    for p in ('temperature.inputs[0].unit', 'temperature.valid_range.max',
              'temperature.filter.tau_s', 'temperature.filter.restart_spread.gyro.value',
              'accel.parameters.T0.std', 'gyro.temperature_input',
              'noise.gyro_random_walk.value', 'noise.horizon_s.value', 'gravity.value', 'fit',
              'notes', 'created', 'software.version', 'sensor.frame_id', 'accel.meta',
              'gyro_ageing.max_days.value'):
        assert p in paths, p
    assert len(FIELDS) >= 40


@pytest.mark.parametrize('path, keys, field', FIELDS, ids=[p for p, _, _ in FIELDS])
def test_a_wrong_type_in_any_field_is_refused_naming_it(path, keys, field):
    d = copy.deepcopy(GOOD)
    node = d
    for k in keys[:-1]:
        node = node.setdefault(k, {}) if isinstance(node, dict) else node[k]
    node[keys[-1]] = WRONG[type(field)]
    with pytest.raises(CalibrationError) as e:
        Calibration.from_dict(yaml.safe_load(yaml.safe_dump(d)), 'x.yaml')
    msg = str(e.value)
    assert msg.startswith(f'x.yaml: {path}'), msg
    assert 'must be' in msg or 'is not one of' in msg, msg
    assert 'Error' not in msg and '\n' not in msg, msg        # no exception names, one line


@pytest.mark.parametrize('path, keys, field',
                         [f for f in FIELDS if f[2].default is spec.REQUIRED],
                         ids=[p for p, _, s in FIELDS if s.default is spec.REQUIRED])
def test_a_missing_required_field_is_named(path, keys, field):
    d = copy.deepcopy(GOOD)
    node = d
    for k in keys[:-1]:
        node = node[k]
    node.pop(keys[-1])
    with pytest.raises(CalibrationError, match=f'^x.yaml: {re.escape(path)} is missing; it '
                       'must be'):
        Calibration.from_dict(d, 'x.yaml')


def test_every_optional_section_round_trips_unchanged(tmp_path):
    cal = full_calibration()
    text = cal.to_yaml()
    back = Calibration.from_yaml(text)
    assert back.to_yaml() == text and back.id == cal.id
    assert list(back.noise_model) == list(cal.noise_model)
    cal.save(tmp_path / 'c.yaml')
    assert Calibration.load(tmp_path / 'c.yaml').to_yaml() == text


@pytest.mark.parametrize('edit, message', [
    # cases the hand-written checks reported as a Python error before the schema
    (lambda d: d['temperature']['inputs'][0].pop('name'),
     'temperature.inputs\\[0\\].name is missing'),
    (lambda d: d['temperature']['valid_range'].update(unit=5),
     'temperature.valid_range.unit must be text or a list of text, got a number 5'),
    (lambda d: d['noise']['rate_hz'].update(value='x'),
     'noise.rate_hz.value must be a number, got text'),
    (lambda d: d['noise']['horizon_s'].update(value=[1.0]),
     'noise.horizon_s.value must be a number, got a list'),
    (lambda d: d['temperature']['filter'].update(tau_s='abc'),
     'temperature.filter.tau_s must be numbers'),
    # a unit given as a number is refused where it is, not as a unit mismatch later
    (lambda d: d['temperature']['inputs'][0].update(unit=5),
     'temperature.inputs\\[0\\].unit must be text, got a number 5'),
])
def test_refusals_name_the_field_instead_of_a_python_error(edit, message):
    d = copy.deepcopy(GOOD)
    edit(d)
    with pytest.raises(CalibrationError, match=message) as e:
        Calibration.from_dict(d, 'x.yaml')
    assert 'Error' not in str(e.value)
