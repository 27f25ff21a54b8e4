"""colcon builds the package in a temporary workspace with the layout ros2 run/launch need."""

import os
import subprocess

from conftest import venv_env, venv_exe

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_colcon_build_layout():
    venv_exe('colcon')   # fails (not skips) when the install did not bring colcon
    r = subprocess.run(['bash', os.path.join(ROOT, 'scripts', 'colcon_check.sh')], cwd=ROOT,
                       env=venv_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    for exe in ('compensator_node', 'calibrator_node', 'bringup', 'thermal-imu-calib'):
        assert f'ok   install/thermal_imu_calib/lib/thermal_imu_calib/{exe}' in r.stdout
    assert 'launch/thermal_imu_calib.launch.py' in r.stdout
