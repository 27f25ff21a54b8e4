"""Whole-unit (seed 002) calibration of a simulated MEMS cold start, judged on a second one.

Device: ``sim.draw_device('mems', seed)`` (the device of every ``mems-*`` scenario): seed
000 accelerometer thermal errors with a skewed S (misalignment 2e-4..8e-4 rad, about
5e-4), accel noise 150 ug/sqrt(Hz), 16-bit quantisation, die temperature published at 1 Hz
in 0.125 degC steps; gyro thermal bias, scale errors 1-4e-3, misalignment 0.3-1.5e-3 rad and
g-sensitivity 1.8e-5..7e-5 rad/s per m/s^2 per element (0.01-0.04 deg/s/g, seed 002
Table 2), all from the simulator (``sim.DEVICES['mems']``).

Calibration: one ``mems-coldstart-poses`` cold start (~65 min, 13 x (six faces + 4
corner-up poses), 15-20 s holds for three rounds then 25-35 s; ``--scenario`` picks another,
``--cold-starts N`` merges N cold starts of the same device) through the ``whole_unit``
estimator (stationary windows + the pose changes from ``gyro_fit.MotionCollector``,
latitude 45 deg given). Validation: ``mems-validation`` (the same device, a further cold
start, eight 5.5-6 min holds). Per validation hold: the static *vector* error
|mean(a) - g up| (up from the schedule, in the true sensor frame; the whole-unit frame
convention, A1 lower-triangular, is the simulator's frame p, so the two compare directly;
the table also gives the error after the best common rotation is removed), the
gravity-norm error, and the gyro bias residual |mean(w) - true rate| (true rate = earth
rate in the body frame). "truth" applies the true parameters; its error is the validation
floor (mostly accel white noise in the 5.5-min averages); "field" is the seed 000
estimator on the same windows, for reference. ``--calibration-noise-scale`` scales the
accel noise of the calibration recordings only (a diagnostic: is the result limited by
the information in the data?).

Usage: ``python bench/bench_mems.py [--seeds 0 1 2 ...] [--cold-starts N] [--json FILE]``
"""

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (CalibrateOptions,  # noqa: E402
                                                    calibrate_windows)
from thermal_imu_calib.collection.metrics import WindowAccumulator  # noqa: E402
from thermal_imu_calib.collection.motion import collect_motion  # noqa: E402
from thermal_imu_calib.collection.segments import Windows  # noqa: E402
from thermal_imu_calib.collection.stationary import DetectorConfig  # noqa: E402
from thermal_imu_calib.io.align import StreamAligner  # noqa: E402
from thermal_imu_calib.io.columns import TemperatureColumns  # noqa: E402

LATITUDE = 45.0          # the scenarios' latitude
SCENARIO = 'mems-coldstart-poses'
RESIDUAL = 'norm'
N_COLDSTARTS = 1
#: accel noise of the calibration recordings relative to the device's (diagnostic)
NOISE_SCALE = 1.0


def aligned(rec, chunks):
    """Resolve the published temperature readings at the IMU stamps (as the CLI does)."""
    topics = list(rec.temperatures)
    al = StreamAligner(len(topics))
    first = True
    for imu in chunks:
        temps = [rec.temperatures[t] if first else TemperatureColumns.empty() for t in topics]
        first = False
        yield from al.push_columns(imu, temps)
    yield from al.finish()


def coldstarts(seed, n):
    """Return n simulated cold starts of device ``seed`` (distinct recordings, same device)."""
    base = sim.SCENARIOS[SCENARIO]
    out = []
    for i in range(n):
        cfg = dataclasses.replace(base, name=base.name if i == 0 else f'{base.name}-{i + 1}')
        rec = sim.simulate(cfg, seed)
        if NOISE_SCALE != 1.0:
            spec = rec.device.spec
            rec.device = dataclasses.replace(rec.device, spec=dataclasses.replace(
                spec, accel_noise_density=spec.accel_noise_density * NOISE_SCALE))
        out.append(rec)
    return out


def calibrate(recs, model='whole_unit'):
    """Collect windows and pose changes of the cold starts; return (result, collection info)."""
    t0 = time.perf_counter()
    parts, transitions, peak = [], [], 0
    offset = 0
    for rec in recs:
        w, tr, col = collect_motion(aligned(rec, rec.imu_chunks()),
                                    DetectorConfig(), len(rec.temperatures))
        w.hold = w.hold + offset                         # keep hold ids distinct
        for t in tr:
            t.hold_from += offset
            t.hold_to += offset
        offset = int(w.hold.max()) + 1
        parts.append(w)
        transitions += tr
        peak = max(peak, col.memory_bytes())
    windows = Windows.concat(parts)
    t_collect = time.perf_counter() - t0
    rec = recs[0]
    opts = CalibrateOptions(model=model, gravity=rec.gravity, inputs=list(rec.truth.inputs),
                            latitude=LATITUDE, transitions=transitions,
                            whole_unit_residual=RESIDUAL)
    t1 = time.perf_counter()
    res = calibrate_windows(windows, opts)
    minutes = round(float(sum(r.duration for r in recs)) / 60, 1)
    return res, {'cold_starts': len(recs), 'minutes': minutes,
                 'windows': len(windows), 'holds': int(len(np.unique(windows.hold))),
                 'transitions': len(transitions), 'collector_kb': round(peak / 1e3, 1),
                 'collect_s': round(t_collect, 2), 'fit_s': round(time.perf_counter() - t1, 2)}


def validation_windows(rec):
    """Return (windows, true specific force means, true rate means) of the validation run."""
    windows, _, _ = collect_motion(aligned(rec, rec.imu_chunks()),
                                   DetectorConfig(), len(rec.temperatures))
    acc = WindowAccumulator(windows.t0, windows.t1)
    for tc in rec.truth_chunks():
        acc.add(tc.stamp_ns * 1e-9, {'f': tc.specific_force, 'w': tc.angular_rate})
    return windows, acc.means('f'), acc.means('w')


def best_rotation(a, b):
    """Return the rotation R minimising sum |R a_i - b_i|^2 (Kabsch)."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def metrics(windows, cal, f_true, w_true, g):
    """Per-hold static errors of one calibration (None: raw) on validation windows."""
    temps = windows.temp if windows.n_inputs else None
    if cal is None:
        a, w = windows.accel, windows.gyro
    else:
        res = cal.apply(windows.accel, windows.gyro, temps)
        a, w = res.accel, res.gyro
    ids = windows.hold_ids
    am, fm, wm, tm = (np.zeros((len(ids), 3)) for _ in range(4))
    for j, h in enumerate(ids):
        m = windows.hold == h
        wt = windows.n[m]
        am[j] = np.average(a[m], 0, wt)
        fm[j] = np.average(f_true[m], 0, wt)
        wm[j] = np.average(w[m], 0, wt)
        tm[j] = np.average(w_true[m], 0, wt)
    vec = np.linalg.norm(am - fm, axis=1)
    rot = best_rotation(am, fm)
    vec_rot = np.linalg.norm(am @ rot.T - fm, axis=1)
    norm = np.linalg.norm(am, axis=1) - np.linalg.norm(fm, axis=1)
    gyro = np.linalg.norm(wm - tm, axis=1)
    ug = 1e6 / g

    def rms(x):
        return float(np.sqrt(np.mean(np.square(x))))
    return {'vector_error_ug': rms(vec) * ug, 'vector_error_max_ug': float(vec.max() * ug),
            'vector_error_rotation_removed_ug': rms(vec_rot) * ug,
            'norm_error_ug': rms(norm) * ug, 'gyro_bias_residual_rad_s': rms(gyro),
            'gyro_bias_residual_max_rad_s': float(gyro.max()),
            'rotation_removed_deg': float(np.degrees(np.arccos(np.clip(
                (np.trace(rot) - 1) / 2, -1, 1))))}


def run_seed(seed, n_coldstarts=N_COLDSTARTS):
    """Calibrate on cold starts of device ``seed`` and validate on one more cold start."""
    recs = coldstarts(seed, n_coldstarts)
    rec = recs[0]
    res, info = calibrate(recs)
    field_res, _ = calibrate(recs, 'field')
    val = sim.simulate('mems-validation', seed)
    vw, f_true, w_true = validation_windows(val)
    truth = dataclasses.replace(
        rec.truth, valid_range=np.array([[-80.0, 200.0]] * len(rec.truth.inputs)),
        out_of_range='extrapolate')
    cals = {'raw': None, 'truth': truth, 'whole_unit': res.calibration,
            'field (seed 000)': field_res.calibration}
    out = {'seed': seed, 'calibration': info,
           'validation_holds': int(len(np.unique(vw.hold))),
           'summary': res.summary,
           'notes': res.calibration.notes,
           'coefficients': {k: res.calibration.fit[k] for k in
                            ('accel_estimated', 'accel_fixed', 'gyro_estimated',
                             'gyro_fixed')},
           'metrics': {k: metrics(vw, c, f_true, w_true, val.gravity) for k, c in cals.items()}}
    est, tru = res.calibration.gyro, rec.truth.gyro
    out['gyro_errors'] = {
        'Omega1_max_abs': float(np.max(np.abs(est.m1 - tru.m1))),
        'C_max_abs': float(np.max(np.abs(est.coupling - tru.coupling))),
        'C_truth_max_abs': float(np.max(np.abs(tru.coupling)))}
    m = out['metrics']
    out['ratios'] = {
        'vector_error_vs_truth': (m['whole_unit']['vector_error_ug']
                                  / m['truth']['vector_error_ug']),
        'gyro_bias_vs_truth': (m['whole_unit']['gyro_bias_residual_rad_s']
                               / m['truth']['gyro_bias_residual_rad_s'])}
    return out


def table(results):
    """Render the per-seed results as markdown."""
    rows = ['| seed | calibration | vector error RMS [ug] | vector, rotation removed [ug] | '
            '|a|-g RMS [ug] | gyro bias residual RMS [rad/s] |',
            '|---|---|---|---|---|---|']
    for r in results:
        for label, m in r['metrics'].items():
            rows.append(f'| {r["seed"]} | {label} | {m["vector_error_ug"]:.1f} | '
                        f'{m["vector_error_rotation_removed_ug"]:.1f} | '
                        f'{m["norm_error_ug"]:.1f} | {m["gyro_bias_residual_rad_s"]:.2e} |')
    rows.append('')
    rows.append('| seed | vector error / truth | gyro bias residual / truth | coefficients '
                'estimated / fixed (accel, gyro) | holds, pose changes used | fit time [s] |')
    rows.append('|---|---|---|---|---|---|')
    for r in results:
        c = r['coefficients']
        rows.append(f'| {r["seed"]} | {r["ratios"]["vector_error_vs_truth"]:.2f} | '
                    f'{r["ratios"]["gyro_bias_vs_truth"]:.2f} | {c["accel_estimated"]}/'
                    f'{c["accel_fixed"]}, {c["gyro_estimated"]}/{c["gyro_fixed"]} | '
                    f'{r["calibration"]["holds"]}, {r["calibration"]["transitions"]} | '
                    f'{r["calibration"]["fit_s"]} |')
    return '\n'.join(rows)


def main(argv=None):
    """Run the benchmark and print the tables (``--json FILE`` writes the figures)."""
    global RESIDUAL, SCENARIO, NOISE_SCALE
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=list(range(7)))
    ap.add_argument('--scenario', default=SCENARIO, choices=sorted(
        n for n in sim.SCENARIOS if n.startswith('mems-coldstart')),
        help=f'calibration scenario (default {SCENARIO})')
    ap.add_argument('--cold-starts', type=int, default=N_COLDSTARTS,
                    help='cold starts of the device merged for the calibration (default 1)')
    ap.add_argument('--calibration-noise-scale', type=float, default=1.0, metavar='X',
                    help='scale the accel noise of the calibration recordings (diagnostic)')
    ap.add_argument('--residual', choices=('norm', 'vector'), default='norm',
                    help='accelerometer residual of the whole-unit fit (default norm)')
    ap.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    RESIDUAL, SCENARIO = args.residual, args.scenario
    NOISE_SCALE = args.calibration_noise_scale
    results = []
    for s in args.seeds:
        results.append(run_seed(s, args.cold_starts))
        r = results[-1]['ratios']
        print(f'seed {s}: vector error / truth {r["vector_error_vs_truth"]:.2f}, gyro bias '
              f'residual / truth {r["gyro_bias_vs_truth"]:.2f}', file=sys.stderr, flush=True)
    print(table(results))
    rv = [r['ratios']['vector_error_vs_truth'] for r in results]
    rg = [r['ratios']['gyro_bias_vs_truth'] for r in results]
    summary = {'scenario': SCENARIO, 'cold_starts': args.cold_starts,
               'calibration_noise_scale': NOISE_SCALE, 'residual': RESIDUAL,
               'seeds': list(args.seeds),
               'median_vector_ratio': float(np.median(rv)), 'worst_vector_ratio': max(rv),
               'seeds_vector_within_2x': int(sum(v <= 2 for v in rv)),
               'median_gyro_ratio': float(np.median(rg)), 'worst_gyro_ratio': max(rg),
               'seeds_gyro_within_3x': int(sum(v <= 3 for v in rg))}
    print(f'\n{SCENARIO} x {args.cold_starts}: vector error / truth median '
          f'{summary["median_vector_ratio"]:.2f}, worst {max(rv):.2f}, '
          f'{summary["seeds_vector_within_2x"]}/{len(rv)} seeds within 2x; gyro bias residual '
          f'/ truth median {summary["median_gyro_ratio"]:.2f}, worst {max(rg):.2f}, '
          f'{summary["seeds_gyro_within_3x"]}/{len(rg)} within 3x; '
          f'{time.perf_counter() - t0:.0f} s')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'benchmark': 'bench_mems', **summary, 'results': results}, f,
                      indent=1, default=float)
    return 0


if __name__ == '__main__':
    sys.exit(main())
