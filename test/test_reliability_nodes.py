"""Issue 21, nodes: shutdown under load, every service call answered, loop guard, registry units.

Real processes and real rclpy nodes over DDS; every wait is on a condition.
"""

import os
import signal
import subprocess
import threading
import time

from conftest import DOMAIN_ID, imu_msg, venv_env, venv_exe, wait_for
import numpy as np
import pytest

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from test_node_compensator import ACCEL, expected, GYRO, make_cal, Rig, T0_NS, vec
from thermal_imu_calib.fleet import registry as reg
from thermal_imu_calib.nodes.calibrator import CalibratorNode

WAIT = 120.0
DAY = 86400 * 10 ** 9


def _diag_values(rig):
    """Return the newest compensator diagnostics as a dict (None before the first)."""
    for arr in reversed(rig.diag):
        for st in arr.status:
            if 'thermal compensation' in st.name:
                return {kv.key: kv.value for kv in st.values} | {'_level': st.level,
                                                                  '_message': st.message}
    return None


# ------------------------------------------------------------------ calibrator services
def test_twenty_concurrent_calibrate_calls_are_all_answered(ros, tmp_path):
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(tmp_path / 'cal.yaml')),
        Parameter('collection_file', value='')]))
    clients = [ros.node(f'caller{i}').create_client(Trigger, '/thermal_imu_calibrator/calibrate')
               for i in range(20)]
    for c in clients:
        wait_for(c.service_is_ready, WAIT, 'the calibrate service')
    futures = [c.call_async(Trigger.Request()) for c in clients]
    wait_for(lambda: all(f.done() for f in futures), WAIT,
             lambda: f'{sum(f.done() for f in futures)} of 20 answers')
    answers = [f.result() for f in futures]
    assert all(a.message for a in answers)
    assert not any(a.success for a in answers)       # nothing collected: refused, not silent
    assert node.counts['samples'] == 0


@pytest.fixture(scope='module')
def collection_text():
    """Return the windows of a short simulated warm-up (six faces) as a collection file."""
    from thermal_imu_calib import sim
    from thermal_imu_calib.pipeline import windows_from_columns
    rec = sim.simulate('demo', 5, hold_s=(14.0, 15.0), transition_s=(1.5, 2.0), repetitions=1)
    win = windows_from_columns(rec.imu_chunks(), rec.temperatures.values())
    assert len(win) > 0
    return win.to_jsonl()


@pytest.mark.parametrize('case', ['directory', 'read_only_dir', 'fifo'])
def test_calibrate_succeeds_only_when_the_file_is_written(case, ros, tmp_path,
                                                          collection_text):
    (tmp_path / 'collection.jsonl').write_text(collection_text)
    target = tmp_path / 'out' / 'cal.yaml'
    target.parent.mkdir()
    if case == 'directory':
        target.mkdir()
    elif case == 'fifo':
        os.mkfifo(target)
    else:
        target.parent.chmod(0o555)
        if os.access(target.parent, os.W_OK):    # root writes anyway: a read-only file system
            from pathlib import Path
            target = Path('/proc/self/thermal_imu_calib/cal.yaml')
    try:
        node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
            Parameter('calibration_file', value=str(target)),
            Parameter('collection_file', value=str(tmp_path / 'collection.jsonl')),
            Parameter('report', value=False)]))
        assert len(node.windows) > 0
        caller = ros.node('caller')
        published = ros.collect(caller, String, 'imu/calibration', 10)
        resp = ros.call(caller, Trigger, '/thermal_imu_calibrator/calibrate', timeout=WAIT)
        assert not resp.success, resp.message
        assert 'NOT written' in resp.message and 'not published' in resp.message
        assert node._result is not None              # kept for ~/save
        assert published == []
        if case == 'directory':
            assert target.is_dir() and list(target.iterdir()) == []
        if case == 'fifo':
            assert target.is_fifo()
    finally:
        (tmp_path / 'out').chmod(0o755)
