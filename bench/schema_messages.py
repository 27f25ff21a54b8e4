"""What the calibration loader says on each broken field (issue 23: the schema's measurement).

Breaks one field at a time of a small valid calibration (field-polynomial accel, offset
gyro, one temperature input, noise and an Allan noise model) and prints, per case, the
message of ``Calibration.from_dict`` (or ``ACCEPTED``). With ``--jsonschema`` it also prints
what the JSON Schema of the same file (``schema_jsonschema.py`` beside this file) says about
each case, worded as the loader would print it.

Usage::

    python bench/schema_messages.py [--json OUT.json] [--compare BEFORE.json] [--jsonschema]

``--compare`` prints the cases whose message changed against an earlier run (e.g. made on
the commit before the schema moved). ``--jsonschema`` needs ``pip install jsonschema`` (not
a dependency of the package; the measurement used 4.26.0, and 4.10.3 for the
distribution's version). docs/architecture.md ("The calibration file's schema")
reports the comparison.
"""

import argparse
import ast
import copy
import io
import json
import os
import subprocess
import sys
import tokenize

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

NAN = float('nan')


def good_calibration():
    """Return test/_hostile.py's valid calibration with the noise model and a fixed date."""
    import dataclasses
    sys.path.insert(0, os.path.join(ROOT, 'test'))
    from _hostile import good_calibration as base
    return dataclasses.replace(
        base(), noise_model={'gyro_noise_density': np.array([1e-4] * 3), 'rate_hz': 100.0,
                             'horizon_s': 3600.0},
        created='2026-11-27T00:00:00+00:00')


def _set(path, value):
    def edit(d):
        node = d
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
    return edit


def _pop(path):
    def edit(d):
        node = d
        for key in path[:-1]:
            node = node[key]
        node.pop(path[-1])
    return edit


def _no_thermal(d):
    d['temperature']['inputs'] = []
    d['temperature'].pop('valid_range')


def _neither(d):
    d.pop('accel')
    d.pop('gyro')


def _filt(tau_s, unit='s'):
    return {'kind': 'lag', 'tau_s': tau_s, 'unit': unit}


K1 = ('accel', 'parameters', 'k1')
#: (case, edit of the good file's dict); each breaks one field
CASES = [
    ('top level a list', lambda d: [1, 2, 3]),
    ('format other', _set(('format',), 'other/9')),
    ('format missing', _pop(('format',))),
    ('temperature not a mapping', _set(('temperature',), 'garbage')),
    ('inputs not a list', _set(('temperature', 'inputs'), 7)),
    ('input not a mapping', _set(('temperature', 'inputs', 0), 'x')),
    ('input name missing', _pop(('temperature', 'inputs', 0, 'name'))),
    ('input name a list', _set(('temperature', 'inputs', 0, 'name'), [1])),
    ('input topic a mapping', _set(('temperature', 'inputs', 0, 'topic'), {'a': 1})),
    ('input unit Kelvin', _set(('temperature', 'inputs', 0, 'unit'), 'K')),
    ('input unit a number', _set(('temperature', 'inputs', 0, 'unit'), 5)),
    ('input unit a list', _set(('temperature', 'inputs', 0, 'unit'), ['degC'])),
    ('valid_range missing', _pop(('temperature', 'valid_range'))),
    ('valid_range text', _set(('temperature', 'valid_range'), 'x')),
    ('valid_range.min missing', _pop(('temperature', 'valid_range', 'min'))),
    ('valid_range.min text', _set(('temperature', 'valid_range', 'min'), 'a')),
    ('valid_range.min strings', _set(('temperature', 'valid_range', 'min'), ['a'])),
    ('valid_range.min two values', _set(('temperature', 'valid_range', 'min'), [1.0, 2.0])),
    ('valid_range.max NaN', _set(('temperature', 'valid_range', 'max'), [NAN])),
    ('valid_range min above max', _set(('temperature', 'valid_range', 'min'), [50.0])),
    ('valid_range Kelvin', _set(('temperature', 'valid_range'), {'min': [300.0],
                                                                 'max': [320.0]})),
    ('valid_range.unit other', _set(('temperature', 'valid_range', 'unit'), 'Hz')),
    ('valid_range.unit a number', _set(('temperature', 'valid_range', 'unit'), 5)),
    ('valid_range.unit two', _set(('temperature', 'valid_range', 'unit'), ['degC', 'degC'])),
    ('out_of_range unknown', _set(('temperature', 'out_of_range'), 'wrap')),
    ('out_of_range a number', _set(('temperature', 'out_of_range'), 5)),
    ('filter text', _set(('temperature', 'filter'), 'x')),
    ('filter two tau_s', _set(('temperature', 'filter'), _filt([1.0, 2.0]))),
    ('filter tau_s text', _set(('temperature', 'filter'), _filt('abc'))),
    ('filter unit min', _set(('temperature', 'filter'), _filt([1.0], 'min'))),
    ('filter tau_s NaN', _set(('temperature', 'filter'), _filt([NAN]))),
    ('accel not a mapping', _set(('accel',), 'garbage')),
    ('accel.kind missing', _pop(('accel', 'kind'))),
    ('accel.kind a number', _set(('accel', 'kind'), 5)),
    ('accel.kind unknown', _set(('accel', 'kind'), 'nope')),
    ('accel.sensor gyro', _set(('accel', 'sensor'), 'gyro')),
    ('accel.sensor a number', _set(('accel', 'sensor'), 5)),
    ('accel.unit a number', _set(('accel', 'unit'), 5)),
    ('accel.meta text', _set(('accel', 'meta'), 'garbage')),
    ('gyro.parameters a list', _set(('gyro', 'parameters'), [1, 2])),
    ('accel.parameters empty', _set(('accel', 'parameters'), {})),
    ('accel.parameters key a number', lambda d: d['accel']['parameters'].update(
        {1: {'value': [1.0], 'unit': 'x'}})),
    ('parameter a number', _set(K1, 5)),
    ('parameter value missing', _pop(K1 + ('value',))),
    ('parameter unit a number', _set(K1 + ('unit',), 5)),
    ('parameter value strings', _set(K1 + ('value',), ['a', 'b', 'c'])),
    ('parameter value ragged', _set(K1 + ('value',), [[1.0], [1.0, 2.0]])),
    ('parameter value NaN', _set(K1 + ('value',), [NAN, 0.0, 0.0])),
    ('parameter value wrong shape', _set(K1 + ('value',), [0.0, 0.0])),
    ('parameter std NaN', _set(K1 + ('std',), [NAN] * 3)),
    ('parameter std negative', _set(K1 + ('std',), [-1.0] * 3)),
    ('parameter std wrong shape', _set(K1 + ('std',), [1.0] * 2)),
    ('parameter description a number', _set(K1 + ('description',), 5)),
    ('parameter missing', _pop(K1)),
    ('parameter b0 100 m/s^2', _set(('accel', 'parameters', 'b0', 'value'), [100.0, 0, 0])),
    ('parameter k2 1e300', _set(('accel', 'parameters', 'k2', 'value'), [1e300] * 3)),
    ('temperature_input text', _set(('gyro', 'temperature_input'), 'x')),
    ('temperature_input two', _set(('gyro', 'temperature_input'), [0, 0])),
    ('temperature_input out of range', _set(('gyro', 'temperature_input'), [0, 0, 5])),
    ('temperature_input bools', _set(('gyro', 'temperature_input'), [True, False, False])),
    ('neither accel nor gyro', _neither),
    ('thermal terms without inputs', _no_thermal),
    ('gravity text', _set(('gravity',), 'x')),
    ('gravity.value text', _set(('gravity', 'value'), 'x')),
    ('gravity.value NaN', _set(('gravity', 'value'), NAN)),
    ('gravity.value 20', _set(('gravity', 'value'), 20.0)),
    ('gravity.source a list', _set(('gravity', 'source'), [1])),
    ('noise text', _set(('noise',), 'x')),
    ('noise.accel_std text', _set(('noise', 'accel_std'), 'x')),
    ('noise.accel_std NaN', _set(('noise', 'accel_std', 'value'), [NAN] * 3)),
    ('noise.accel_std two', _set(('noise', 'accel_std', 'value'), [1.0, 2.0])),
    ('noise.accel_std negative', _set(('noise', 'accel_std', 'value'), [-1.0, 0.0, 0.0])),
    ('noise.gyro_noise_density text', _set(('noise', 'gyro_noise_density', 'value'), 'x')),
    ('noise.rate_hz text', _set(('noise', 'rate_hz', 'value'), 'x')),
    ('noise.rate_hz negative', _set(('noise', 'rate_hz', 'value'), -1.0)),
    ('noise.horizon_s a list', _set(('noise', 'horizon_s', 'value'), [1.0])),
    ('fit a list', _set(('fit',), [1])),
    ('notes a number', _set(('notes',), 5)),
    ('notes a mapping', _set(('notes',), {'a': 1})),
    ('sensor text', _set(('sensor',), 'x')),
    ('sensor.frame_id a list', _set(('sensor', 'frame_id'), [1])),
    ('software text', _set(('software',), 'x')),
    ('software.version a mapping', _set(('software', 'version'), {'a': 1})),
    ('created a list', _set(('created',), [1])),
]


def cases():
    """Return [(case, broken dict)] of ``CASES`` applied to the good calibration."""
    good = good_calibration().to_dict()
    out = []
    for name, edit in CASES:
        d = copy.deepcopy(good)
        res = edit(d)
        out.append((name, d if res is None else res))
    return out


def loader_messages():
    """Return {case: message of Calibration.from_dict, or 'ACCEPTED'}."""
    from thermal_imu_calib.calibration import Calibration, CalibrationError
    out = {}
    for name, d in cases():
        try:
            Calibration.from_dict(d, 'x.yaml')
            out[name] = 'ACCEPTED'
        except CalibrationError as e:
            out[name] = str(e)
    return out


def code_lines(src, ranges=None):
    """Count lines with code: not blank, not a comment, not a docstring (within ``ranges``)."""
    doc = set()
    for node in ast.walk(ast.parse(src)):
        body = getattr(node, 'body', None)
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef)) and body and \
                isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                and isinstance(body[0].value.value, str):
            doc.update(range(body[0].lineno, body[0].end_lineno + 1))
    skip = (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
            tokenize.ENDMARKER)
    lines = {n for t in tokenize.generate_tokens(io.StringIO(src).readline)
             if t.type not in skip for n in range(t.start[0], t.end[0] + 1)} - doc
    return len([n for n in lines if ranges is None or any(a <= n <= b for a, b in ranges)])


def ranges_of(src, names):
    """Return the line ranges of the top-level definitions (and class methods) ``names``."""
    out = []
    for node in ast.parse(src).body:
        for n in [node] + [m for m in getattr(node, 'body', []) if isinstance(node, ast.ClassDef)]:
            name = getattr(n, 'name', None) or getattr(getattr(n, 'targets', [None])[0], 'id',
                                                       None)
            if name in names:
                out.append((n.lineno - len(getattr(n, 'decorator_list', [])), n.end_lineno))
    return out


#: what checked the file in calibration.py of 43cdb78 (its YAML text limits and
#: plausibility checks, moved unchanged, are counted apart)
OLD_CHECKS = ['from_dict', '_build', '_type_name', '_short', '_mapping', '_list', '_text',
              '_number', '_numbers', '_check_model_section', '_free_form', '_check_range_units',
              '_noise_model', '_opt_vec', 'GRAVITY_BOUNDS', 'FORMAT', 'OUT_OF_RANGE_POLICIES',
              'NOISE_UNITS']
RULES = ['_at', '_inputs', '_valid_range', '_filter', '_models', '_noise', '_plain_fields',
         'RULES']


def line_counts():
    """Print the code lines of the file's checks: 43cdb78, the own table, jsonschema."""
    old = subprocess.run(['git', 'show', '43cdb78:thermal_imu_calib/calibration.py'], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    print(f'43cdb78 calibration.py: {len(old.splitlines())} lines; the file\'s checks '
          f'{code_lines(old, ranges_of(old, OLD_CHECKS))} code lines')
    pkg = os.path.join(ROOT, 'thermal_imu_calib', 'calibration')
    sch = open(os.path.join(pkg, 'schema.py')).read()
    rules, load = code_lines(sch, ranges_of(sch, RULES)), code_lines(sch, ranges_of(sch, ['load']))
    spec = code_lines(open(os.path.join(pkg, 'spec.py')).read())
    table = code_lines(sch) - rules - load
    print(f'own table: spec.py {spec} + table and imports {table} + RULES {rules} + load {load}'
          f' = {spec + table + rules + load} code lines')
    js = open(os.path.join(HERE, 'schema_jsonschema.py')).read()
    n = code_lines(js) - code_lines(js, ranges_of(js, ['messages']))
    print(f'jsonschema: {n} + RULES {rules} = {n + rules} code lines')
    for f in sorted(os.listdir(pkg)):
        if f.endswith('.py'):
            text = open(os.path.join(pkg, f)).read()
            print(f'  calibration/{f}: {len(text.splitlines())} lines, {code_lines(text)} code')


def main(argv=None):
    """Print the loader's message per case; optionally the library prototypes' too."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--json', help='write {case: message} here')
    ap.add_argument('--compare', help='an earlier --json: print the cases that changed')
    ap.add_argument('--jsonschema', action='store_true', help='also print jsonschema\'s')
    ap.add_argument('--lines', action='store_true', help='print the code line counts only')
    args = ap.parse_args(argv)
    if args.lines:
        line_counts()
        return 0
    msgs = loader_messages()
    protos = []
    if args.jsonschema:
        import schema_jsonschema
        protos.append(('jsonschema', schema_jsonschema.messages(cases())))
    for name, msg in msgs.items():
        print(f'## {name}\n  loader: {msg}')
        for label, other in protos:
            print(f'  {label}: {other[name]}')
    for label, other in protos:
        same = sum(other[k] == msgs[k] for k in msgs)
        print(f'{label}: {same} of {len(msgs)} messages identical to the loader\'s')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(msgs, f, indent=1)
    if args.compare:
        before = json.load(open(args.compare))
        changed = [k for k in msgs if before.get(k) != msgs[k]]
        print(f'\n{len(changed)} of {len(msgs)} messages changed')
        for k in changed:
            print(f'## {k}\n  before: {before.get(k)}\n  after:  {msgs[k]}')
    print(f'{len(msgs)} cases, {sum(m == "ACCEPTED" for m in msgs.values())} accepted')
    return 0


if __name__ == '__main__':
    sys.exit(main())
