"""compensator_node with ``registry_dir``: the latest calibration of the IMU's frame_id."""

from conftest import imu_msg, wait_for
import numpy as np

from test_node_compensator import ACCEL, expected, GYRO, make_cal, Rig, T0_NS, vec
from thermal_imu_calib.fleet import registry as reg

DAY = 86400 * 10 ** 9


def test_compensator_picks_latest_calibration_of_its_frame_id(ros, tmp_path):
    old, new, other = make_cal(db0=0.01, frame_id='u07'), make_cal(db0=0.05, frame_id='u07'), \
        make_cal(db0=-0.2, frame_id='u08')
    reg.add(str(tmp_path), [('u07', old, T0_NS - 40 * DAY, T0_NS - 41 * DAY, ['a']),
                            ('u07', new, T0_NS - 10 * DAY, T0_NS - 11 * DAY, ['b']),
                            ('u08', other, T0_NS - 5 * DAY, T0_NS - 6 * DAY, ['c'])])
    rig = Rig(ros, registry_dir=str(tmp_path), calibration_file='')
    assert rig.node.active is None
    rig.temperature(25.0)
    for i in range(5):
        rig.imu_pub.publish(imu_msg(T0_NS + i * 10 ** 7, ACCEL, GYRO, 'u07'))
    wait_for(lambda: len(rig.out) >= 5, 10, '5 compensated messages')
    assert rig.node.active.id == new.id
    exp = expected(new, 25.0)
    for m in rig.out:
        a, w = vec(m)
        np.testing.assert_allclose(a, exp.accel[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(w, exp.gyro[0], rtol=0, atol=1e-12)
        assert m.header.frame_id == 'u07'
    assert not np.allclose(expected(old, 25.0).accel[0], exp.accel[0], atol=1e-3)
