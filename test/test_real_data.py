"""Real recordings: CSV readers, imucal's own results reproduced, whole-unit held-out figures."""

import gzip
import json
import os
import sys

import numpy as np
import pytest

from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main
from thermal_imu_calib.collection.motion import collect_motion
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.collection.stationary import DetectorConfig, StationaryDetector
from thermal_imu_calib.estimation.hold_consistency import hold_consistency
from thermal_imu_calib.estimation.whole_unit_fit import fit_whole_unit
from thermal_imu_calib.io.bag import write_columns
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
from thermal_imu_calib.io.csv_logs import (read_imucal_annotated, read_imucal_session,
                                           read_mpu6050_csv, read_static_intervals)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'bench'))
import bench_real_data as R  # noqa: E402
from make_real_bags import bmi270_rows  # noqa: E402
from ferraris_turns import turn_errors  # noqa: E402

FER = R.FERRARIS
MPU = R.MPU


@pytest.fixture(scope='module')
def session():
    return read_imucal_session(os.path.join(FER, 'example_ferraris_session.csv.gz'),
                               os.path.join(FER, 'example_ferraris_session_list.json'))


def test_readers_convert_to_si(session):
    s = session
    assert len(s.imu) == 10376 and s.rate_hz == 102.4
    assert s.sections['x_rot'] == (6770, 7093)
    # a labelled turn integrates to ~360 deg at 102.4 Hz (the gyro is in rad/s now)
    a, b = s.sections['z_rot']
    assert abs(np.degrees(np.sum(s.imu.gyro[a:b, 2])) / s.rate_hz + 359.2) < 0.5
    assert abs(np.linalg.norm(s.section('x_p').accel.mean(0)) - 10.341) < 1e-3
    ann = read_imucal_annotated(os.path.join(FER, 'annotated_session.csv.gz'))
    assert len(ann.imu) == 9414 and set(ann.sections) == set(R.FACES + R.ROTATIONS)
    counts = ann.imu.accel / ann.meta['accel_m_s2_per_count']
    assert np.max(np.abs(counts - np.round(counts))) < 1e-9          # raw counts kept exact
    m = read_mpu6050_csv(os.path.join(MPU, 'example_data_calibration.csv.gz'))
    assert len(m.imu) == 10245 and m.rate_hz == 100.0
    assert m.meta['Initialization time'] == '36.5'
    first = m.imu.accel[:3500].mean(0)
    assert abs(np.linalg.norm(first) - 8.92) < 0.05                  # 14862 counts ~ 0.91 g
    iv = read_static_intervals(os.path.join(MPU, 'static_intervals.csv'))
    assert iv.shape == (10, 2) and iv[0].tolist() == [150, 3613]


def test_ferraris_reimplementation_reproduces_what_imucal_reports(session):
    s = session
    regions = {k: (s.imu.accel[a:b], np.degrees(s.imu.gyro[a:b]))
               for k, (a, b) in s.sections.items()}
    head = np.loadtxt(os.path.join(FER, 'imucal_ferraris_example_head.csv'), delimiter=',',
                      skiprows=1)
    for rate, match in ((204.8, True), (102.4, False)):
        cal = R.ferraris(regions, rate)
        acc = R.ferraris_acc(cal, s.imu.accel[:10])
        gyr = R.ferraris_gyro(cal, np.degrees(s.imu.gyro[:10]), acc)
        assert np.max(np.abs(acc - head[:, 4:])) < 1e-12
        assert (np.max(np.abs(gyr - head[:, 1:4])) < 1e-12) == match
    ann = read_imucal_annotated(os.path.join(FER, 'annotated_session.csv.gz'))
    counts = {k: (ann.imu.accel[a:b] / ann.meta['accel_m_s2_per_count'],
                  ann.imu.gyro[a:b] / ann.meta['gyro_rad_s_per_count'])
              for k, (a, b) in ann.sections.items()}
    cal = R.ferraris(counts, 204.8)
    with open(os.path.join(FER, 'imucal_example_cal.json')) as f:
        snap = json.load(f)
    for key in ('K_a', 'R_a', 'b_a', 'K_g', 'R_g', 'K_ga', 'b_g'):
        assert np.allclose(cal[key], snap[key], rtol=1e-12, atol=1e-12), key


def test_whole_unit_on_the_imucal_session(session):
    s = session
    windows, transitions, _ = collect_motion(s.aligned(), None, 0)
    labels = R.label_holds(windows, s.imu, s.sections)
    faces = [h for h, lab in labels.items() if lab in R.FACES]
    others = [h for h, lab in labels.items() if lab == '']
    assert len(faces) == 6 and len(others) >= 5
    t = s.imu.t
    spans = {k: (t[a] - R.ROTATION_MARGIN_S, t[b - 1] + R.ROTATION_MARGIN_S)
             for k, (a, b) in s.sections.items() if k in R.ROTATIONS}
    fit_tr = [x for x in transitions
              if not any(min(x.t[-1], b) > max(x.t[0], a) for a, b in spans.values())]
    fit = fit_whole_unit(windows, R.G, transitions=fit_tr,
                         accel_rows=np.isin(windows.hold, faces))
    ids, am = R.hold_means(windows, R.apply_whole_unit(fit, windows.accel, windows.gyro)[0])
    err = dict(zip(ids.tolist(), R.norm_error_mg(am)))
    _, raw = R.hold_means(windows)
    raw_err = dict(zip(ids.tolist(), R.norm_error_mg(raw)))
    assert R.rms([err[h] for h in faces]) < 0.05                     # mg, fitted holds
    assert R.rms([err[h] for h in others]) < 0.8                     # mg, held out (raw 60)
    assert R.rms([raw_err[h] for h in others]) > 50
    # held-out 360 deg turns: gyro scale from the face-to-face pose changes only
    before, after = [], []
    for lo, hi in spans.values():
        sel = (t >= lo) & (t <= hi)
        g = R.apply_whole_unit(fit, s.imu.accel[sel], s.imu.gyro[sel])[1]
        before.append(R.turn_angle_error_deg(t[sel], s.imu.gyro[sel]))
        after.append(R.turn_angle_error_deg(t[sel], g))
    assert R.rms(before) > 7.0 and R.rms(after) < 3.0, (before, after)
    assert not np.any(fit.accel.model.estimated_mask('A1')[np.tril_indices(3, -1)])


def test_whole_unit_on_the_mpu6050_session():
    s = read_mpu6050_csv(os.path.join(MPU, 'example_data_calibration.csv.gz'))
    windows, transitions, _ = collect_motion(s.aligned(), None, 0)
    ids, raw = R.hold_means(windows)
    assert len(ids) == 10 and len(transitions) == 9
    faces = {}
    for h, m in zip(ids, raw):
        u = m / np.linalg.norm(m)
        i = int(np.argmax(np.abs(u)))
        if abs(u[i]) > np.cos(np.radians(25)):
            faces.setdefault((i, u[i] > 0), int(h))     # the first hold of each face
    assert len(faces) == 6
    tilted = [int(h) for h in ids if int(h) not in faces.values()]
    assert len(tilted) == 4
    # every tilted hold held out in turn: misalignment comes from the other three
    held, raw_held = [], []
    for h in tilted:
        keep = windows.hold != h
        fit = fit_whole_unit(windows, R.G, accel_rows=keep)
        a = R.apply_whole_unit(fit, windows.accel[~keep], windows.gyro[~keep])[0]
        held.append(R.norm_error_mg(np.average(a, 0, windows.n[~keep])[None])[0])
        raw_held.append(R.norm_error_mg(np.average(windows.accel[~keep], 0,
                                                   windows.n[~keep])[None])[0])
        assert np.any(fit.accel.model.estimated_mask('A1')[np.tril_indices(3, -1)])
    assert R.rms(raw_held) > 50 and R.rms(held) < 1.0, (raw_held, held)   # mg
    # every pose change held out in turn
    t = s.imu.t
    up_raw = {int(i): m / np.linalg.norm(m) for i, m in zip(ids, raw)}
    bias0 = R.hold_means(windows, windows.gyro)[1][0]
    before, after = [], []
    for k, tr in enumerate(transitions):
        fit = fit_whole_unit(windows, R.G, transitions=transitions[:k] + transitions[k + 1:])
        sel = (t >= tr.t[0]) & (t <= tr.t[-1])
        _, am = R.hold_means(windows, R.apply_whole_unit(fit, windows.accel, windows.gyro)[0])
        up = {int(i): m / np.linalg.norm(m) for i, m in zip(ids, am)}
        g = R.apply_whole_unit(fit, s.imu.accel[sel], s.imu.gyro[sel])[1]
        after.append(R.direction_error_deg(t[sel], g, up[tr.hold_from], up[tr.hold_to]))
        before.append(R.direction_error_deg(t[sel], s.imu.gyro[sel] - bias0,
                                            up_raw[tr.hold_from], up_raw[tr.hold_to]))
    assert R.rms(after) < 0.5 * R.rms(before), (before, after)      # 8.9 -> 2.6 deg RMS


# ----------------------------------------------------------- default detector vs annotations
def _holds(t, accel, gyro):
    """Run the shipped detector with default settings; return (start, end) per hold, s."""
    det = StationaryDetector(DetectorConfig(), 0)
    for i in range(0, len(t), 20000):
        det.update(t[i:i + 20000], accel[i:i + 20000], gyro[i:i + 20000])
    det.finish()
    return [(h['start'], h['start'] + h['duration']) for h in det.holds]


def _covered(holds, lo, hi):
    """Return the fraction of [lo, hi] inside the holds."""
    return sum(max(0.0, min(hi, b) - max(lo, a)) for a, b in holds) / (hi - lo)


def test_default_detector_finds_the_six_ferraris_faces(session):
    # the authors' section list, read here with json (sample indices at 102.4 Hz)
    with open(os.path.join(FER, 'example_ferraris_session_list.json')) as f:
        sections = json.load(f)
    t = session.imu.t
    holds = _holds(t, session.imu.accel, session.imu.gyro)
    faces = [k for k in sections if not k.endswith('rot')]
    assert len(faces) == 6
    for k in faces:
        a, b = int(sections[k]['start']), int(sections[k]['end'])
        assert _covered(holds, t[a], t[b - 1]) >= 0.8, k
    for k in ('x_rot', 'y_rot', 'z_rot'):                # the turns are motion
        a, b = int(sections[k]['start']), int(sections[k]['end'])
        mid = slice(a + (b - a) // 4, b - (b - a) // 4)
        assert _covered(holds, t[mid][0], t[mid][-1]) == 0.0, k


def test_default_detector_finds_the_mpu6050_static_intervals():
    m = read_mpu6050_csv(os.path.join(MPU, 'example_data_calibration.csv.gz'))
    # the authors' own detection: row 1 starts, row 2 ends (sample indices at 100 Hz)
    iv = np.loadtxt(os.path.join(MPU, 'static_intervals.csv'), delimiter=',').astype(int)
    holds = _holds(m.imu.t, m.imu.accel, m.imu.gyro)
    t = m.imu.t
    found = [_covered(holds, t[a], t[min(b, len(t) - 1)]) >= 0.5 for a, b in iv.T]
    assert np.mean(found) >= 0.9, found
    assert len(holds) == iv.shape[1]                     # ten still periods, no extra


def _bmi270(name):
    return bmi270_rows(os.path.join(ROOT, 'test', 'fixtures', 'real', 'bmi270', name))


@pytest.mark.parametrize('name', ['BMI_270_cold_test_.csv', 'BMI_270_hot_test.csv'])
@pytest.mark.parametrize('rate_hz', [10.0, 80.0])
def test_default_detector_keeps_the_bmi270_soaks_in_holds(name, rate_hz):
    # no time base in the files: the detector works in samples; 80 Hz is about what a
    # 38400-baud link carries at ~45 characters per line, 10 Hz a slow logger
    x = _bmi270(name)
    t = np.arange(len(x)) / rate_hz
    holds = _holds(t, x[:, 1:4] * 4.0 * R.G, np.radians(x[:, 4:7]))
    assert _covered(holds, t[0], t[-1]) >= 0.95


def _csv_session():
    """Read the Ferraris CSV and its section list with numpy/json only (no package reader)."""
    with gzip.open(os.path.join(FER, 'example_ferraris_session.csv.gz'), 'rt') as f:
        x = np.loadtxt(f, delimiter=',', skiprows=1)
    with open(os.path.join(FER, 'example_ferraris_session_list.json')) as f:
        sections = {k: (int(v['start']), int(v['end'])) for k, v in json.load(f).items()}
    return x[:, 4:7], np.radians(x[:, 1:4]), sections


@pytest.mark.parametrize('model', [[], ['--model', 'whole_unit']])
def test_default_calibrate_judges_the_disagreeing_ferraris_holds_held_out(tmp_path, session,
                                                                          model):
    # the shipped CLI path with default options only (and whole_unit, the other candidate)
    bag, cal_path = str(tmp_path / 'ferraris.mcap'), str(tmp_path / 'f.yaml')
    write_columns(bag, '/imu', session.imu)
    assert main(['calibrate', bag, '--imu-topic', '/imu', '--gravity', '9.81',
                 '-o', cal_path] + model) == 0
    cal = Calibration.load(cal_path)
    acc, gyr, sections = _csv_session()
    t = np.arange(len(acc)) / 102.4
    # the still periods next to the x turn read |a| ~0.85 mg below the +x face a minute
    # earlier (same pose, same noise): the pose-repeat test flags both (z > 5). Leaving
    # them out is then judged held out (leave-one-hold-out over the holds that can go
    # without losing a face, every held-out hold scored): it does not predict them better
    # by more than the noise, so they stay in the fit (docs/real_recordings.md)
    rep = cal.fit['hold_consistency']
    assert rep['left_out'] == [] and not rep['heldout']['applied'], rep
    pairwise = [h for h in rep['not_applied'] if 'epoch' not in h]
    a, b = sections['x_rot']
    assert len(pairwise) == 2
    for h in pairwise:
        assert t[a] - 10.0 < h['start_s'] and h['end_s'] < t[b - 1] + 10.0
        assert h['z'] > 5.0
    assert any('not left out' in n for n in cal.notes)
    if not model:
        assert cal.fit['model_choice']['model'] == 'standard'
    # |a| - g over the authors' six face sections: imucal's in-sample 40.3 ug is MISSED
    # (measured 2026-11-26: 188 ug default, 126 ug whole_unit; raw 6.7 mg; with holds 7-8
    # left out the standard fit gives 39.6 ug, but held-out holds do not support leaving
    # them out: docs/real_recordings.md). The bounds below guard against regression only.
    ca = cal.apply(acc, gyr, np.zeros((len(acc), 0))).accel
    err = []
    for k in R.FACES:
        lo, hi = sections[k]
        err.append(np.linalg.norm(ca[lo:hi].mean(0)) - 9.81)
    rms = np.sqrt(np.mean(np.square(err)))
    assert rms <= (140e-6 if model else 200e-6) * 9.81, rms / 9.81e-6


def _six_faces_and_repeat(step_g, seed=0):
    """Windows of a biased, scaled sensor: six faces, then +x again 3 deg off, |a| stepped."""
    rng = np.random.default_rng(seed)
    bias, scale, g, n, sd = np.array([0.5, -0.4, 0.3]), np.array([1.02, 0.97, 1.01]), 9.81, \
        500, 0.015
    ups = [np.eye(3)[i] * s for i in range(3) for s in (1, -1)]
    tilt = np.radians(3.0)
    ups.append(np.array([np.cos(tilt), np.sin(tilt), 0.0]))
    rows = []
    for j, u in enumerate(ups):
        f = g * u * (1.0 + (step_g if j == 6 else 0.0))
        rows.append(f * scale + bias + rng.normal(0.0, sd / np.sqrt(n), 3))
    m = len(rows)
    return Windows(np.arange(m), 10.0 * np.arange(m), 10.0 * np.arange(m) + 5.0,
                   np.full(m, n), np.array(rows), np.zeros((m, 3)), np.full((m, 3), sd ** 2),
                   np.zeros((m, 3)), np.zeros((m, 0)), np.zeros((m, 0)))


@pytest.mark.parametrize('step_g, left_out', [(0.0, []), (1e-3, [6])])
def test_pose_repeat_test_leaves_out_only_a_visit_that_disagrees(step_g, left_out):
    # a 3 deg tilt between two visits with a 0.5 m/s^2 bias changes the raw |m| by ~26 mg:
    # that must not count; a 1 mg step (~10 sigma of the two hold means) must
    w = _six_faces_and_repeat(step_g)
    keep, rep = hold_consistency(w, 9.81)
    assert [h['hold'] for h in rep['left_out']] == left_out
    assert np.array_equal(~keep, np.isin(w.hold, left_out))
    if left_out:
        assert rep['left_out'][0]['reference_hold'] == 0                 # the face is kept
        assert abs(rep['left_out'][0]['difference_ug'] - 1e3) < 300


def _turn_errors(t, gyro, sections):
    """Return the |integrated angle| - 360 deg (deg) of the three labelled turns."""
    return np.array(list(turn_errors(t, gyro, sections).values()))


def test_default_calibrate_uses_the_ferraris_turns_for_the_gyro(tmp_path, session, capsys):
    # default options: the accelerometer model is field (fewer than 3 tilted holds), and the
    # gyro still gets its scale from the pose changes, the three 360 deg turns included
    bag, cal_path = str(tmp_path / 'ferraris.mcap'), str(tmp_path / 'f.yaml')
    write_columns(bag, '/imu', session.imu)
    assert main(['calibrate', bag, '--imu-topic', '/imu', '--gravity', '9.81',
                 '-o', cal_path]) == 0
    out = capsys.readouterr().out
    cal = Calibration.load(cal_path)
    n = cal.fit['pose_changes']['collected']
    assert n >= 9 and cal.fit['pose_changes']['used'] == n, cal.fit['pose_changes']
    assert f'{n} of {n} pose changes used for gyro scale' in out, out
    gyro = cal.fit['model_choice']['gyro']
    assert gyro['model'] == 'whole_unit_turns' and cal.gyro.kind == 'whole_unit_gyro'
    assert 'gyro candidates compared held out' in out and 'whole_unit_turns' in out
    # every candidate scored on both figures; the one kept is within 1.5x of the best on each
    figs = gyro['heldout']
    assert set(figs) == {'polynomial', 'whole_unit_static', 'whole_unit_turns'}
    for key in ('heldout_still_error_rad_s', 'heldout_pose_change_error_deg'):
        best = min(f[key] for f in figs.values())
        assert figs['whole_unit_turns'][key] <= 1.5 * best, figs
    acc, gyr, sections = _csv_session()
    t = np.arange(len(acc)) / 102.4
    ours = _turn_errors(t, cal.apply(acc, gyr, np.zeros((len(acc), 0))).gyro, sections)
    raw = _turn_errors(t, gyr, sections)
    # imucal's Ferraris equations fitted on these very turns (in-sample, at the true rate)
    regions = {k: (session.imu.accel[a:b], np.degrees(session.imu.gyro[a:b]))
               for k, (a, b) in session.sections.items()}
    ref = R.ferraris(regions, 102.4)
    imucal = _turn_errors(t, np.radians(R.ferraris_gyro(ref, np.degrees(gyr),
                                                        R.ferraris_acc(ref, acc))), sections)

    def rms(x):
        return float(np.sqrt(np.mean(x ** 2)))
    # measured: ours 0.097 deg RMS, imucal in-sample 0.039, raw 7.7 (ours without the turns:
    # 6.8 with the bias polynomial, 2.5 with the face-to-face pose changes only)
    assert rms(ours) < 4.0 * rms(imucal) and rms(ours) < rms(raw) / 20, \
        (rms(ours), rms(imucal), rms(raw))


@pytest.mark.parametrize('name', ['BMI_270_cold_test_.csv', 'BMI_270_hot_test.csv'])
def test_default_calibrate_ends_at_offset_on_a_bmi270_soak(tmp_path, name):
    # one orientation, 0.0-0.2 degC over the fixture slice (0.03 / 0.4 degC on the full
    # soaks): only a per-axis offset is observable, and no temperature shape is compared
    x = _bmi270(name)
    stamp = (1_700_000_000 * 10 ** 9 + np.round(np.arange(len(x)) * 1e9 / 80.0)).astype(np.int64)
    imu = ImuColumns(stamp, x[:, 1:4] * 4.0 * R.G, np.radians(x[:, 4:7]), 'imu')
    bag, cal_path = str(tmp_path / 'soak.mcap'), str(tmp_path / 's.yaml')
    temp = TemperatureColumns(stamp, x[:, 0], 'imu')
    write_columns(bag, '/imu', imu, {'/imu/temperature': temp})
    assert main(['calibrate', bag, '--imu-topic', '/imu', '--gravity', '9.81',
                 '-o', cal_path]) == 0
    cal = Calibration.load(cal_path)
    choice = cal.fit['model_choice']
    assert choice['model'] == 'offset', choice
    assert 'only an offset per axis vs temperature is observable' in choice['reason']
    assert cal.accel.kind == 'offset_polynomial'
