"""Linter as a test, as ROS packages do (ament_flake8 equivalent)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.linter
def test_flake8():
    r = subprocess.run([sys.executable, '-m', 'flake8', 'thermal_imu_calib', 'test', 'bench',
                        'scripts', 'setup.py', 'launch'], cwd=ROOT, capture_output=True,
                       text=True)
    assert r.returncode == 0, f'flake8 found problems:\n{r.stdout}{r.stderr}'
