"""The report subcommand: text as before, a self-contained HTML page and PNG figures."""

import os

from _html_check import parse_report
import pytest

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main
from thermal_imu_calib.report.build import parameter_rows, SECTIONS

FIGURES = {'timeline', 'accel', 'gyro', 'gravity_residual', 'coverage'}


@pytest.fixture(scope='module')
def calibrated(tmp_path_factory):
    """Return (dir, log, calibration, windows file) of a calibrated demo recording."""
    d = tmp_path_factory.mktemp('report')
    log = str(d / 'demo.mcap')
    sim.write_scenario(log, 'demo', 3)
    cal = str(d / 'cal.yaml')
    win = str(d / 'cal.windows.jsonl')
    assert main(['calibrate', log, '-o', cal, '--save-windows', win]) == 0
    return d, log, cal, win


def test_text_report_is_unchanged_without_html(calibrated, capsys):
    d, _, cal, _ = calibrated
    capsys.readouterr()
    assert main(['report', cal]) == 0
    out = capsys.readouterr().out
    assert out.startswith('calibration ') and 'gravity' in out and 'note:' in out
    assert not list(d.glob('*.html'))


def test_html_from_log_has_every_section_and_decodable_figures(calibrated, tmp_path):
    _, log, cal, _ = calibrated
    out, png = tmp_path / 'r.html', tmp_path / 'png'
    assert main(['report', cal, '--log', log, '--html', str(out), '--png-dir', str(png)]) == 0
    ids, images = parse_report(out.read_text())
    assert set(SECTIONS) <= set(ids)
    assert {n for n, _ in images} == FIGURES
    assert {p.stem for p in png.glob('*.png')} == FIGURES
    # the PNG files are the embedded figures, byte for byte
    import base64
    text = out.read_text()
    for p in png.glob('*.png'):
        assert base64.b64encode(p.read_bytes()).decode() in text
    c = Calibration.load(cal)
    for note in c.notes[:2]:
        assert note.split(':')[0] in text


def test_html_from_saved_windows_and_from_the_file_alone(calibrated, tmp_path):
    _, _, cal, win = calibrated
    out = tmp_path / 'w.html'
    assert main(['report', cal, '--windows', win, '--html', str(out)]) == 0
    ids, images = parse_report(out.read_text())
    assert set(SECTIONS) <= set(ids) and {n for n, _ in images} == FIGURES
    bare = tmp_path / 'bare.html'
    assert main(['report', cal, '--html', str(bare)]) == 0
    ids, images = parse_report(bare.read_text())
    assert set(SECTIONS) <= set(ids)
    assert {n for n, _ in images} == {'accel', 'gyro'}      # fitted curves only
    assert 'pass --log' in bare.read_text()


def test_parameter_table_has_units_stds_and_fixed_reasons(calibrated):
    c = Calibration.load(calibrated[2])
    rows = parameter_rows(c)
    names = {(r[0], r[1]) for r in rows}
    for which, model in (('accel', c.accel), ('gyro', c.gyro)):
        assert {(which, n) for n in model.params()} <= names
    for sensor, name, value, std, unit, status, reason in rows:
        assert unit and status.split()[0] in ('estimated', 'fixed')
        assert (std != '-') or status == 'fixed' or 'estimated' in status
        if status == 'fixed':
            assert reason, (sensor, name)


def test_bad_windows_file_is_a_user_error(calibrated, tmp_path, capsys):
    cal = calibrated[2]
    assert main(['report', cal, '--windows', str(tmp_path / 'nope.jsonl'), '--html',
                 str(tmp_path / 'x.html')]) == 2
    assert 'calibrate --save-windows' in capsys.readouterr().err
    assert not os.path.exists(tmp_path / 'x.html')
