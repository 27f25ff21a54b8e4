"""Hostile inputs shared by the hostile-input tests: bags with edited columns, bad calibrations.

``write_bag`` writes a real log (io.bag.LogWriter) from a simulated recording whose IMU and
temperature columns an ``edit`` callable may change; log times stay the original, increasing
stamps, so header stamps may be broken (all 0, running backwards) as a real driver might.
"""

import copy

import numpy as np

from thermal_imu_calib import sim
from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag_writer import LogWriter
from thermal_imu_calib.io.cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

IMU_TOPIC, TEMP_TOPIC = '/imu/data_raw', '/imu/temperature'


def recording(seed=3):
    """Return (imu ImuColumns, temperature TemperatureColumns) of the short demo scenario."""
    rec = sim.simulate('demo', seed, repetitions=1)
    return rec.imu(), rec.temperatures[TEMP_TOPIC]


def write_bag(path, imu, temp, edit=None, storage='mcap'):
    """Write ``imu``/``temp`` (copied, then ``edit(arrays)`` in place) to a log at ``path``.

    ``arrays`` is a dict with stamp_ns, accel, gyro, temp_stamp_ns, temperature; ``edit``
    may also replace them by arrays of other lengths.
    """
    a = {'stamp_ns': imu.stamp_ns.copy(), 'accel': imu.accel.copy(), 'gyro': imu.gyro.copy(),
         'temp_stamp_ns': temp.stamp_ns.copy(), 'temperature': temp.temperature.copy()}
    log_imu, log_temp = imu.stamp_ns.copy(), temp.stamp_ns.copy()
    if edit is not None:
        edit(a)
    n, m = len(a['stamp_ns']), len(a['temp_stamp_ns'])
    if len(log_imu) != n:
        log_imu = np.arange(n, dtype=np.int64) * 10_000_000 + 1
    if len(log_temp) != m:
        log_temp = np.arange(m, dtype=np.int64) * 100_000_000 + 1
    imu_raw = cdr.encode_imu(ImuColumns(a['stamp_ns'], a['accel'], a['gyro'], 'imu_link'))
    temp_raw = cdr.encode_temperature(TemperatureColumns(a['temp_stamp_ns'], a['temperature']))
    msgs = sorted([(int(t), 0, i) for i, t in enumerate(log_imu)]
                  + [(int(t), 1, i) for i, t in enumerate(log_temp)])
    with LogWriter(path, storage) as w:
        w.add_topic(IMU_TOPIC, IMU_MSGTYPE)
        w.add_topic(TEMP_TOPIC, TEMPERATURE_MSGTYPE)
        for t, kind, i in msgs:
            if kind == 0:
                w.write(IMU_TOPIC, t, imu_raw[i])
            else:
                w.write(TEMP_TOPIC, t, temp_raw[i])
    return path


def clean_pair(d, rec, *calibrate_args):
    """Write ``rec`` as d/clean.mcap and calibrate it to d/clean.yaml; return both paths."""
    from thermal_imu_calib.cli import main
    bag = write_bag(str(d / 'clean.mcap'), *rec)
    cal = str(d / 'clean.yaml')
    assert main(['calibrate', bag, '-o', cal, *calibrate_args]) == 0
    return bag, cal


def edited(d, *path_value):
    """Return a deep copy of the mapping ``d`` with ``path -> value`` set (path: tuple of keys)."""
    d = copy.deepcopy(d)
    for path, value in zip(path_value[::2], path_value[1::2]):
        x = d
        for key in path[:-1]:
            x = x[key]
        x[path[-1]] = value
    return d


ALIAS_BOMB = '\n'.join(
    ['a0: &a0 [x, x, x, x, x, x, x, x, x, x]']
    + [f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * 10) + ']' for i in range(1, 10)])


def good_calibration():
    """Return a small valid field + offset calibration on imu/temperature (20..40 degC)."""
    from thermal_imu_calib.calibration import Calibration, TemperatureInput
    from thermal_imu_calib.models.field import FieldPolynomialModel
    from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
    th = np.zeros((3, 6))
    th[:, 0], th[:, 1], th[:, 3], th[:, 4] = 2e-3, -5e-5, 0.05, 2e-3
    return Calibration(
        accel=FieldPolynomialModel([30.0] * 3, th, thermal_std=np.full((3, 6), 1e-6)),
        gyro=OffsetPolynomialModel([30.0] * 3, np.array([[1e-3, 1e-4, 0.0]] * 3), 'gyro'),
        inputs=[TemperatureInput('t0', 'imu/temperature')],
        valid_range=np.array([[20.0, 40.0]]), frame_id='imu_link',
        accel_noise_std=np.array([1e-3, 2e-3, 3e-3]), gyro_noise_std=np.array([1e-4] * 3),
        notes=['a note'], fit={'holds': 3})


def bad_calibrations():
    """Return {case: (text or bytes, the field the rejection must name)} of the probe."""
    import yaml
    good = good_calibration().to_dict()

    def dump(d):
        return yaml.safe_dump(d, sort_keys=False)
    text = dump(good)
    k2 = len(good['accel']['parameters']['k2']['value'])
    return {
        'temperature_garbage': (dump(edited(good, ('temperature',), 'garbage')),
                                'temperature'),
        'meta_garbage': (dump(edited(good, ('accel', 'meta'), 'garbage')), 'accel.meta'),
        'non_utf8': (text.encode() + b'\nnotes: [caf\xe9]\n', 'UTF-8'),
        'nested_100000': (text + 'fit: ' + '[' * 100_000 + ']' * 100_000 + '\n', 'nested'),
        'alias_bomb_fit': (text.replace('fit:', 'fit_old:') + 'fit:\n'
                           + '\n'.join('  ' + ln for ln in ALIAS_BOMB.splitlines()) + '\n',
                           'expands'),
        'alias_bomb_notes': (text.replace('notes:', 'notes_old:') + 'notes:\n- &n0 [x, x]\n'
                             + ''.join(f'- &n{i} [' + ', '.join([f'*n{i - 1}'] * 10) + ']\n'
                                       for i in range(1, 10)), 'expands'),
        'k2_1e300': (dump(edited(good, ('accel', 'parameters', 'k2', 'value'), [1e300] * k2)),
                     'valid range'),
        'gravity_nan': (dump(edited(good, ('gravity', 'value'), float('nan'))), 'gravity'),
        'noise_std_nan': (dump(edited(good, ('noise', 'accel_std', 'value'),
                                      [float('nan')] * 3)), 'noise.accel_std'),
        'param_std_nan': (dump(edited(good, ('accel', 'parameters', 'k1', 'std'),
                                      [float('nan')] * 3)), 'k1.std'),
        'temperature_input_garbage': (dump(edited(good, ('gyro', 'temperature_input'), 'x')),
                                      'gyro.temperature_input'),
        'inputs_not_a_list': (dump(edited(good, ('temperature', 'inputs'), 7)),
                              'temperature.inputs'),
        'parameters_list': (dump(edited(good, ('gyro', 'parameters'), [1, 2])),
                            'gyro.parameters'),
        'value_strings': (dump(edited(good, ('accel', 'parameters', 'b1', 'value'),
                                      ['a', 'b', 'c'])), 'accel.parameters.b1'),
        'top_level_list': ('[1, 2, 3]\n', 'mapping'),
        'too_large': ('# ' + 'x' * (5 * 2 ** 20) + '\n' + text, 'too large'),
    }
