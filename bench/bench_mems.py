"""Whole-unit (seed 002) calibration of a simulated MEMS cold start, judged on a second one.

Device: ``sim.draw_device('mems', seed)`` (the device of the ``mems-coldstart`` and
``mems-validation`` scenarios): seed 000 accelerometer thermal errors with a skewed S
(misalignment 2e-4..8e-4 rad, about 5e-4), 16-bit quantisation, die temperature published
at 1 Hz in 0.125 degC steps. The simulator has no gyro scale/misalignment or g-sensitivity,
so this bench adds them on top of the simulated kinematics (``truth_chunks``): gyro scale
errors 1-4e-3, misalignment 0.3-1.5e-3 rad, g-sensitivity 1.8e-5..7e-5 rad/s per m/s^2
per element (0.01-0.04 deg/s/g, seed 002 Table 2), plus the simulated gyro thermal bias.

Calibration: ``mems-coldstart`` with diverse poses (3 x (six faces + 4 corner-up poses),
60-90 s holds, hand-made pose changes) through the ``whole_unit`` estimator (stationary
windows + the pose changes from ``gyro_fit.MotionCollector``, latitude 45 deg given).
Validation: ``mems-validation`` (the same device, a second cold start, 5.5-6 min holds).
Per validation hold: the static *vector* error |mean(a) - g up| (up from the schedule, in
the true sensor frame; the whole-unit frame convention, A1 lower-triangular, is the
simulator's frame p, so the two compare directly; the table also gives the error after
the best common rotation is removed), the gravity-norm error, and the gyro bias residual
|mean(w) - true rate| (true rate = earth rate in the body frame). "truth" applies the
true parameters; "field" is the seed 000 estimator on the same windows, for reference.

Usage: ``python bench/bench_mems.py [--seeds 0 1 2] [--json FILE]``
"""

import argparse
import dataclasses
import json
import os
import sys
import time
import zlib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.calibration import Calibration  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (CalibrateOptions,  # noqa: E402
                                                    calibrate_windows)
from thermal_imu_calib.estimation.evaluate import WindowAccumulator  # noqa: E402
from thermal_imu_calib.estimation.gyro_fit import collect_motion  # noqa: E402
from thermal_imu_calib.estimation.segments import Windows  # noqa: E402
from thermal_imu_calib.estimation.stationary import DetectorConfig  # noqa: E402
from thermal_imu_calib.io.align import StreamAligner  # noqa: E402
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns  # noqa: E402
from thermal_imu_calib.models.whole_unit import WholeUnitGyroModel  # noqa: E402

LATITUDE = 45.0          # the scenarios' latitude
COLDSTART = dict(faces=sim.SIX_FACES + (sim.TILTED,) * 4, repetitions=8, hold_s=(25.0, 35.0))
RESIDUAL = 'norm'
N_COLDSTARTS = 2


def truth_gyro(dev, seed):
    """Return the true seed 002 gyro model of device ``seed`` (scale, misalignment, C, bias)."""
    rng = np.random.default_rng([seed, 2002])
    m = np.eye(3) + np.diag(rng.choice([-1, 1], 3) * rng.uniform(1e-3, 4e-3, 3))
    off = rng.choice([-1, 1], (3, 3)) * rng.uniform(3e-4, 1.5e-3, (3, 3))
    np.fill_diagonal(off, 0.0)
    m = m + off                                       # raw = m w + G f + bias(T)
    g = rng.choice([-1, 1], (3, 3)) * rng.uniform(1.8e-5, 7e-5, (3, 3))
    om1 = np.linalg.inv(m)
    return WholeUnitGyroModel(dev.t0, dev.gyro_coeffs, None, np.zeros(3), om1, None, None,
                              -om1 @ g)


def raw_chunks(rec, gyro_model, seed):
    """Yield raw ImuColumns: simulated accel errors + the whole-unit gyro truth, noise, LSB."""
    dev, spec, cal = rec.device, rec.device.spec, rec.truth
    rng = np.random.default_rng([seed, 7, zlib.crc32(rec.name.encode())])
    sig_a = spec.accel_noise_density * np.sqrt(rec.imu_rate)
    sig_g = spec.gyro_noise_density * np.sqrt(rec.imu_rate)
    for tc in rec.truth_chunks():
        n = len(tc.stamp_ns)
        ta, tg = tc.temps[:, cal.accel_input], tc.temps[:, cal.gyro_input]
        acc = sim.accel_forward(tc.specific_force, ta, dev.t0, dev.k0, dev.b0, dev.s,
                                dev.thermal) + sig_a * rng.standard_normal((n, 3))
        gyr = gyro_model.forward(tc.angular_rate, tg, aux={'accel': tc.specific_force}) \
            + sig_g * rng.standard_normal((n, 3))
        acc = np.round(acc / spec.accel_lsb) * spec.accel_lsb
        gyr = np.round(gyr / spec.gyro_lsb) * spec.gyro_lsb
        yield ImuColumns(tc.stamp_ns, acc, gyr, rec.frame_id)


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
    base = sim.SCENARIOS['mems-coldstart']
    out = []
    for i in range(n):
        cfg = dataclasses.replace(base, name=base.name if i == 0 else f'{base.name}-{i + 1}',
                                  **COLDSTART)
        out.append(sim.simulate(cfg, seed))
    return out


def calibrate(recs, gyro_model, seed, model='whole_unit'):
    """Collect windows and pose changes of the cold starts; return (result, collection info)."""
    t0 = time.perf_counter()
    parts, transitions, peak = [], [], 0
    offset = 0
    for rec in recs:
        w, tr, col = collect_motion(aligned(rec, raw_chunks(rec, gyro_model, seed)),
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
    opts = CalibrateOptions(model=model, gravity=rec.gravity, inputs=list(rec.truth.inputs))
    # the two settings calibrate_windows has no field for yet (see docs/whole_unit.md)
    opts.latitude = LATITUDE
    opts.transitions = transitions
    opts.whole_unit_residual = RESIDUAL
    t1 = time.perf_counter()
    res = calibrate_windows(windows, opts)
    minutes = round(float(sum(r.duration for r in recs)) / 60, 1)
    return res, {'cold_starts': len(recs), 'minutes': minutes,
                 'windows': len(windows), 'holds': int(len(np.unique(windows.hold))),
                 'transitions': len(transitions), 'collector_kb': round(peak / 1e3, 1),
                 'collect_s': round(t_collect, 2), 'fit_s': round(time.perf_counter() - t1, 2)}


def validation_windows(rec, gyro_model, seed):
    """Return (windows, true specific force means, true rate means) of the validation run."""
    windows, _, _ = collect_motion(aligned(rec, raw_chunks(rec, gyro_model, seed)),
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
    gm = truth_gyro(rec.device, seed)
    res, info = calibrate(recs, gm, seed)
    field_res, _ = calibrate(recs, gm, seed, 'field')
    val = sim.simulate('mems-validation', seed)
    vw, f_true, w_true = validation_windows(val, gm, seed)
    truth = Calibration(accel=rec.truth.accel, gyro=gm, inputs=rec.truth.inputs,
                        valid_range=np.array([[-80.0, 200.0]] * len(rec.truth.inputs)),
                        accel_input=rec.truth.accel_input, gyro_input=rec.truth.gyro_input,
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
    est, tru = res.calibration.gyro, gm
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
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    ap.add_argument('--cold-starts', type=int, default=N_COLDSTARTS,
                    help='cold starts of the device merged for the calibration (default 2)')
    ap.add_argument('--residual', choices=('norm', 'vector'), default='norm',
                    help='accelerometer residual of the whole-unit fit (default norm)')
    ap.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    global RESIDUAL
    RESIDUAL = args.residual
    results = [run_seed(s, args.cold_starts) for s in args.seeds]
    print(table(results))
    worst_v = max(r['ratios']['vector_error_vs_truth'] for r in results)
    worst_g = max(r['ratios']['gyro_bias_vs_truth'] for r in results)
    print(f'\nworst ratio to the true parameters: vector error {worst_v:.2f} (limit 2), gyro '
          f'bias residual {worst_g:.2f} (limit 3); {time.perf_counter() - t0:.0f} s')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'benchmark': 'bench_mems', 'results': results,
                       'worst_vector_ratio': worst_v, 'worst_gyro_ratio': worst_g}, f,
                      indent=1, default=float)
    return 0


if __name__ == '__main__':
    sys.exit(main())
