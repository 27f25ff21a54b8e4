"""Export/import: each target tool's correction, re-implemented here from its published formula.

The formulas are written independently of ``thermal_imu_calib.formats`` (from the tools'
sources cited in docs/export.md) and applied to a simulated cold start; where our model
is representable they must match our compensation within 1 ug and 0.01 deg/h.
"""

import json
import os

import numpy as np
import pytest

from _thermal_data import options, sim_windows
from thermal_imu_calib import cli, sim
from thermal_imu_calib.estimation.calibrate import calibrate_windows, make_context
from thermal_imu_calib.formats import EXTENSIONS, export_calibration, load_prior, read_calibration
from thermal_imu_calib.models.field import FieldPolynomialModel

UG = 9.80665e-6
DPH = np.pi / 180 / 3600
FIXTURE = os.path.join(os.path.dirname(__file__), 'fixtures', 'real', 'imucal_ferraris',
                       'imucal_example_cal.json')


@pytest.fixture(scope='module')
def cold():
    """A 40-min single-pose cold start, its windows, and PX4-/ArduPilot-style calibrations."""
    rec = sim.simulate('single-warmup', 2, hold_s=(2400.0, 2400.0), imu_rate=100.0)
    w = sim_windows(rec)
    cals = {}
    for name in ('px4', 'ardupilot'):
        o = options()
        o.model = name
        cals[name] = calibrate_windows(w, o).calibration
    imu = rec.imu()
    temps = rec.temperature_at(imu.stamp_ns, 'read')
    return {'rec': rec, 'windows': w, 'cals': cals, 'accel': imu.accel, 'gyro': imu.gyro,
            'temps': temps}


def _write(tmp_path, name, out, fmt=''):
    paths = {}
    for suffix, text in out.files.items():
        p = tmp_path / (name + EXTENSIONS.get(fmt, '') + suffix)
        p.write_text(text)
        paths[suffix] = p
    return paths


# -------------------------------------------------------------- the tools' formulas
def px4_params(text):
    """QGroundControl .params: vehicle, component, name, value, type (tab-separated)."""
    out = {}
    for line in text.splitlines():
        if line and not line.startswith('#'):
            _, _, name, value, _ = line.split('\t')
            out[name] = float(value)
    return out


def px4_correct(p, pre, raw, temp):
    """PX4 calc_thermal_offsets_3D, in float32 as on board; the offset is subtracted."""
    f = np.float32
    dt = (np.clip(temp.astype(f), f(p[f'{pre}_TMIN']), f(p[f'{pre}_TMAX']))
          - f(p[f'{pre}_TREF']))
    x = np.array([[p[f'{pre}_X{j}_{a}'] for a in range(3)] for j in range(4)], f)
    dt = dt[:, None]
    off = x[0] + x[1] * dt + x[2] * dt * dt + x[3] * dt * dt * dt
    return raw - off.astype(float)


def ap_params(text):
    return {ln.split(',')[0]: float(ln.split(',')[1]) for ln in text.splitlines()
            if ln and not ln.startswith('#')}


def ap_correct(p, stem, caltemp, raw, temp):
    """ArduPilot TCal::correct_sensor (float32): v -= P(T - 35) - P(Tcal - 35)."""
    f = np.float32
    lo, hi = f(p['INS_TCAL1_TMIN']), f(p['INS_TCAL1_TMAX'])
    c = np.array([[p[f'INS_TCAL1_{stem}{k}_{a}'] for a in 'XYZ'] for k in (1, 2, 3)], f)

    def poly(t):
        t = t[:, None]
        return (c[0] + (c[1] + c[2] * t) * t) * t * f(1e-6)
    t = np.clip(temp.astype(f), lo, hi) - f(35.0)
    tc = np.clip(np.full_like(t, f(caltemp)), lo, hi) - f(35.0)
    return raw - (poly(t) - poly(tc)).astype(float)


def imu_tk_correct(text, raw):
    """imu_tk unbiasNormalize: X' = T K (X - B), from the 21 numbers of the file."""
    v = np.array(text.split(), float)
    t, k, b = v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:]
    return (raw - b) @ (t @ k).T


def imucal_correct(d, acc, gyr):
    """imucal FerrarisCalibrationInfo.calibrate."""
    a = np.asarray
    acc_out = (acc - a(d['b_a'])) @ (np.linalg.inv(a(d['R_a'])) @ np.linalg.inv(a(d['K_a']))).T
    g = gyr - acc_out @ a(d['K_ga']).T - a(d['b_g'])
    return acc_out, g @ (np.linalg.inv(a(d['R_g'])) @ np.linalg.inv(a(d['K_g']))).T


# -------------------------------------------------------------- exact where representable
def test_px4_matches_our_compensation(cold, tmp_path):
    cal = cold['cals']['px4']
    out = export_calibration(cal, 'px4', accel_id=1311244, gyro_id=2359308)
    assert out.loss['accel']['what'] == out.loss['gyro']['what'] == 'exact'
    p = px4_params(out.files[''])
    assert p['TC_A_ENABLE'] == p['TC_G_ENABLE'] == 1 and p['TC_A0_ID'] == 1311244
    ours = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    t = cold['temps'][:, 0]
    da = px4_correct(p, 'TC_A0', cold['accel'], t) - ours.accel
    dg = px4_correct(p, 'TC_G0', cold['gyro'], t) - ours.gyro
    assert np.abs(da).max() < 1 * UG
    assert np.abs(dg).max() < 0.01 * DPH
    # and the drift it removes is real (a test that could fail)
    assert np.ptp(ours.accel - cold['accel'], axis=0).max() > 100 * UG


def test_export_states_a_linear_continuation(cold):
    """The autopilots clamp; a calibration that continues the gyro says so, per sensor."""
    import dataclasses
    cal = dataclasses.replace(cold['cals']['px4'], out_of_range='linear_gyro')
    for fmt in ('px4', 'ardupilot'):
        notes = ' '.join(export_calibration(cal, fmt).notes)
        assert 'continues linearly outside its valid range (gyro)' in notes
        assert 'continues linearly outside its valid range (accel)' not in notes


def test_ardupilot_matches_our_compensation(cold):
    cal = cold['cals']['ardupilot']
    out = export_calibration(cal, 'ardupilot')
    p = ap_params(out.files[''])
    assert p['INS_TCAL1_ENABLE'] == 1
    assert p['INS_TCAL1_TMIN'] < p['INS_ACC1_CALTEMP'] == 35.0 < p['INS_TCAL1_TMAX']
    ours = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    t = cold['temps'][:, 0]
    da = ap_correct(p, 'ACC', p['INS_ACC1_CALTEMP'], cold['accel'], t) - ours.accel
    dg = ap_correct(p, 'GYR', p['INS_GYR1_CALTEMP'], cold['gyro'], t) - ours.gyro
    # one TMIN..TMAX per IMU: the gyro's; the accelerometer's cubic is held at its own
    # (narrower) range in ours and continued by ArduPilot, which the export says
    (lo, hi), = cal.own_range('accel')
    inside = (t >= lo) & (t <= hi)
    assert inside.mean() > 0.9 and (p['INS_TCAL1_TMIN'], p['INS_TCAL1_TMAX']) == pytest.approx(
        tuple(cal.own_range('gyro')[0]))
    assert np.abs(da[inside]).max() < 1 * UG
    assert np.abs(dg).max() < 0.01 * DPH
    if not inside.all():
        assert any('accel: this calibration holds it at its own range' in n for n in out.notes)
    # a cubic with a constant (PX4-style) is exact up to that constant, which ArduPilot's
    # own offsets (taken at CALTEMP) hold
    cal = cold['cals']['px4']
    p = ap_params(export_calibration(cal, 'ardupilot').files[''])
    ours = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    da = ap_correct(p, 'ACC', p['INS_ACC1_CALTEMP'], cold['accel'], t) - ours.accel
    (lo, hi), = cal.own_range('accel')
    inside = (t >= lo) & (t <= hi)
    assert np.ptp(da[inside], axis=0).max() < 1 * UG


def test_static_formats_match_at_their_temperature(cold):
    """imu_tk and imucal hold no temperature: exact at the export temperature."""
    rec = cold['rec']
    cal = rec.truth
    te = 30.0
    n = 20000
    acc, gyr = cold['accel'][:n], cold['gyro'][:n]
    temps = np.full((n, len(cal.inputs)), te)
    ours = cal.apply(acc, gyr, temps)
    out = export_calibration(cal, 'json', temperature=te)
    a, g = imucal_correct(json.loads(out.files['']), acc, gyr)
    assert np.abs(a - ours.accel).max() < 1 * UG
    assert np.abs(g - ours.gyro).max() < 0.01 * DPH
    out = export_calibration(cal, 'imu_tk', temperature=te)
    a = imu_tk_correct(out.files['_acc.calib'], acc)
    assert np.abs(a - ours.accel).max() < 1 * UG
    coupling = getattr(cal.gyro, 'coupling', None)
    if coupling is None or not np.any(coupling):
        g = imu_tk_correct(out.files['_gyro.calib'], gyr)
        assert np.abs(g - ours.gyro).max() < 0.01 * DPH
    # over the cold start the static file loses the thermal drift: stated, and real
    full = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    dev = np.abs(imu_tk_correct(out.files['_acc.calib'], cold['accel']) - full.accel) / UG
    assert out.loss['accel']['max'] > 10 and dev.max() > 10
    assert dev.max() < 2 * out.loss['accel']['max']


def test_refit_states_the_loss(cold):
    """A field model (scale-factor terms) in PX4/ArduPilot: refit, loss stated and bounded."""
    cal = cold['rec'].truth
    assert isinstance(cal.accel, FieldPolynomialModel)
    ours = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    t = cold['temps'][:, 0]
    out = export_calibration(cal, 'px4')
    loss = out.loss['accel']
    assert loss['what'].startswith('cubic offset refit') and loss['max'] > 0
    assert any('static calibration' in n for n in out.notes)
    p = px4_params(out.files[''])
    # PX4's static calibration (CAL_ACC0_*) holds the scale/misalignment L at T0
    lin = np.linalg.inv(cal.accel._s_inv @ np.diag(1 / cal.accel.scale_bias(
        cal.accel.t0[None])[0][0]))
    got = px4_correct(p, 'TC_A0', cold['accel'], t) @ np.linalg.inv(lin).T
    dev = np.abs(got - ours.accel) / UG
    assert dev.max() < 1.5 * loss['max']
    assert np.sqrt(np.mean(dev ** 2)) < 3 * loss['rms']
    out_w = export_calibration(cal, 'px4', windows=cold['windows'])
    assert 'windows' in out_w.loss['accel']['what']


# -------------------------------------------------------------- round trips
@pytest.mark.parametrize('fmt,which', [('px4', 'px4'), ('ardupilot', 'ardupilot'),
                                       ('px4', 'truth'), ('ardupilot', 'truth'),
                                       ('imu_tk', 'truth'), ('json', 'truth')])
def test_round_trip_is_identical(cold, tmp_path, fmt, which):
    cal = cold['rec'].truth if which == 'truth' else cold['cals'][which]
    first = export_calibration(cal, fmt)
    paths = _write(tmp_path, 'a', first, fmt)
    back = read_calibration(next(iter(paths.values())))
    second = export_calibration(back, fmt)
    assert second.files == first.files
    third = export_calibration(read_calibration(next(iter(_write(tmp_path, 'b', second,
                                                                 fmt).values()))), fmt)
    assert third.files == first.files


def test_a_sensor_with_its_own_range(cold, tmp_path):
    """``sensor_range`` (a lifelong one-sensor swap, ``--high-order-margin``): PX4 gets each
    sensor's own TMIN/TMAX and reads it back; ArduPilot (one pair per IMU) the wider one,
    and says how far it continues the narrower sensor."""
    import dataclasses
    cal = cold['cals']['px4']
    (lo, hi), = cal.valid_range
    narrow = np.array([[lo + 1.0, hi - 1.0]])
    cal = dataclasses.replace(cal, sensor_range={'accel': narrow})
    out = export_calibration(cal, 'px4')
    p = px4_params(out.files[''])
    assert (p['TC_A0_TMIN'], p['TC_A0_TMAX']) == pytest.approx(tuple(narrow[0]), abs=1e-4)
    assert (p['TC_G0_TMIN'], p['TC_G0_TMAX']) == pytest.approx((lo, hi), abs=1e-4)
    back = read_calibration(next(iter(_write(tmp_path, 'a', out, 'px4').values())))
    assert np.allclose(back.own_range('accel'), narrow, atol=1e-4)
    assert np.allclose(back.own_range('gyro'), [[lo, hi]], atol=1e-4)
    t = cold['temps'][:, 0]
    ours = cal.apply(cold['accel'], cold['gyro'], cold['temps'])
    da = px4_correct(p, 'TC_A0', cold['accel'], t) - ours.accel
    assert np.abs(da).max() < 1 * UG and (t < narrow[0, 0]).any()
    ap = export_calibration(cal, 'ardupilot')
    q = ap_params(ap.files[''])
    assert (q['INS_TCAL1_TMIN'], q['INS_TCAL1_TMAX']) == pytest.approx((lo, hi), abs=1e-4)
    assert any('accel: this calibration holds it at its own range' in n and
               'up to 1.00 degC beyond' in n for n in ap.notes)


def test_kalibr_noise_export_and_round_trip(cold, tmp_path):
    cal = cold['cals']['px4']
    with pytest.raises(ValueError, match='--noise noise.yaml'):
        export_calibration(cal, 'kalibr')
    noise = ('accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n'
             'gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n'
             'rostopic: /imu0\nupdate_rate: 200.0\n'
             'thermal_imu_calib: {accel: {axes: {x: {noise_density: 1.0e-3}}}}\n')
    out = export_calibration(cal, 'kalibr', noise_text=noise)
    import yaml
    d = yaml.safe_load(out.files[''])
    assert d == {'accelerometer_noise_density': 1.86e-03, 'accelerometer_random_walk': 4.33e-04,
                 'gyroscope_noise_density': 1.87e-04, 'gyroscope_random_walk': 2.66e-05,
                 'rostopic': '/imu0', 'update_rate': 200.0}
    p = _write(tmp_path, 'imu', out, 'kalibr')['']
    back = read_calibration(p)
    assert export_calibration(back, 'kalibr').files == out.files
    # per-axis figures in the calibration's own noise section: the worst axis
    raw = {'noise': {'accel_noise_density': {'value': [1e-3, 3e-3, 2e-3]},
                     'accel_random_walk': [1e-4] * 3, 'gyro_noise_density': [1e-4] * 3,
                     'gyro_random_walk': [1e-5, 2e-5, 1e-5]}}
    d = yaml.safe_load(export_calibration(cal, 'kalibr', raw_dict=raw, rostopic='/imu',
                                          update_rate=100).files[''])
    assert d['accelerometer_noise_density'] == 3e-3 and d['gyroscope_random_walk'] == 2e-5
    with pytest.raises(ValueError, match='lacks one'):
        export_calibration(cold['rec'].prior, 'kalibr', raw_dict=raw, rostopic='/imu',
                           update_rate=100, kalibr_model='scale-misalignment')


def kalibr_correct(d, acc, gyr):
    """Invert Kalibr's IccScaledMisalignedImu measurement model (biases from our keys).

    a_meas = M_a a_i + b_a;  w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g
    """
    a = np.asarray
    ma, mg = a(d['accelerometers']['M']), a(d['gyroscopes']['M'])
    am, c = a(d['gyroscopes']['A']), a(d['gyroscopes']['C_gyro_i'])
    ba, bg = a(d['thermal_imu_calib']['accelerometer_bias']), \
        a(d['thermal_imu_calib']['gyroscope_bias'])
    assert np.allclose(np.triu(ma, 1), 0) and np.allclose(np.triu(mg, 1), 0)
    assert np.allclose(c @ c.T, np.eye(3), atol=1e-9)
    a_i = np.linalg.solve(ma, (acc - ba).T).T
    w_i = (c.T @ np.linalg.solve(mg, (gyr - bg - (am @ c @ a_i.T).T).T)).T
    return a_i, w_i


def test_kalibr_scale_misalignment_intrinsics(cold, tmp_path):
    import yaml
    cal = cold['rec'].truth
    noise = ('accelerometer_noise_density: 1.0e-3\naccelerometer_random_walk: 1.0e-4\n'
             'gyroscope_noise_density: 1.0e-4\ngyroscope_random_walk: 1.0e-5\n')
    te, n = 30.0, 20000
    out = export_calibration(cal, 'kalibr', noise_text=noise, rostopic='/imu',
                             update_rate=100.0, kalibr_model='scale-misalignment',
                             temperature=te)
    d = yaml.safe_load(out.files[''])
    assert d['model'] == 'scale-misalignment' and d['rostopic'] == '/imu'
    acc, gyr = cold['accel'][:n], cold['gyro'][:n]
    ours = cal.apply(acc, gyr, np.full((n, len(cal.inputs)), te))
    a_i, w_i = kalibr_correct(d, acc, gyr)
    assert np.abs(a_i - ours.accel).max() < 1 * UG       # seed 000 S is Kalibr's frame
    assert np.abs(w_i - ours.gyro).max() < 0.01 * DPH
    assert out.loss['accel']['max'] > 10                 # no temperature in Kalibr: stated
    # round trip: C_gyro_i is re-orthonormalised on the way, so equal to 1e-11, not textually
    p = _write(tmp_path, 'imu', out, 'kalibr')['']
    again = yaml.safe_load(export_calibration(read_calibration(p), 'kalibr',
                                              kalibr_model='scale-misalignment').files[''])
    for sec, key in (('accelerometers', 'M'), ('gyroscopes', 'M'), ('gyroscopes', 'A'),
                     ('gyroscopes', 'C_gyro_i')):
        np.testing.assert_allclose(again[sec][key], d[sec][key], rtol=0, atol=1e-11)
    assert again['thermal_imu_calib'] == d['thermal_imu_calib']


# -------------------------------------------------------------- import as prior
def test_imucal_fixture_and_si_import(tmp_path):
    text = open(FIXTURE).read()
    with pytest.raises(ValueError, match='from_acc_unit is .a.u.'):
        read_calibration(FIXTURE)
    d = json.loads(text)
    # the same rotations and relative scales, as if imucal had been run on SI raw data
    for k in ('K_a', 'K_g'):
        d[k] = (np.asarray(d[k]) / np.mean(np.diag(d[k]))).tolist()
    d.update(from_acc_unit='m/s^2', from_gyr_unit='rad/s')
    p = tmp_path / 'si.json'
    p.write_text(json.dumps(d))
    cal = read_calibration(p)
    rng = np.random.default_rng(0)
    acc, gyr = rng.normal(0, 10, (50, 3)), rng.normal(0, 1, (50, 3))
    a, g = imucal_correct(d, acc, gyr)
    ours = cal.apply(acc, gyr)
    np.testing.assert_allclose(ours.accel, a, atol=1e-12)
    np.testing.assert_allclose(ours.gyro, g * np.pi / 180, atol=1e-12)   # gyr_unit deg/s


def test_prior_from_every_format(cold, tmp_path):
    truth = cold['rec'].truth
    w = cold['windows']
    for fmt, cal in (('imu_tk', truth), ('json', truth), ('px4', cold['cals']['px4']),
                     ('ardupilot', cold['cals']['ardupilot'])):
        paths = _write(tmp_path, fmt, export_calibration(cal, fmt), fmt)
        prior = load_prior(next(iter(paths.values())))
        assert isinstance(prior.accel, FieldPolynomialModel)
        o = options()
        o.prior = prior
        ctx = make_context(w, o)
        assert ctx.prior_model is prior.accel
        if fmt in ('imu_tk', 'json'):
            # the prior corrects like the file at T0, up to a rotation of the frame
            raw = cold['accel'][:100]
            t0 = prior.accel.t0
            a = prior.accel.correct(raw, np.broadcast_to(t0, raw.shape))
            b = export_calibration(truth, 'imu_tk', temperature=float(np.mean(t0)))
            ref = imu_tk_correct(b.files['_acc.calib'], raw)
            np.testing.assert_allclose(np.linalg.norm(a, axis=1), np.linalg.norm(ref, axis=1),
                                       atol=1e-9)
    kal = tmp_path / 'imu.yaml'
    kal.write_text('accelerometer_noise_density: 1e-3\naccelerometer_random_walk: 1e-4\n'
                   'gyroscope_noise_density: 1e-4\ngyroscope_random_walk: 1e-5\n'
                   'rostopic: /imu\nupdate_rate: 100\n')
    prior = load_prior(kal)
    assert prior.accel is None and prior.fit['imported']['gyroscope_random_walk'] == 1e-5


# -------------------------------------------------------------- CLI
def test_cli_export(cold, tmp_path, capsys):
    src = tmp_path / 'cal.yaml'
    cold['cals']['px4'].save(src)
    assert cli.main(['export', str(src), '--format', 'px4']) == 0
    assert (tmp_path / 'cal.params').is_file()
    assert cli.main(['export', str(src), '--format', 'px4']) == 2
    assert 'exists' in capsys.readouterr().err
    assert cli.main(['export', str(src), '--format', 'kalibr']) == 2
    err = capsys.readouterr().err
    assert 'pass --noise noise.yaml' in err and 'Traceback' not in err
    assert (tmp_path / 'cal.yaml').stat().st_size > 0      # the input is untouched
    assert cli.main(['export', str(src), '--format', 'imu_tk', '-o', str(tmp_path / 'x')]) == 0
    assert (tmp_path / 'x_acc.calib').is_file() and (tmp_path / 'x_gyro.calib').is_file()
    jl = tmp_path / 'w.jsonl'
    jl.write_text(cold['windows'].to_jsonl())
    assert cli.main(['export', str(src), '--format', 'ardupilot', '--windows', str(jl)]) == 0


# -------------------------------------------------------------- real data, default options
def test_real_mpu6050_whole_unit_exports():
    """A seed 002 calibration fitted on the real MPU-6050 session, in imucal, imu_tk, Kalibr."""
    import sys
    import yaml
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(
        __file__))), 'bench'))
    import bench_real_data as R
    from thermal_imu_calib.calibration import Calibration
    from thermal_imu_calib.collection.motion import collect_motion
    from thermal_imu_calib.estimation.whole_unit_fit import fit_whole_unit
    from thermal_imu_calib.io.csv_logs import read_mpu6050_csv
    s = read_mpu6050_csv(os.path.join(R.MPU, 'example_data_calibration.csv.gz'))
    windows, transitions, _ = collect_motion(s.aligned(), None, 0)   # default detector
    fit = fit_whole_unit(windows, R.G, transitions=transitions)
    cal = Calibration(accel=fit.accel.model, gyro=fit.gyro.model)
    assert np.abs(cal.gyro.coupling).max() > 1e-5          # a real g-sensitivity
    acc, gyr = s.imu.accel, s.imu.gyro
    ours = cal.apply(acc, gyr)
    a, g = imucal_correct(json.loads(export_calibration(cal, 'json').files['']), acc, gyr)
    assert np.abs(a - ours.accel).max() < 1 * UG
    assert np.abs(g - ours.gyro).max() < 0.01 * DPH
    out = export_calibration(cal, 'imu_tk', windows=windows)
    assert np.abs(imu_tk_correct(out.files['_acc.calib'], acc) - ours.accel).max() < 1 * UG
    dev = np.abs(imu_tk_correct(out.files['_gyro.calib'], gyr) - ours.gyro).max() / DPH
    assert any('no g-sensitivity' in n for n in out.notes) and out.loss['gyro']['max'] > 10
    assert dev > 10
    kal = export_calibration(cal, 'kalibr', rostopic='/imu', update_rate=100.0,
                             kalibr_model='scale-misalignment',
                             noise_text='accelerometer_noise_density: 1.0e-3\n'
                                        'accelerometer_random_walk: 1.0e-4\n'
                                        'gyroscope_noise_density: 1.0e-4\n'
                                        'gyroscope_random_walk: 1.0e-5\n')
    d = yaml.safe_load(kal.files[''])
    a_i, w_i = kalibr_correct(d, acc, gyr)
    # Kalibr's IMU frame is ours rotated so that M_a is lower-triangular: compare invariants
    np.testing.assert_allclose(np.linalg.norm(a_i, axis=1), np.linalg.norm(ours.accel, axis=1),
                               rtol=0, atol=1 * UG)
    np.testing.assert_allclose(np.linalg.norm(w_i, axis=1), np.linalg.norm(ours.gyro, axis=1),
                               rtol=0, atol=0.01 * DPH)
    np.testing.assert_allclose(np.sum(a_i * w_i, 1), np.sum(ours.accel * ours.gyro, 1),
                               rtol=0, atol=1e-9)
