"""Calibrator node over real DDS: a successful ~/calibrate also writes the HTML report."""

from _html_check import parse_report
from conftest import wait_for
import pytest

pytest.importorskip('rclpy')

from test_node_calibrator import calibrator, Player, recording  # noqa: E402

from thermal_imu_calib.report.build import SECTIONS  # noqa: E402


def test_calibrate_writes_the_report_next_to_the_calibration(ros, tmp_path):
    rec = recording(repetitions=1)
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(rec)
    player.wait_received()
    resp = player.call('calibrate')
    assert resp.success, (resp.message, node.counts)
    report = tmp_path / 'calibration.report.html'
    wait_for(lambda: report.exists(), 60, 'the report next to the calibration')
    ids, images = parse_report(report.read_text())
    assert set(SECTIONS) <= set(ids)
    assert {n for n, _ in images} == {'timeline', 'accel', 'gyro', 'gravity_residual',
                                      'coverage'}
