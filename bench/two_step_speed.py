"""The two-step estimation's sweeps: the plain alternation against Anderson mixing.

``fit_field_model`` repeats the seed 000 paper's two steps (thermal vector given the tilts,
tilts given the thermal vector) until a sweep moves the fitted window means by less than
``tol`` of their noise. Before 2026-12-07 that was the plain alternation with ``tol``
1e-3; since, the sweeps are mixed (``estimation.fixed_point``) with ``tol`` 1e-5.

This runs ``calibrate`` with its default options on a simulated three-log fleet unit
(``fleet.simulate``, seed 0, unit u00), on test_standard_floor's session of six faces held
twice along a warm-up (two seeds), on the repository's MPU-6050 fixture and, where
``../shared/data/real`` is present, on every multi-pose real recording of the scoreboard
(``real_recordings``). Every two-step fit ``calibrate`` asks for is recorded and re-run
three ways without the joint refinement: plain at tol 1e-3 (``ANDERSON_DEPTH`` 0: the
code before, bit for bit), mixed at the default tol, and mixed at tol 1e-10 (the fixed
point). For each it prints the sweeps, the seconds and how far its fitted window means are
from the fixed point's (max over windows and axes, in units of each mean's standard error).

    .venv/bin/python bench/two_step_speed.py [--out bench/results/two_step_speed.json]
"""

import argparse
import contextlib
import functools
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, '..'))
sys.path.insert(0, HERE)

from thermal_imu_calib import cli  # noqa: E402
from thermal_imu_calib.estimation import builtin_estimators, field_estimator as fe  # noqa: E402
from thermal_imu_calib.estimation import fixed_point  # noqa: E402
from thermal_imu_calib.selection import multi_select  # noqa: E402

EXACT_TOL = 1e-10
EXACT_MAX_ITER = 20000


def _record(args):
    """Run ``calibrate`` on ``args`` (its command-line arguments, or a callable that
    calibrates); return the (args, kwargs) of every two-step fit it asked for."""
    calls = []
    original = fe.fit_field_model

    def recording(*a, **k):
        calls.append((a, k))
        return original(*a, **k)
    builtin_estimators.fit_field_model = multi_select.fit_field_model = recording
    try:
        with open(os.devnull, 'w') as null, contextlib.redirect_stdout(null), \
                contextlib.redirect_stderr(null):
            code = args() if callable(args) else cli.main(['calibrate', *args])
    finally:
        builtin_estimators.fit_field_model = multi_select.fit_field_model = original
    if code:
        raise SystemExit(f'calibrate {args} exited {code}')
    return calls


def _run(a, k, depth, **extra):
    """Fit without the joint refinement; return (fit, seconds)."""
    kw = {**k, 'refine': False, 'free_s': False, **extra}
    saved = fixed_point.ANDERSON_DEPTH
    fixed_point.ANDERSON_DEPTH = depth
    try:
        t = time.perf_counter()
        fit = fe.fit_field_model(*a, **kw)
        return fit, time.perf_counter() - t
    finally:
        fixed_point.ANDERSON_DEPTH = saved


def _se(w):
    """Return (m, 3) standard errors of the window means, m/s^2 (``fit_field_model``'s)."""
    return np.sqrt(np.maximum(w.accel_var, 1e-30) / w.n[:, None])


def _means(fit, a):
    """Return (m, 3) fitted window means, m/s^2, of ``fit`` on its arguments ``a``."""
    w = a[0]
    hold_idx = np.unique(w.hold, return_inverse=True)[1]
    return fit.model.forward(a[2] * fit.tilts[hold_idx], np.asarray(a[1], float))


def compare(a, k):
    """Return the three runs of one recorded fit as a dict."""
    w = a[0]
    se = _se(w)
    exact, t_exact = _run(a, k, fixed_point.ANDERSON_DEPTH, tol=EXACT_TOL, max_iter=EXACT_MAX_ITER)
    ref = _means(exact, a)
    row = {'windows': int(len(w.n)), 'holds': int(len(np.unique(w.hold))),
           'fixed_point': {'sweeps': exact.iterations, 'converged': bool(exact.converged),
                           'seconds': round(t_exact, 3)}}
    for name, depth, tol in (('plain_tol_1e-3', 0, 1e-3),
                             ('mixed_default_tol', fixed_point.ANDERSON_DEPTH, None)):
        fit, sec = _run(a, k, depth, **({} if tol is None else {'tol': tol}))
        row[name] = {'sweeps': fit.iterations, 'converged': bool(fit.converged),
                     'seconds': round(sec, 3),
                     'se_from_fixed_point': float(np.max(np.abs(_means(fit, a) - ref) / se))}
    return row


def cases(work):
    """Yield (name, calibrate arguments)."""
    from thermal_imu_calib.fleet.simulate import FleetDesign, simulate_fleet
    fleet = os.path.join(work, 'fleet')
    simulate_fleet(fleet, FleetDesign(units=1, logs_per_unit=3, seed=0))
    unit = os.path.join(fleet, 'u00')
    yield 'simulated fleet unit u00 (3 logs)', sorted(
        os.path.join(unit, n) for n in os.listdir(unit) if n.endswith('.mcap'))
    sys.path.insert(0, os.path.join(HERE, '..', 'test'))
    from test_standard_floor import _session, options
    from thermal_imu_calib.estimation.calibrate import calibrate_windows

    def six_faces_twice(seed):
        calibrate_windows(_session(1e-4, visits=2, seed=seed), options())
        return 0
    for seed in (0, 1):
        yield (f'six faces twice along a 20-40 degC warm-up (test_standard_floor, seed {seed})',
               functools.partial(six_faces_twice, seed))
    import real_recordings
    from thermal_imu_calib.io.bag_writer import write_columns
    from thermal_imu_calib.io.columns import ImuColumns
    from thermal_imu_calib.io.csv_logs import read_mpu6050_csv
    m = read_mpu6050_csv(os.path.join(HERE, '..', 'test', 'fixtures', 'real',
                                      'mpu6050_tomisuarez', 'example_data_calibration.csv.gz'))
    imu = ImuColumns(m.imu.stamp_ns + real_recordings.T0_NS, m.imu.accel, m.imu.gyro, 'mpu6050')
    log = os.path.join(work, 'mpu6050_fixture.mcap')
    write_columns(log, '/imu', imu, {real_recordings.TEMP_TOPIC:
                                     real_recordings.flat_temperature(imu)})
    yield 'MPU-6050 fixture (test/fixtures/real, room temperature)', [
        log, '--imu-topic', '/imu', '--gravity', '9.81',
        '--temperature-topic', real_recordings.TEMP_TOPIC]
    if not os.path.isdir(real_recordings.REAL):
        return
    for rec in real_recordings.all_recordings(os.path.join(work, 'real')):
        if rec.kind != 'multi':
            continue
        args = [rec.log, '--imu-topic', rec.imu_topic, '--gravity', repr(rec.gravity)]
        if rec.temperature_topic:
            args += ['--temperature-topic', rec.temperature_topic]
        yield rec.name, args


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', default=os.path.join(HERE, 'results', 'two_step_speed.json'))
    args = ap.parse_args(argv)
    out = {'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime()),
           'anderson_depth': fixed_point.ANDERSON_DEPTH, 'exact_tol': EXACT_TOL, 'recordings': {}}
    with tempfile.TemporaryDirectory() as work:
        for name, cal_args in cases(work):
            calls = _record(cal_args if callable(cal_args)
                            else [*cal_args, '-o', os.path.join(work, 'out.yaml')])
            rows = [compare(a, k) for a, k in calls]
            out['recordings'][name] = rows
            for r in rows:
                p, m = r['plain_tol_1e-3'], r['mixed_default_tol']
                print(f'{name[:40]:40s} {r["windows"]:4d} windows: plain {p["sweeps"]:5d} '
                      f'sweeps {p["seconds"]:6.2f} s {p["se_from_fixed_point"]:8.1e} se | '
                      f'mixed {m["sweeps"]:4d} sweeps {m["seconds"]:5.2f} s '
                      f'{m["se_from_fixed_point"]:8.1e} se | fixed point '
                      f'{r["fixed_point"]["sweeps"]} sweeps', flush=True)
    rows = [r for rs in out['recordings'].values() for r in rs]
    out['totals'] = {k: {'seconds': round(sum(r[k]['seconds'] for r in rows), 2),
                         'sweeps': sum(r[k]['sweeps'] for r in rows),
                         'not_converged': sum(not r[k]['converged'] for r in rows),
                         'max_se_from_fixed_point': max(r[k]['se_from_fixed_point']
                                                        for r in rows)}
                     for k in ('plain_tol_1e-3', 'mixed_default_tol')}
    out['totals']['fixed_point_not_converged'] = sum(not r['fixed_point']['converged']
                                                     for r in rows)
    print(json.dumps(out['totals'], indent=1))
    with open(args.out, 'w') as f:
        json.dump(out, f, indent=1)
    print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
