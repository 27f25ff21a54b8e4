"""Nodes with a thermal proxy input over real DDS: the gyro follows a resonance frequency.

The compensator subscribes a die temperature (degC) and the gyro's resonance frequency (Hz,
in sensor_msgs/Temperature or FluidPressure), compensates with the core's result, and
refuses a calibration whose input units are not what ``temperature_units`` says. The
calibrator writes the units of ``temperature_units`` into its calibration.
"""

from conftest import imu_msg, temperature_msg, wait_for
import numpy as np
import pytest

from rclpy.parameter import Parameter
from sensor_msgs.msg import FluidPressure, Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from test_proxy_inputs import PROXY, proxy_cal
from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.nodes import common
from thermal_imu_calib.nodes.calibrator import CalibratorNode
from thermal_imu_calib.nodes.compensator import CompensatorNode

S = 1_000_000_000
T0_NS = 1_700_000_000 * S
ACCEL, GYRO = (0.3, -0.2, 9.7), (0.01, -0.02, 0.005)
TOPICS = ['imu/temperature', PROXY.lstrip('/')]


def scalar_msg(cls, stamp_ns, value):
    """Build a header-stamped scalar of ``cls`` (value field per common.SCALAR_TYPES)."""
    if cls is Temperature:
        return temperature_msg(stamp_ns, value)
    m = cls()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), S)
    m.fluid_pressure = float(value)
    return m


def compensator(ros, tmp_path, cal, **params):
    """Start a compensator on TOPICS with ``cal`` as its file; return (node, driver)."""
    path = cal.save(tmp_path / 'cal.yaml')
    params = {'calibration_file': str(path), 'temperature_topics': TOPICS, **params}
    node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]))
    return node, ros.node('driver')


@pytest.mark.parametrize('proxy_type', [Temperature, FluidPressure])
def test_compensator_follows_the_proxy_topic(ros, tmp_path, proxy_type):
    cal = proxy_cal()
    types = ['sensor_msgs/msg/Temperature',
             'sensor_msgs/msg/' + proxy_type.__name__]
    node, drv = compensator(ros, tmp_path, cal, temperature_units=['degC', 'Hz'],
                            temperature_types=types)
    assert node.active is not None and node.active.id == cal.id
    imu_pub = drv.create_publisher(Imu, 'imu/data_raw', 1000)
    die_pub = drv.create_publisher(Temperature, TOPICS[0], 100)
    f_pub = drv.create_publisher(proxy_type, TOPICS[1], 100)
    out = ros.collect(drv, Imu, 'imu/data_compensated', 1000)
    for pub in (imu_pub, die_pub, f_pub):
        ros.wait_matched(pub)
    wait_for(lambda: node.pub.get_subscription_count() >= 1, 10, 'output subscriber')
    die_pub.publish(temperature_msg(T0_NS, 31.0))
    f_pub.publish(scalar_msg(proxy_type, T0_NS, 24962.5))
    wait_for(lambda: min(node.temps.received) >= 1, 10, 'both thermal inputs')
    for i in range(5):
        imu_pub.publish(imu_msg(T0_NS + i * S // 100, ACCEL, GYRO))
    wait_for(lambda: len(out) >= 5, 10, '5 compensated messages')
    want = cal.apply(np.array([ACCEL]), np.array([GYRO]), np.array([[31.0, 24962.5]]))
    for m in out:
        w = m.angular_velocity
        np.testing.assert_allclose([w.x, w.y, w.z], want.gyro[0], rtol=0, atol=1e-12)
        a = m.linear_acceleration
        np.testing.assert_allclose([a.x, a.y, a.z], want.accel[0], rtol=0, atol=1e-12)
    # the gyro correction used the frequency: 7.5 Hz above X0, not 31 degC
    x = 24962.5 - 24955.0
    np.testing.assert_allclose(want.gyro[0], np.array(GYRO) - (1e-3 - 2e-4 * x + 1e-6 * x * x))
    assert node.counts['compensated'] == 5 and node.counts['clamped'] == 0


def test_compensator_refuses_a_calibration_in_other_units(ros, tmp_path):
    # configured as two degC inputs: the Hz calibration is refused at start, with the reason
    node, drv = compensator(ros, tmp_path, proxy_cal(), temperature_units=['degC'])
    assert node.active is None and node.counts['calibrations_rejected'] == 1
    assert (f'{PROXY} is in Hz in the calibration but degC here' in node.last_rejection
            and 'set temperature_units' in node.last_rejection)
    ros.remove(node)
    # configured for the proxy: a calibration arriving with the second input in degC is
    # refused and the proxy calibration stays active
    node, drv = compensator(ros, tmp_path, proxy_cal(), temperature_units=['degC', 'Hz'])
    good = node.active.id
    wrong = Calibration(
        gyro=OffsetPolynomialModel([30.0] * 3, [[1e-3] * 3], 'gyro'),
        inputs=[TemperatureInput('die', TOPICS[0]),
                TemperatureInput('gyro_temperature', PROXY, 'degC')],
        valid_range=np.array([[20.0, 40.0]] * 2), gyro_input=[1, 1, 1])
    pub = drv.create_publisher(String, 'imu/calibration', common.CALIBRATION_QOS)
    pub.publish(String(data=wrong.to_yaml()))
    wait_for(lambda: node.counts['calibrations_rejected'] >= 1, 10, 'the rejection')
    assert node.active.id == good
    assert 'is in degC in the calibration but Hz here' in node.last_rejection


def test_bad_unit_parameters_are_refused(ros):
    for units, message in ((['degC', 'K'], 'Kelvin'), (['degC', 'Hz', 'Hz'], '3 entries')):
        with pytest.raises(ValueError, match=message):
            CompensatorNode(context=ros.context, parameter_overrides=[
                Parameter('temperature_topics', value=TOPICS),
                Parameter('temperature_units', value=units),
                Parameter('calibration_file', value='')])


def test_calibrator_writes_the_proxy_units(ros, tmp_path):
    from thermal_imu_calib import sim
    from thermal_imu_calib.collection.feed import windows_from_columns
    from thermal_imu_calib.sim.proxy import with_resonance_proxy
    rec = with_resonance_proxy(sim.simulate('demo', 6))
    windows = windows_from_columns(rec.imu_chunks(), [rec.temperatures['/imu/temperature'],
                                                      rec.temperatures[PROXY]])
    path = tmp_path / 'out.yaml'
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('temperature_topics', value=TOPICS),
        Parameter('temperature_units', value=['degC', 'Hz']),
        Parameter('calibration_file', value=str(path)),
        Parameter('collection_file', value='')]))
    assert [i.unit for i in node.options().inputs] == ['degC', 'Hz']
    with node._lock:
        node.windows = windows
    res = ros.call(ros.node('client'), Trigger, '/thermal_imu_calibrator/calibrate')
    assert res.success, res.message
    assert ' Hz' in res.message
    cal = Calibration.load(path)
    assert cal.input_units == ['degC', 'Hz'] and cal.gyro_input == [1, 1, 1]
    # the gyro's first-order thermal coefficient is per Hz, whichever gyro model was chosen
    # (bias polynomial: c1; seed 002 static model, chosen by the default gyro choice: its
    # offset stem with index 1)
    units = {n: p.unit for n, p in cal.gyro.params().items()}
    first = 'c1' if 'c1' in units else f'{cal.gyro.stems[0]}1'
    assert units[first] == 'rad/s/Hz', (cal.gyro.kind, units)
