"""Fleet on a real dask.distributed cluster: LocalCluster processes and a separate scheduler.

One simulated fleet (8 units x 3 logs, 3 drifting, 1 step) is written once; every test
runs the real CLI (``cli.main``) or ``fleet.runner`` on it.
"""

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import yaml

from thermal_imu_calib import cli
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.fleet import registry as reg
from thermal_imu_calib.fleet.inputs import expand_inputs, GroupBy
from thermal_imu_calib.fleet.simulate import FleetDesign, read_truth, simulate_fleet

DESIGN = FleetDesign(units=8, logs_per_unit=3, seed=0)


@pytest.fixture(scope='module')
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp('fleet') / 'logs'
    simulate_fleet(str(d), DESIGN)
    return str(d)


def _unit_logs(fleet, unit):
    return sorted(os.path.join(fleet, unit, n) for n in os.listdir(os.path.join(fleet, unit))
                  if n.endswith('.mcap'))


def _plain(cal):
    d = cal.to_dict()
    d.pop('created', None)
    return d


#: Dask's nanny starts workers with one BLAS/OpenMP thread (distributed.nanny
#: pre-spawn-environ); the reference runs the same way, so results agree bit for bit
#: (with a multi-threaded BLAS they differ in the 12th digit: summation order).
ONE_THREAD = {k: '1' for k in ('OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'OPENBLAS_NUM_THREADS')}


_REFERENCES = {}


def _reference(fleet, unit, tmp):
    """Calibrate one unit with the plain ``calibrate`` subcommand (a new process).

    Each unit's is computed once per module and loaded afresh from its file for every
    caller: the tests compare u00, u01 and u02 only (the subprocess takes ~10 s a unit).
    """
    key = (fleet, unit)
    if key not in _REFERENCES:
        out = os.path.join(tmp, f'ref_{unit}.yaml')
        subprocess.run([os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib'),
                        'calibrate', *_unit_logs(fleet, unit), '-o', out], check=True,
                       capture_output=True, env={**os.environ, **ONE_THREAD}, timeout=300)
        with open(out) as f:
            _REFERENCES[key] = f.read()
    return Calibration.from_yaml(_REFERENCES[key], f'the reference calibration of {unit}')


def _latest(registry, unit):
    return Calibration.load(reg.valid_at(registry, unit))


def test_local_cluster_equals_calibrate(fleet, tmp_path, capsys):
    registry = str(tmp_path / 'reg')
    manifest = tmp_path / 'logs.txt'
    # half the fleet (the other tests cover the rest): every unit's logs give one row
    units = [f'u{i:02d}' for i in range(DESIGN.units // 2)]
    manifest.write_text('# two units by glob, the others by directory\n'
                        f'{fleet}/u0[01]/*.mcap\n' + ''.join(
                            f'{fleet}/{u}\n' for u in units[2:]))
    assert cli.main(['fleet', 'calibrate', str(manifest), '--workers', '2',
                     '-o', registry]) == 0
    out = capsys.readouterr()
    assert 'dashboard http://' in out.err
    rows = reg.read_index(registry)
    assert sorted(r['sensor'] for r in rows) == units
    for r in rows:
        assert int(r['logs']) == DESIGN.logs_per_unit
        assert float(r['accel.alarm_b0.x_std']) > 0 and float(r['temp_max']) > float(r['temp_min'])
        assert r['time'] > r['valid_from']
    for unit in ('u00', 'u02'):     # by glob, by directory (references shared with others)
        assert _plain(_latest(registry, unit)) == _plain(_reference(fleet, unit, tmp_path))


def test_corrupt_log_reported_others_calibrated(fleet, tmp_path, capsys):
    work = tmp_path / 'logs'
    shutil.copytree(os.path.join(fleet, 'u01'), work / 'u01')
    shutil.copytree(os.path.join(fleet, 'u02'), work / 'u02')
    (work / 'u01' / 'broken.mcap').write_bytes(b'\x89MCAP0\r\n' + os.urandom(4000))
    bad = work / 'u02' / 'u02_log1.mcap'
    bad.write_bytes(bad.read_bytes()[:len(bad.read_bytes()) // 2])   # truncated copy
    registry = str(tmp_path / 'reg')
    code = cli.main(['fleet', 'calibrate', str(work), '--workers', '2',
                     '--by', r'path:/(u\d+)/', '-o', registry])
    cap = capsys.readouterr()
    out = cap.out
    assert code == 1, cap.err
    assert f'FAILED {work / "u01" / "broken.mcap"}: ' in out
    assert f'FAILED {bad}: ' in out
    rows = {r['sensor']: r for r in reg.read_index(registry)}
    assert sorted(rows) == ['u01', 'u02']
    assert int(rows['u01']['logs']) == 3 and int(rows['u02']['logs']) == 2
    cal = _latest(registry, 'u02')
    assert any('u02_log1.mcap was not used' in n for n in cal.notes)
    # the good logs of u01 give exactly what calibrate gives on them, plus one note
    got, ref = _plain(_latest(registry, 'u01')), _plain(_reference(fleet, 'u01', tmp_path))
    assert got.pop('notes')[:-1] == ref.pop('notes')
    assert got == ref


def _temperature_all_nan(a):
    a['temperature'][:] = np.nan


def _imu_stamps_duplicated(a):
    a['stamp_ns'][1::2] = a['stamp_ns'][::2][:len(a['stamp_ns'][1::2])]


def test_map_step_applies_the_input_gate(fleet, tmp_path, capsys):
    """A log ``calibrate`` refuses (test_hostile_cli's inputs) is refused by the map step too."""
    from _hostile import recording, write_bag
    work = tmp_path / 'logs'
    for unit in ('u01', 'u02'):
        shutil.copytree(os.path.join(fleet, unit), work / unit)
    imu, temp = recording()
    bad = {write_bag(str(work / 'u01' / 'nan_temperature.mcap'), imu, temp,
                     _temperature_all_nan): 'no usable reading',
           write_bag(str(work / 'u02' / 'stamps_duplicated.mcap'), imu, temp,
                     _imu_stamps_duplicated): 'do not increase'}
    for path, cause in bad.items():   # what calibrate says of the same log
        assert cli.main(['calibrate', path, '-o', str(tmp_path / 'one.yaml')]) == 2
        assert cause in capsys.readouterr().err
    registry = str(tmp_path / 'reg')
    code = cli.main(['fleet', 'calibrate', str(work), '--workers', '2',
                     '--by', r'path:/(u\d+)/', '-o', registry])
    out = capsys.readouterr().out
    assert code == 1, out
    for path, cause in bad.items():
        line = next(ln for ln in out.splitlines() if ln.startswith(f'FAILED {path}: '))
        assert cause in line and 'not used' in line
    rows = {r['sensor']: r for r in reg.read_index(registry)}
    assert sorted(rows) == ['u01', 'u02']
    assert all(int(r['logs']) == DESIGN.logs_per_unit for r in rows.values())
    # the refused log did not enter the reduction: u01 is what calibrate gives on its logs
    got, ref = _plain(_latest(registry, 'u01')), _plain(_reference(fleet, 'u01', tmp_path))
    notes = got.pop('notes')
    assert 'nan_temperature.mcap was not used' in notes[-1] and notes[:-1] == ref.pop('notes')
    assert got == ref


def _free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _wait(cond, timeout, what):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return
        time.sleep(0.2)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')


def test_separate_scheduler_and_two_workers(fleet, tmp_path, capsys):
    from distributed import Client
    port = _free_port()
    addr = f'tcp://127.0.0.1:{port}'
    dask = os.path.join(os.path.dirname(sys.executable), 'dask')
    log = open(tmp_path / 'dask.log', 'w')
    procs = [subprocess.Popen([dask, 'scheduler', '--host', '127.0.0.1', '--port', str(port),
                               '--dashboard-address', '127.0.0.1:0'],
                              stdout=log, stderr=subprocess.STDOUT)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([dask, 'worker', addr, '--nworkers', '1',
                                           '--nthreads', '1', '--host', '127.0.0.1',
                                           '--no-dashboard'],
                                          stdout=log, stderr=subprocess.STDOUT))

        def two_workers():
            try:
                with Client(addr, timeout='2s') as c:
                    return len(c.scheduler_info()['workers']) == 2
            except OSError:
                return False
        _wait(two_workers, 60, 'the scheduler and two workers')
        registry = str(tmp_path / 'reg')
        logs = [p for u in ('u01', 'u02') for p in _unit_logs(fleet, u)]
        assert cli.main(['fleet', 'calibrate', *logs, '--scheduler', addr,
                         '-o', registry]) == 0
        assert f'scheduler {addr}, 2 workers' in capsys.readouterr().err
        for unit in ('u01', 'u02'):
            assert _plain(_latest(registry, unit)) == _plain(_reference(fleet, unit, tmp_path))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        log.close()


def test_worker_killed_mid_job_loses_nothing(fleet, tmp_path):
    from distributed import Client, LocalCluster
    from thermal_imu_calib.fleet.runner import run_fleet
    from thermal_imu_calib.app.fleet import calibrate_unit
    from thermal_imu_calib.cli.fleet import fleet_settings
    import functools
    units = ('u00', 'u01', 'u02')   # the units other tests compare too (one reference each)
    logs = [p for u in units for p in _unit_logs(fleet, u)]
    args = cli.build_parser().parse_args(['fleet', 'calibrate', *logs, '-o', '-'])
    reduce_fn = functools.partial(calibrate_unit, fleet_settings(args), None)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=':0') as cluster, Client(cluster) as client:
        pids = client.run(os.getpid)
        box = {}
        job = threading.Thread(target=lambda: box.update(out=run_fleet(
            client, logs, GroupBy('frame_id'), reduce_fn, {})))
        job.start()

        def some_done():
            return client.run_on_scheduler(
                lambda dask_scheduler: sum(ts.state == 'memory'
                                           for ts in dask_scheduler.tasks.values())) >= 2
        _wait(some_done, 120, 'two finished tasks')
        assert job.is_alive(), 'the job ended before a worker could be killed'
        victim = sorted(pids.values())[0]
        os.kill(victim, signal.SIGKILL)
        job.join(timeout=300)
        assert not job.is_alive()
        assert victim not in client.run(os.getpid).values()
    results, failed = box['out']
    assert not failed
    assert [u.sensor for u in results] == list(units)
    for u in results:
        assert not u.error and len(u.logs) == 3
        assert _plain(u.result.calibration) == _plain(_reference(fleet, u.sensor, tmp_path))


def test_alarms_history_and_compensate(fleet, tmp_path, capsys):
    registry = str(tmp_path / 'reg')
    assert cli.main(['fleet', 'calibrate', fleet, '--workers', '2', '--period', '20',
                     '-o', registry]) == 0
    rows = reg.read_index(registry)
    assert len(rows) == DESIGN.units * DESIGN.logs_per_unit
    truth = read_truth(fleet)
    flagged = {s for s, a in reg.alarms(rows).items() if a}
    assert flagged == {u for u, t in truth.items() if t['kind'] != 'stable'}
    step = next(u for u, t in truth.items() if t['kind'] == 'step')
    capsys.readouterr()
    html = tmp_path / 'h.html'
    assert cli.main(['history', registry, '--sensor', step, '--html', str(html)]) == 0
    text = capsys.readouterr().out
    assert f'{step}: {DESIGN.logs_per_unit} calibrations  ALARM' in text
    assert text.startswith('alarm rule: ') and '1 % family-wise false-alarm rate' in text
    assert f'db0 {"xyz"[int(truth[step]["step_axis"])]} changed' in text
    page = html.read_text()
    assert '<svg' in page and '1 % family-wise false-alarm rate' in page

    # compensate: every log with the calibration of its own period, outputs mirror the tree
    out_dir = tmp_path / 'out'
    logs = _unit_logs(fleet, step)
    assert cli.main(['fleet', 'compensate', *logs, os.path.join(fleet, 'u01'),
                     '--registry', registry, '--workers', '2', '-o', str(out_dir)]) == 0
    text = capsys.readouterr().out
    times = sorted(r['time'] for r in rows if r['sensor'] == step)
    for k, path in enumerate(logs):
        dst = out_dir / step / os.path.basename(path)
        assert dst.is_file()
        assert f'{dst}: ' in text and f'{step}/{times[k]}.yaml' in text
    assert len(list((out_dir / 'u01').glob('*.mcap'))) == DESIGN.logs_per_unit
    assert not [p for p in out_dir.rglob('.tmp-*')]
    # identical to the single-log compensate with that calibration
    single = tmp_path / 'single.mcap'
    cal = os.path.join(registry, step, times[-1] + '.yaml')
    assert cli.main(['compensate', logs[-1], '--calibration', cal, '-o', str(single)]) == 0
    assert _imu_values(single) == _imu_values(out_dir / step / os.path.basename(logs[-1]))
    # a second run refuses to overwrite
    assert cli.main(['fleet', 'compensate', logs[0], '--registry', registry,
                     '-o', str(out_dir / step)]) == 2


def test_a_fleet_without_a_temperature_is_calibrated_and_indexed(tmp_path, capsys):
    """Logs without a temperature (a posing session of a driver that publishes none).

    Each is calibrated temperature-independent; its index row has no temperature span and
    ``history`` reads it. Until 2026-12-03 the index row read the span None as an array and
    ``fleet calibrate`` ended in "cannot reshape array of size 1 into shape (2)".
    """
    from thermal_imu_calib.io.bag import write_columns
    from thermal_imu_calib.io.csv_logs import read_mpu6050_csv
    fix = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'fixtures', 'real',
                       'mpu6050_tomisuarez', 'example_data_calibration.csv.gz')
    logs = tmp_path / 'logs'
    logs.mkdir()
    write_columns(str(logs / 'mpu.mcap'), '/imu', read_mpu6050_csv(fix).imu)
    registry = str(tmp_path / 'reg')
    assert cli.main(['fleet', 'calibrate', str(logs), '--workers', '1', '--gravity', '9.81',
                     '-o', registry]) == 0
    rows = reg.read_index(registry)
    assert len(rows) == 1 and rows[0]['temp_min'] == rows[0]['temp_max'] == 'nan'
    cal = Calibration.load(os.path.join(registry, rows[0]['file']))
    assert cal.inputs == [] and cal.fit['temperature_span'] is None
    capsys.readouterr()
    assert cli.main(['history', registry]) == 0
    assert '1 calibrations' in capsys.readouterr().out


def _imu_values(path):
    from thermal_imu_calib.io.bag import open_log
    with open_log(path) as r:
        chunks = list(r.stream('/imu/data_compensated', [], 100000))
    a = np.concatenate([c.imu.accel for c in chunks])
    return a.round(12).tolist()


def test_inputs_and_registry_lookup(fleet, tmp_path):
    paths = expand_inputs([os.path.join(fleet, 'u0[0-1]', '*.mcap'), os.path.join(fleet, 'u00')])
    assert len(paths) == 2 * DESIGN.logs_per_unit
    with pytest.raises(ValueError, match='matches nothing'):
        expand_inputs([os.path.join(fleet, 'nope*', '*.mcap')])
    with pytest.raises(ValueError, match='--by'):
        GroupBy.parse('metadata')
    assert GroupBy.parse(r'path:/(u\d+)/').sensor_id(paths[0]) == 'u00'
    # registry lookup by time: oldest/newest and a time between
    d = tmp_path / 'r'
    cal = Calibration.load(os.path.join(fleet, 'u00', 'u00_log0.mcap.truth.yaml'))
    day = 86400 * 10 ** 9
    reg.add(str(d), [('u00', cal, 10 * day, 9 * day, ['a']),
                     ('u00', cal, 40 * day, 39 * day, ['b'])])
    assert reg.valid_at(str(d), 'u00', 5 * day).endswith(reg.iso(10 * day) + '.yaml')
    assert reg.valid_at(str(d), 'u00', 39 * day + 1).endswith(reg.iso(40 * day) + '.yaml')
    assert reg.valid_at(str(d), 'u00').endswith(reg.iso(40 * day) + '.yaml')
    with pytest.raises(LookupError, match='no calibration'):
        reg.valid_at(str(d), 'u99')
    idx = yaml.safe_load(open(os.path.join(d, 'u00', reg.iso(10 * day) + '.yaml')))
    assert idx['accel']['kind'] == cal.accel.kind


def _synthetic_rows(rng, units, cals, sigma, drift=0.0, prefix='u'):
    """Index rows of a fleet whose true db0/dk0 are constant (+ ``drift`` per 30 days)."""
    day = 86400 * 10 ** 9
    rows = []
    for u in range(units):
        for k in range(cals):
            r = {'sensor': f'{prefix}{u:02d}', 'time': reg.iso((30 * k + 1) * day),
                 'accel_model': 'field_polynomial', 'residual_rms_mps2': '5e-4'}
            for a in 'xyz':
                r[f'accel.T0.{a}'] = 30.0 + rng.normal(0, 0.3)
                for name, s, d in (('db0', sigma, drift * k), ('dk0', 1e-4, 0.0)):
                    r[f'accel.{name}.{a}'] = d + rng.normal(0, s)
                    r[f'accel.{name}.{a}_std'] = s
            rows.append(r)
    return rows


def test_alarm_statistic_keeps_its_family_rate_and_matches_numpy():
    """Honest stds: a stable fleet is flagged at about the stated family rate; trend = polyfit."""
    rng = np.random.default_rng(14)
    scale = {'b': 1.0, 'k': 1.0}
    n_fleets = 400
    flagged = sum(any(reg.assess(_synthetic_rows(rng, 20, 5, 1e-3), std_scale=scale)[0].values())
                  for _ in range(n_fleets))
    # expected 4 of 400 at 1 %; Poisson(4) exceeds 12 with probability 1e-3
    assert flagged <= 12
    assert reg.family_threshold(1, 0.05) == pytest.approx(1.959964, abs=1e-5)
    # the trend z is numpy's weighted polyfit slope over its std
    rows = _synthetic_rows(rng, 1, 5, 1e-3, drift=2e-3, prefix='drifting')
    z = reg.trend(rows, 'b', scale)
    t = np.array([reg.parse_time(r['time']) for r in rows]) / 86400e9
    t_ref = np.mean([[r[f'accel.T0.{a}'] for a in 'xyz'] for r in rows], axis=0)
    vs = np.array([reg.at_temperature(r, 'b', t_ref) for r in rows])
    for i in range(3):
        p, cov = np.polyfit(t, vs[:, 0, i], 1, w=1 / vs[:, 1, i], cov='unscaled')
        assert z[i] == pytest.approx(p[0] / np.sqrt(cov[0, 0]), rel=1e-9)
    # a drift of 2 sigma per 30 days: no consecutive change is, the trend over 5 is flagged
    found = reg.assess(rows + _synthetic_rows(rng, 19, 5, 1e-3), std_scale=scale)[0]
    assert found['drifting00'] and all('trend' in a for a in found['drifting00'])


def _gyro_rows(rng, units, cals, sigma, scale_true=1.8, step=None):
    """Index rows with gyro-bias alarm terms whose stated std is ``scale_true`` too small."""
    day = 86400 * 10 ** 9
    rows = []
    for u in range(units):
        for k in range(cals):
            r = {'sensor': f'g{u:02d}', 'time': reg.iso((30 * k + 1) * day),
                 'accel_model': 'field_polynomial', 'gyro_model': 'whole_unit_gyro',
                 'residual_rms_mps2': '5e-4'}
            for a in 'xyz':
                r[f'gyro.alarm_T0.{a}'] = 30.0
                jump = step if (step is not None and u == 0 and k >= cals // 2) else 0.0
                r[f'gyro.alarm_b0.{a}'] = jump + rng.normal(0, scale_true * sigma)
                r[f'gyro.alarm_b0.{a}_std'] = sigma
            rows.append(r)
    return rows


def test_gyro_bias_is_tested_in_units_of_its_own_spread():
    """Stds 1.8x too small: the empirical null keeps a stable fleet quiet; a step is found."""
    rng = np.random.default_rng(3)
    flagged = sum(any(reg.assess(_gyro_rows(rng, 10, 4, 1e-5))[0].values()) for _ in range(100))
    assert flagged <= 6            # ~1 expected at the 1 % family rate
    rows = _gyro_rows(rng, 10, 4, 1e-5, step=3e-4)
    found, info = reg.assess(rows)
    assert 1.4 < info['gyro_scale'] < 2.4
    assert 'the gyro bias (its z divided by their robust spread' in info['rule']
    assert found['g00'] and all(a.startswith(('gyro db0', '... and')) for a in found['g00'])
    assert any('changed 19700201T000000Z -> 19700303T000000Z' in a for a in found['g00'])
    assert not any(v for s, v in found.items() if s != 'g00')
    # too few gyro tests to measure their spread: the gyro is not tested, and said so
    few, info = reg.assess(_gyro_rows(rng, 1, 2, 1e-5, step=3e-4))
    assert info['gyro_scale'] is None and not few['g00']
    assert 'the gyro bias is not tested' in info['rule']


def test_alarm_terms_of_a_gyro_and_of_a_relative_offset():
    """A g-sensitive gyro is probed at zero g; an offset model's bias at T0 is no measurement."""
    from thermal_imu_calib.models.alarm_terms import bias_scale_terms, relative_bias
    from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
    coeffs = np.array([[1e-3, -2e-3, 5e-4], [1e-5, 2e-5, -1e-5]])
    std = np.full_like(coeffs, 1e-6)
    absolute = OffsetPolynomialModel([30.0] * 3, coeffs, 'gyro', True, std)
    t = bias_scale_terms(absolute)
    np.testing.assert_allclose(t['b'][:, 0], coeffs[0], atol=1e-15)
    np.testing.assert_allclose(t['b'][:, 1], coeffs[1], atol=1e-12)
    np.testing.assert_allclose(t['b_std'][:, 0], std[0], rtol=1e-6)
    relative = OffsetPolynomialModel([30.0] * 3, coeffs.copy(), 'accel', False, std)
    assert relative_bias(relative) and not relative_bias(absolute)
    r = bias_scale_terms(relative)
    assert np.all(np.isnan(r['b'][:, 0])) and np.all(np.isnan(r['b_std'][:, 0]))
    np.testing.assert_allclose(r['b'][:, 1], coeffs[1], atol=1e-12)
