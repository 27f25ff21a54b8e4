"""Docstring linter as a test (ament_pep257 equivalent)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.linter
def test_pep257():
    r = subprocess.run([sys.executable, '-m', 'pydocstyle', 'thermal_imu_calib'], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, f'pydocstyle found problems:\n{r.stdout}{r.stderr}'
