"""Calibrator node over real DDS: a successful ~/calibrate also writes the HTML report."""

import glob
import os
import tempfile

from _html_check import parse_report
from conftest import wait_for
import pytest

pytest.importorskip('rclpy')

from test_node_calibrator import calibrator, Player, recording  # noqa: E402

from thermal_imu_calib.report.build import SECTIONS  # noqa: E402

#: bound of a wait for the report child (a process drawing five matplotlib figures): 60 s
#: was passed once on a 2-core machine running a clean-clone make test next to a Dask fleet
#: bench; reached only when something is broken
REPORT_WAIT = 240.0


def _calibrated(ros, tmp_path):
    """Return a calibrator node that has just calibrated a one-repetition recording."""
    node = calibrator(ros, tmp_path)
    player = Player(ros)
    player.play(recording(repetitions=1))
    player.wait_received()
    resp = player.call('calibrate')
    assert resp.success, (resp.message, node.counts)
    return node


def test_calibrate_writes_the_report_next_to_the_calibration(ros, tmp_path):
    _calibrated(ros, tmp_path)
    report = tmp_path / 'calibration.report.html'
    wait_for(lambda: report.exists(), REPORT_WAIT, 'the report next to the calibration')
    ids, images = parse_report(report.read_text())
    assert set(SECTIONS) <= set(ids)
    assert {n for n, _ in images} == {'timeline', 'accel', 'gyro', 'gravity_residual',
                                      'coverage'}


def test_finish_stops_a_report_being_drawn_and_removes_its_inputs(ros, tmp_path):
    """On the way out (SIGINT/SIGTERM) the report child is stopped, nothing is left behind."""
    node = _calibrated(ros, tmp_path)
    wait_for(lambda: (node._report_running or [None])[0] is not None, REPORT_WAIT,
             'the report child drawing')
    child, tmp = node._report_running
    node.finish()
    assert child.poll() is not None                  # stopped, not left drawing
    wait_for(lambda: not os.path.exists(tmp), 10, f'{tmp} removed')
    assert not (tmp_path / 'calibration.report.html').exists()
    assert sorted(p.name for p in tmp_path.iterdir()
                  if 'report' in p.name) == [], list(tmp_path.iterdir())


def test_no_report_child_starts_after_finish(ros, tmp_path):
    """A report queued or being prepared when the node finishes never starts its child."""
    node = _calibrated(ros, tmp_path)
    report = tmp_path / 'calibration.report.html'
    wait_for(lambda: report.exists(), REPORT_WAIT, 'the first report')
    report.unlink()
    node.finish()
    before = set(glob.glob(os.path.join(tempfile.gettempdir(), 'thermal-imu-report-*')))
    node._report_file(node._result.calibration, node.windows)     # what the thread would run
    assert node._report_running is None
    assert not report.exists()
    # no temporary is made once the node has finished (it is made and recorded under the
    # lock that finish() takes, so finish() removes any made before it)
    after = set(glob.glob(os.path.join(tempfile.gettempdir(), 'thermal-imu-report-*')))
    assert after <= before, sorted(after - before)


def test_the_report_inputs_are_written_before_finish_can_remove_them(ros, tmp_path):
    """finish() waits while the report's inputs are being written, then removes them.

    Written outside the report lock, finish() removed the temporary while the calibration
    was being saved into it; the save made the directory again and a node exiting then left
    ``thermal-imu-report-*/.cal.yaml.*.partial`` behind (seen after a live scoreboard run).
    """
    import threading
    node = _calibrated(ros, tmp_path)
    report = tmp_path / 'calibration.report.html'
    wait_for(lambda: report.exists(), REPORT_WAIT, 'the first report')
    cal, saving, go, where = node._result.calibration, threading.Event(), threading.Event(), []

    class SlowSave:
        """The calibration, saved only once the test says so."""

        def save(self, path):
            where.append(os.path.dirname(path))
            saving.set()
            assert go.wait(REPORT_WAIT)
            return cal.save(path)
    writer = threading.Thread(target=node._report_file, args=(SlowSave(), node.windows))
    writer.start()
    assert saving.wait(REPORT_WAIT)
    stopper = threading.Thread(target=node._stop_report)
    stopper.start()
    stopper.join(timeout=1.0)
    assert stopper.is_alive(), 'finish() removed the report inputs while they were written'
    go.set()
    writer.join(timeout=REPORT_WAIT)
    stopper.join(timeout=REPORT_WAIT)
    assert not writer.is_alive() and not stopper.is_alive()
    assert not os.path.exists(where[0])                 # removed by _stop_report
    assert node._report_running is None
