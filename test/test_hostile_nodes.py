"""Issue 9 defects 1, 2 and 8 on the real nodes over DDS: bad calibrations and collections.

The compensator must survive every calibration the probe sent (file, reload, latched
``imu/calibration`` message), reject it naming the field, keep the previous one and keep
compensating; the calibrator must start on a damaged collection file or an unusable
collection directory.
"""

import json
import os

from conftest import imu_msg, temperature_msg, wait_for
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from _hostile import bad_calibrations, good_calibration, recording
from thermal_imu_calib.nodes import common
from thermal_imu_calib.nodes.calibrator import CalibratorNode
from thermal_imu_calib.nodes.compensator import CompensatorNode
from thermal_imu_calib.collection.feed import windows_from_columns

S = 1_000_000_000
T0_NS = 1_700_000_000 * S
BAD = bad_calibrations()
#: what a DDS String can carry (str): every case but raw non-UTF-8 bytes
TEXT_CASES = sorted(k for k, (t, _) in BAD.items() if isinstance(t, str) and k != 'too_large')


def _write(path, data):
    with open(path, 'wb' if isinstance(data, bytes) else 'w') as f:
        f.write(data)
    return str(path)


class Rig:
    """A compensator and a driver node publishing IMU/temperature/calibration messages."""

    def __init__(self, ros, calibration_file=''):
        self.ros = ros
        self.node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
            Parameter('calibration_file', value=calibration_file)]))
        self.driver = ros.node('driver')
        self.imu_pub = self.driver.create_publisher(Imu, 'imu/data_raw', 100)
        self.temp_pub = self.driver.create_publisher(Temperature, 'imu/temperature', 100)
        self.cal_pub = self.driver.create_publisher(String, 'imu/calibration',
                                                    common.CALIBRATION_QOS)
        self.out = ros.collect(self.driver, Imu, 'imu/data_compensated', 100)
        self.diag = ros.collect(self.driver, DiagnosticArray, '/diagnostics', 10)
        ros.wait_matched(self.imu_pub)
        ros.wait_matched(self.temp_pub)
        self.k = 0

    def compensates(self):
        """Publish temperature + IMU until a compensated sample comes back; return it."""
        start = len(self.out)

        def step():
            self.k += 1
            t = T0_NS + self.k * S // 10
            self.temp_pub.publish(temperature_msg(t, 30.0))
            self.imu_pub.publish(imu_msg(t, (0.3, -0.2, 9.7), (0.01, -0.02, 0.005)))
            return len(self.out) > start and self.node.counts['compensated'] > 0
        wait_for(step, 20, 'a compensated sample', poll=0.05)
        return self.out[-1]


@pytest.mark.parametrize('case', sorted(BAD))
def test_compensator_starts_on_any_bad_calibration_file(case, ros, tmp_path):
    data, field = BAD[case]
    rig = Rig(ros, _write(tmp_path / 'cal.yaml', data))
    node = rig.node
    assert node.active is None and node.counts['calibrations_rejected'] == 1
    assert field in node.last_rejection, node.last_rejection
    # still serving: ~/reload with the same bad file is rejected again, not fatal
    resp = ros.call(rig.driver, Trigger, f'/{node.get_name()}/reload')
    assert not resp.success and field in resp.message
    _write(tmp_path / 'cal.yaml', good_calibration().to_yaml())
    assert ros.call(rig.driver, Trigger, f'/{node.get_name()}/reload').success


def test_compensator_survives_every_bad_calibration_message(ros, tmp_path):
    good = good_calibration()
    rig = Rig(ros, _write(tmp_path / 'cal.yaml', good.to_yaml()))
    node = rig.node
    assert node.active is not None and node.active.id == good.id
    ref = rig.compensates()
    for i, case in enumerate(TEXT_CASES, start=1):
        data, field = BAD[case]
        rig.cal_pub.publish(String(data=data))
        wait_for(lambda: node.counts['calibrations_rejected'] >= i, 20,
                 lambda: f'rejection {i} ({case}); {node.counts}')
        assert field in node.last_rejection, (case, node.last_rejection)
        assert node.active.id == good.id
    out = rig.compensates()
    assert out.linear_acceleration.z == pytest.approx(ref.linear_acceleration.z, abs=1e-3)
    wait_for(lambda: any(kv.key == 'last_rejection' and kv.value
                         for a in rig.diag for s in a.status for kv in s.values), 10,
             'the rejection in /diagnostics')


@pytest.mark.parametrize('case', ['alias_bomb_fit', 'nested_100000', 'meta_garbage'])
def test_latched_bad_calibration_does_not_crash_loop(case, ros):
    # the latched message is there before the node starts (the probe's crash loop)
    driver = ros.node('latcher')
    pub = driver.create_publisher(String, 'imu/calibration', common.CALIBRATION_QOS)
    pub.publish(String(data=BAD[case][0]))
    rig = Rig(ros)
    wait_for(lambda: rig.node.counts['calibrations_rejected'] >= 1, 20,
             'the latched calibration rejected')
    assert rig.node.active is None
    rig.cal_pub.publish(String(data=good_calibration().to_yaml()))
    wait_for(lambda: rig.node.active is not None, 20, 'a good calibration after the bad one')
    rig.compensates()
    assert pub.topic_name


# ------------------------------------------------------------------ calibrator (defect 8)
@pytest.fixture(scope='module')
def records():
    imu, temp = recording(4)
    from thermal_imu_calib.io.columns import ImuColumns
    chunks = [ImuColumns(imu.stamp_ns[i:i + 5000], imu.accel[i:i + 5000],
                         imu.gyro[i:i + 5000]) for i in range(0, len(imu), 5000)]
    win = windows_from_columns(chunks, [temp])
    assert len(win) > 4
    return win.to_jsonl().splitlines()


def _calibrator(ros, path):
    return ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('collection_file', value=str(path)),
        Parameter('calibration_file', value=str(os.path.dirname(str(path))) + '/cal.yaml')]))


def test_calibrator_skips_bad_records_and_keeps_the_rest(ros, tmp_path, records):
    missing = json.loads(records[1])
    del missing['temp']
    lines = ([records[0].encode(), json.dumps(missing).encode(), b'{"t0": \xff\xfe}']
             + [r.encode() for r in records[2:]])
    path = tmp_path / 'collection.jsonl'
    path.write_bytes(b'\n'.join(lines) + b'\n')
    node = _calibrator(ros, path)
    assert len(node.windows) == len(records) - 1
    # the file now holds exactly the readable records
    assert len(path.read_text().splitlines()) == len(records) - 1


def test_calibrator_starts_on_a_non_utf8_collection(ros, tmp_path):
    path = tmp_path / 'collection.jsonl'
    path.write_bytes(b'\xff\xfe\x00garbage\n\x80\x81\n')
    node = _calibrator(ros, path)
    assert len(node.windows) == 0
    assert any(n.startswith('collection.jsonl.incompatible') for n in os.listdir(tmp_path))


def test_calibrator_starts_with_an_unwritable_collection_dir(ros, tmp_path):
    node = _calibrator(ros, '/proc/thermal_imu_calib_no_such_dir/collection.jsonl')
    assert node._collection_error
    # it still collects (in memory) and answers its services
    driver = ros.node('driver')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 100)
    temp_pub = driver.create_publisher(Temperature, 'imu/temperature', 100)
    ros.wait_matched(imu_pub)
    k = [0]

    def step():
        k[0] += 1
        t = T0_NS + k[0] * S // 100
        if k[0] % 10 == 0:
            temp_pub.publish(temperature_msg(t, 25.0))
        imu_pub.publish(imu_msg(t, (0.0, 0.0, 9.8), (0.0, 0.0, 0.0)))
        return node.counts['samples'] > 0
    wait_for(step, 20, 'samples collected in memory', poll=0.005)
    resp = ros.call(driver, Trigger, f'/{node.get_name()}/reset')
    assert resp is not None
    assert np.isfinite(node.counts['samples'])
