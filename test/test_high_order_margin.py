"""``high_order_margin``: a model above first order in temperature gets its own margin."""

import dataclasses
import math

import numpy as np
import pytest

from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.estimation.options import (CalibrateOptions, narrow_high_order,
                                                  valid_range)
from thermal_imu_calib.models.base import SensorModel
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.models.rvm import RvmModel
from thermal_imu_calib.models.whole_unit import WholeUnitAccelModel


@dataclasses.dataclass
class _Windows:
    temp: np.ndarray

    @property
    def n_inputs(self):
        return self.temp.shape[1]

    def __len__(self):
        return len(self.temp)


def _poly(degree, sensor):
    c = np.zeros((4, 3))
    c[:degree + 1, 1] = 1e-3
    return OffsetPolynomialModel(np.full(3, 5.0), c, sensor=sensor)


def test_temperature_degree_of_each_family():
    assert [_poly(d, 'accel').temperature_degree() for d in range(4)] == [0, 1, 2, 3]
    th = np.zeros((3, 6))
    assert FieldPolynomialModel(np.zeros(3), th).temperature_degree() == 0
    th[1, 4] = 1e-4
    assert FieldPolynomialModel(np.zeros(3), th).temperature_degree() == 1
    th[0, 2] = 1e-6
    assert FieldPolynomialModel(np.zeros(3), th).temperature_degree() == 2
    off = np.zeros((3, 3))
    off[1, 2] = 1e-3
    assert WholeUnitAccelModel(np.zeros(3), off).temperature_degree() == 1
    assert WholeUnitAccelModel(np.zeros(3), off,
                               scale=np.ones((2, 3)) * 1e-5).temperature_degree() == 2
    # kernels are not a polynomial in temperature: the base's answer, infinite
    assert RvmModel.temperature_degree is SensorModel.temperature_degree
    assert math.isinf(SensorModel.temperature_degree(None))


def _cal(accel_degree, gyro_degree, windows, options):
    return Calibration(accel=_poly(accel_degree, 'accel'), gyro=_poly(gyro_degree, 'gyro'),
                       inputs=[TemperatureInput('t', '/t', 'degC')],
                       valid_range=valid_range(windows, options))


def test_only_models_above_first_order_are_narrowed():
    w = _Windows(np.array([[4.7], [6.0], [7.4]]))
    off = CalibrateOptions(range_margin=1.0, high_order_margin=None, high_order_sensors='both')
    on = dataclasses.replace(off, high_order_margin=0.0)
    cal = _cal(3, 1, w, off)
    narrow_high_order(cal, w, off)          # off: nothing changes
    assert cal.sensor_range == {} and np.allclose(cal.valid_range, [[3.7, 8.4]])
    cal = _cal(3, 1, w, on)
    narrow_high_order(cal, w, on)           # the cubic accel at the data, the linear gyro not
    assert np.allclose(cal.valid_range, [[3.7, 8.4]])
    assert list(cal.sensor_range) == ['accel']
    assert np.allclose(cal.sensor_range['accel'], [[4.7, 7.4]])
    # applied: beyond the data the cubic is held at the data's edge, the gyro goes on
    temps = np.array([[7.4], [8.4]])
    a, g = np.zeros((2, 3)), np.zeros((2, 3))
    out = cal.apply(a, g, temps)
    assert np.allclose(out.accel[0], out.accel[1])
    assert not np.allclose(out.gyro[0], out.gyro[1])
    cal = _cal(2, 3, w, on)                 # both above first order: the valid range itself
    narrow_high_order(cal, w, on)
    assert cal.sensor_range == {} and np.allclose(cal.valid_range, [[4.7, 7.4]])


def test_one_sensor_only():
    w = _Windows(np.array([[4.7], [6.0], [7.4]]))
    on = CalibrateOptions(range_margin=1.0, high_order_margin=0.0, high_order_sensors='accel')
    cal = _cal(3, 3, w, on)                 # both cubic, only the accelerometer narrowed
    narrow_high_order(cal, w, on)
    assert np.allclose(cal.valid_range, [[3.7, 8.4]])
    assert list(cal.sensor_range) == ['accel']
    with pytest.raises(ValueError, match='high_order_sensors'):
        narrow_high_order(cal, w, dataclasses.replace(on, high_order_sensors='imu'))


def test_the_command_line_and_the_node_set_the_same_options(ros, tmp_path, monkeypatch):
    """``--high-order-margin``/``--high-order-sensors`` and the node's parameters reach
    CalibrateSettings alike; 'off' (node: -1) is None, and a bad value is refused."""
    import argparse
    from rclpy.parameter import Parameter
    from thermal_imu_calib.cli.calibrate import add_calibrate_parser, settings_from_args
    from thermal_imu_calib.nodes.calibrator import CalibratorNode

    ap = argparse.ArgumentParser()
    add_calibrate_parser(ap.add_subparsers(dest='cmd'))

    def cli(*extra):
        s = settings_from_args(ap.parse_args(['calibrate', '-', '-o', '-', *extra]))
        return s.high_order_margin, s.high_order_sensors

    assert cli('--high-order-margin', '0', '--high-order-sensors', 'gyro') == (0.0, 'gyro')
    assert cli('--high-order-margin', 'off')[0] is None
    with pytest.raises(SystemExit):
        ap.parse_args(['calibrate', '-', '-o', '-', '--high-order-margin', 'wide'])
    monkeypatch.setenv('HOME', str(tmp_path))
    for value, sensors, expected in ((0.5, 'accel', 0.5), (-1.0, 'both', None)):
        node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
            Parameter('temperature_topics', value=['']),
            Parameter('high_order_margin', value=value),
            Parameter('high_order_sensors', value=sensors)], node_name=f'hom{len(sensors)}'))
        s = node.settings()
        assert (s.high_order_margin, s.high_order_sensors) == (expected, sensors)
    refused = node.set_parameters([Parameter('high_order_margin', value=-0.5)])[0]
    assert not refused.successful and 'high_order_margin' in refused.reason
