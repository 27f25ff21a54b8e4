"""Issue-5 acceptance: held-out thermal drift of raw, PX4/ArduPilot-style cubics and our models.

Four experiments, one table each (markdown on stdout, ``--json FILE`` for the figures):

1. ``chamber-cycle`` (simulated, several seeds): one pose, two 10..50 degC cycles at
   1 degC/min, errors following the reading through a 300-s lag, so heating and cooling
   legs disagree (hysteresis). Leave one temperature leg out: every method is fitted on
   the other legs and judged on the held-out one. Held-out drift = corrected window means
   minus their mean over the training legs (the constant is not observable in one pose),
   RMS over the held-out windows and axes of all folds.
2. ``lag-warmup`` (simulated): calibrate on one 1-h warm-up whose errors follow a 240-s
   lagged temperature; evaluate on two other recordings of the same device, a fast
   warm-up (3x shorter time constant) and a 21..39 degC heating/cooling cycle. The
   constant differs between recordings (pose), so drift is about each recording's mean.
3. Real BMI270 hot/cold soak (``../shared/data/real/bmi270_hot_cold``, else the repo's
   fixture slices): gyroscope bias only (the two soaks have different orientations), two
   nearly isothermal points; each soak is cut in halves and one half is left out.
4. Restarts of the compensator's stream (``Calibration.stream``): the default calibrated on
   one recording streams another one (the chamber cycle of the next seed; the lag warm-up's
   fast warm-up and cycle), restarted 25 times along it; the step against the
   never-restarted stream, at and after the restart, in units of the restarted stream's
   own 1-sigma (``predict_std``).

Also the RVM training time on 3 h of segment statistics (accelerometer and gyroscope,
grid search included). Equivalent CLI for one recording::

    thermal-imu-calib simulate cyc.mcap --scenario chamber-cycle --seed 0
    thermal-imu-calib calibrate cyc.mcap --model auto -o cal.yaml

Usage: python bench/bench_thermal.py [--seeds 0 1 2] [--json out.json] [--quick]
[--only-restarts]
"""

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation import baselines
from thermal_imu_calib.selection import select
from thermal_imu_calib.estimation.calibrate import (calibrate_windows, CalibrateOptions,
                                                    ESTIMATORS, model_choices)
from thermal_imu_calib.io.columns import ImuColumns
from thermal_imu_calib.thermal_input import history_windows, parse_history_key
from thermal_imu_calib.estimation.rvm_fit import fit_rvm_offset, RvmSettings
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.thermal_lag import cv_groups, lagged_axis_temperatures, legs
from thermal_imu_calib.collection.feed import windows_from_columns

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BMI_DIRS = (os.path.join(os.path.dirname(ROOT), 'shared', 'data', 'real', 'bmi270_hot_cold'),
            '/work/shared/data/real/bmi270_hot_cold',
            os.path.join(ROOT, 'test', 'fixtures', 'real', 'bmi270'))
METHODS = ('raw', 'px4', 'ardupilot', 'offset', 'lag', 'rvm', 'rvm-lag', 'auto')
LABEL = {'raw': 'raw', 'px4': 'PX4-style cubic', 'ardupilot': 'ArduPilot-style cubic',
         'offset': 'offset polynomial (T)', 'lag': 'lag-aware polynomial',
         'rvm': 'RVM (T)', 'rvm-lag': 'RVM, lagged T', 'auto': '**auto** (default)'}
G0 = 9.80665
MG = 1e3 / G0                 # m/s^2 -> mg
MDPS = 1e3 * 180.0 / np.pi    # rad/s -> mdeg/s


# ---------------------------------------------------------------------- data
def sim_windows(rec):
    """Run the stationary detector over a simulated recording (no bag round trip)."""
    return windows_from_columns(rec.imu_chunks(),
                                [rec.temperatures[t] for t in rec.config.temp_topics])


def options():
    """Return calibration options for one shared temperature input."""
    return CalibrateOptions(inputs=[TemperatureInput('t0', '/imu/temperature')])


def read_bmi270(path, rate_hz=100.0):
    """Parse a PuTTY log of the BMI270 soak: (t s, accel m/s^2, gyro rad/s, temp degC).

    Lines that are not 7 floats are skipped (banner, serial garbage); accel is in g/4
    (see SOURCE.md), gyro in deg/s; there is no time base, ``rate_hz`` is assumed.
    """
    rows = []
    with open(path, errors='replace') as f:
        for line in f:
            parts = line.strip().split(',')
            if len(parts) != 7:
                continue
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                continue
    a = np.asarray(rows)
    t = np.arange(len(a)) / rate_hz
    return t, a[:, 1:4] * 4.0 * G0, np.radians(a[:, 4:7]), a[:, 0]


def bmi270_windows(directory, window=64):
    """Return Windows of both soaks (cold then hot, as one cold-to-hot sequence)."""
    files = [('BMI_270_cold_test_.csv', 0), ('BMI_270_hot_test.csv', 1)]
    parts, t_off = [], 0.0
    for name, hold in files:
        t, acc, gyr, temp = read_bmi270(os.path.join(directory, name))
        m = len(t) // window
        sl = slice(0, m * window)

        def mean(x):
            return x[sl].reshape(m, window, -1).mean(1)

        def var(x):
            return x[sl].reshape(m, window, -1).var(1, ddof=1)
        tt = t[sl].reshape(m, window)
        parts.append(Windows(np.full(m, hold), tt[:, 0] + t_off, tt[:, -1] + t_off,
                             np.full(m, window), mean(acc), mean(gyr), var(acc), var(gyr),
                             mean(temp[:, None]), np.zeros((m, 1))))
        t_off += t[-1] + 3600.0
    return Windows.concat(parts)


# ---------------------------------------------------------------------- methods
def fit_methods(methods, ctx, signals=('accel', 'gyro')):
    """Fit every method on a training context; returns {method: (accel, gyro, tau, name)}.

    One automatic selection is run; the fixed candidates reuse its lag estimate and RVM
    kernels (the same fits ``--model lag`` / ``rvm`` / ``rvm-lag`` would make).
    """
    sel = select.select_single(ctx, signals=signals)
    tau = np.asarray(sel.lag['tau_s'])
    out = {}
    for m in methods:
        if m == 'auto' and set(signals) == {'accel', 'gyro'}:
            out[m] = _default_fit(ctx)
        elif m == 'raw':
            out[m] = (None, None, None, 'raw')
        elif m in ('px4', 'ardupilot'):
            fit = baselines.px4_fit if m == 'px4' else baselines.ardupilot_fit
            try:
                acc = fit(ctx.windows, ctx.ta, 'accel', 'accel')[0] if 'accel' in signals \
                    else None
                gyr = fit(ctx.windows, ctx.tg, 'gyro', 'gyro')[0] if 'gyro' in signals else None
                out[m] = (acc, gyr, None, m)
            except ValueError as e:    # e.g. ArduPilot's learner never saw a warm-up
                out[m] = (None, None, None, f'n/a: {e}')
        else:
            name = sel.model if m == 'auto' else m
            t = (sel.tau_s if m == 'auto' else tau) if name.endswith('lag') else None
            family = 'rvm' if name.startswith('rvm') else 'poly'
            acc, gyr, _ = select.fit_single(ctx, family, t, kernels=sel.kernels.get(name),
                                            signals=signals)
            out[m] = (acc, gyr, t, name)
    return out


def _default_fit(ctx):
    """Return (accel, gyro, tau, name) of the default: ``auto_policy`` and its estimator."""
    model_choices()                 # loads every registered estimator
    name, _ = select.auto_policy(ctx)
    est = ESTIMATORS[name](ctx)
    filt = est.temperature_filter
    tau = None if filt is None or filt.is_identity else filt.tau_s
    if name == 'hysteresis':
        name = ' / '.join(r['spec'] for r in (est.report['accel_history'],
                                              est.report['gyro_history']))
    return est.accel, est.gyro, tau, name


def _warmup_tests(seed):
    """Return {name: SimRecording}: other recordings of the lag-warmup device."""
    base = sim.SCENARIOS['lag-warmup']
    return {
        'fast warm-up': sim.simulate(dataclasses.replace(
            base, name='lag-warmup-fast', tau_s=300.0, t_amb=20.5), seed),
        '21-38 degC cycle': sim.simulate(dataclasses.replace(
            base, name='lag-cycle', profile='cycle', cycles=1, cycle_lo=21.5, cycle_hi=38.0,
            ramp_degc_per_min=1.0, dwell_s=300.0, case_tau_s=60.0), seed),
    }


def _streamed(cal, rec, max_rows):
    """Return (t, accel, gyro, temp, never-restarted output) of ``rec`` (decimated rows)."""
    imu = ImuColumns.concat(list(rec.imu_chunks()))
    tc = rec.temperatures[rec.config.temp_topics[0]]
    step = max(1, len(imu.stamp_ns) // max_rows)
    t = imu.stamp_ns[::step] * 1e-9
    acc, gyr = imu.accel[::step], imu.gyro[::step]
    temp = np.interp(t, tc.stamp_ns * 1e-9, tc.temperature)[:, None]
    return t, acc, gyr, temp, cal.stream().apply(t, acc, gyr, temp)


def restart_steps(cal, rec, n_restarts=25, max_rows=40000):
    """Return the largest restart step (accel, gyro) in the restarted stream's 1-sigma.

    ``rec`` is streamed whole (rows decimated to at most ``max_rows``) and again from each
    of ``n_restarts`` restarts; the step is |restarted - whole| / restarted std, max over
    the axes and every row from the restart on.
    """
    t, acc, gyr, temp, whole = _streamed(cal, rec, max_rows)
    out = np.zeros(2)
    for i0 in range(100, len(t), max(1, len(t) // n_restarts)):
        r = cal.stream().apply(t[i0:], acc[i0:], gyr[i0:], temp[i0:])
        if r.accel_std is None or r.gyro_std is None:
            return None
        out = np.maximum(out, [np.max(np.abs(r.accel - whole.accel[i0:]) / r.accel_std),
                               np.max(np.abs(r.gyro - whole.gyro[i0:]) / r.gyro_std)])
    return out.tolist()


def resumed_steps(cal, rec, n_restarts=25, max_rows=40000, down_s=10.0, save_period_s=5.0):
    """Return the largest step (accel, gyro) of a stream resumed from a saved state, in sigma.

    What ``compensator_node`` with ``state_file`` does after a crash, worst case: the state
    was last written ``save_period_s`` before the node stopped, the node was down
    ``down_s`` (stamps), and the new one restores the state at its first sample (the gap
    run through with the reading interpolated). Same restarts and measure as
    ``restart_steps``.
    """
    t, acc, gyr, temp, whole = _streamed(cal, rec, max_rows)
    out = np.zeros(2)
    for i0 in range(100, len(t), max(1, len(t) // n_restarts)):
        saved = int(np.searchsorted(t, t[i0] - down_s - save_period_s, side='right'))
        if saved < 1:
            continue
        old = cal.stream()
        old.apply(t[:saved], acc[:saved], gyr[:saved], temp[:saved])
        state = old.state()
        r_stream = cal.stream()
        if state is not None:
            r_stream.restore(state)
        r = r_stream.apply(t[i0:], acc[i0:], gyr[i0:], temp[i0:])
        if r.accel_std is None or r.gyro_std is None:
            return None
        out = np.maximum(out, [np.max(np.abs(r.accel - whole.accel[i0:]) / r.accel_std),
                               np.max(np.abs(r.gyro - whole.gyro[i0:]) / r.gyro_std)])
    return out.tolist()


def restarts(seed):
    """Return {test: {'model', 'steps'}}: restart steps of the default on other recordings."""
    out = {}
    for train, tests in (('chamber-cycle', {'chamber-cycle, next seed':
                                            sim.simulate('chamber-cycle', seed + 1)}),
                         ('lag-warmup', _warmup_tests(seed))):
        cal = calibrate_windows(sim_windows(sim.simulate(train, seed)),
                                options()).calibration
        model = cal.fit['model_choice']['model']
        for name, rec in tests.items():
            out[f'{train} -> {name}'] = {'model': model, 'steps': restart_steps(cal, rec),
                                         'resumed': resumed_steps(cal, rec)}
    return out


def corrected(windows, model, tau, signal):
    """Return corrected window means of ``signal`` (lag computed over the whole history).

    History-dependent models get their lagged readings over the whole history too, as
    ``Calibration.stream()`` computes them sample by sample.
    """
    y = getattr(windows, signal)
    if model is None:
        return y
    temps = lagged_axis_temperatures(windows, tau, [0, 0, 0])
    keys = getattr(model, 'history_keys', ())
    aux = {'history': {k: history_windows(windows.t0, windows.t1, windows.temp,
                                          parse_history_key(k))[:, [0, 0, 0]]
                       for k in keys}} if keys else None
    return model.correct(y, temps, aux=aux)


def rms(x):
    """Return the RMS over all entries."""
    return float(np.sqrt(np.mean(np.square(x))))


def hysteresis(windows, signal='accel'):
    """Return the RMS heating-minus-cooling disagreement of the raw output at equal T."""
    ids, info = legs(windows)
    temp = windows.temp[:, 0]
    y = getattr(windows, signal)
    up = [i['leg'] for i in info if i['direction'] == 'heating']
    down = [i['leg'] for i in info if i['direction'] == 'cooling']
    if not up or not down:
        return 0.0
    grid = np.linspace(np.percentile(temp, 10), np.percentile(temp, 90), 50)

    def curve(legs_):
        m = np.isin(ids, legs_)
        order = np.argsort(temp[m])
        return np.stack([np.interp(grid, temp[m][order], y[m][order, a]) for a in range(3)], 1)
    return rms(curve(up) - curve(down))


# ---------------------------------------------------------------------- experiments
def chamber(seed, methods):
    """Leave-one-leg-out drift of every method on one simulated chamber cycle."""
    t0 = time.perf_counter()
    w = sim_windows(sim.simulate('chamber-cycle', seed))
    t_sim = time.perf_counter() - t0
    ids, info = legs(w)
    out = {m: {'accel': [], 'gyro': []} for m in methods}
    chosen = []
    for leg in np.unique(ids):
        test = ids == leg
        ctx = select.make_context(w.select(~test), options())
        ctx.filter_ok = True
        fits = fit_methods(methods, ctx)
        for m in methods:
            acc, gyr, tau, name = fits[m]
            if m == 'auto':
                chosen.append(name)
            for sig, model in (('accel', acc), ('gyro', gyr)):
                c = corrected(w, model, tau, sig)
                ref = np.average(c[~test], axis=0, weights=w.n[~test])
                out[m][sig].append(c[test] - ref)
    res = {m: {s: rms(np.concatenate(v[s])) for s in v} for m, v in out.items()}
    return {'seed': seed, 'legs': len(info), 'windows': len(w), 'sim_s': t_sim,
            'hysteresis_accel_mg': hysteresis(w, 'accel') * MG,
            'hysteresis_gyro_mdps': hysteresis(w, 'gyro') * MDPS,
            'auto_chose': chosen, 'drift': res, 'seconds': time.perf_counter() - t0}


def lag_warmup(seed, methods):
    """Calibrate on lag-warmup, evaluate on a fast warm-up and a cycle of the same device."""
    t0 = time.perf_counter()
    train = sim_windows(sim.simulate('lag-warmup', seed))
    # same seed and device family: the same IMU; another scenario name: another recording
    tests = {k: sim_windows(rec) for k, rec in _warmup_tests(seed).items()}
    ctx = select.make_context(train, options())
    ctx.filter_ok = True
    res = {name: {} for name in tests}
    chosen = ''
    fits = fit_methods(methods, ctx)
    for m in methods:
        acc, gyr, tau, name = fits[m]
        if m == 'auto':
            chosen = name
        for tname, tw in tests.items():
            res[tname][m] = {}
            for sig, model in (('accel', acc), ('gyro', gyr)):
                c = corrected(tw, model, tau, sig)
                res[tname][m][sig] = rms(c - np.average(c, axis=0, weights=tw.n))
    return {'seed': seed, 'auto_chose': chosen, 'drift': res,
            'seconds': time.perf_counter() - t0}


def bmi270(methods):
    """Gyro bias held-out error on the real BMI270 soaks (halves of each soak left out)."""
    directory = next((d for d in BMI_DIRS if os.path.isfile(
        os.path.join(d, 'BMI_270_hot_test.csv'))), None)
    if directory is None:
        return None
    w = bmi270_windows(directory)
    half = np.zeros(len(w), int)
    for h in (0, 1):
        m = np.flatnonzero(w.hold == h)
        half[m[len(m) // 2:]] = 1
    groups = 2 * w.hold + half
    out = {m: [] for m in methods if m not in ('lag', 'rvm-lag')}
    chosen = []
    failed = {}
    for g in np.unique(groups):
        test = groups == g
        ctx = select.make_context(w.select(~test), options())
        ctx.n_orientations = 1      # gyro bias does not depend on the pose
        fits = fit_methods(list(out), ctx, signals=('gyro',))
        for m in out:
            _, gyr, tau, name = fits[m]
            if m == 'auto':
                chosen.append(name)
            if name.startswith('n/a'):
                failed[m] = name
                continue
            c = corrected(w, gyr, tau, 'gyro')
            out[m].append(c[test] - np.average(c[~test], axis=0, weights=w.n[~test]))
    temps = [float(np.mean(w.temp[w.hold == h])) for h in (0, 1)]
    bias = [np.average(w.gyro[w.hold == h], axis=0, weights=w.n[w.hold == h]) for h in (0, 1)]
    slope = (bias[1] - bias[0]) / (temps[1] - temps[0])
    return {'source': directory, 'windows': len(w), 'soak_temps_degC': temps,
            'gyro_bias_slope_mdps_per_degC': (slope * MDPS).tolist(),
            'auto_chose': chosen, 'failed': failed,
            'drift_gyro_mdps': {m: rms(np.concatenate(v)) * MDPS if m not in failed
                                else float('nan') for m, v in out.items()}}


def rvm_timing(w, hours=3.0):
    """Time the RVM training (grid search + fit, accel and gyro) on ``hours`` of windows."""
    keep = w.t0 - w.t0.min() <= hours * 3600.0
    wt = w.select(keep)
    groups, _ = cv_groups(wt)
    ctx = select.make_context(wt, options())
    t0 = time.perf_counter()
    acc, rep_a = fit_rvm_offset(wt, ctx.ta, 'accel', 'accel', groups, True, ctx.t0)
    gyr, rep_g = fit_rvm_offset(wt, ctx.tg, 'gyro', 'gyro', groups, False, ctx.t0)
    return {'hours': float((wt.t1.max() - wt.t0.min()) / 3600.0), 'windows': len(wt),
            'training_points': rep_a['training_points'], 'grid': len(RvmSettings().grid()),
            'relevance_vectors_accel': rep_a['relevance_vectors'],
            'relevance_vectors_gyro': rep_g['relevance_vectors'],
            'seconds': time.perf_counter() - t0}


# ---------------------------------------------------------------------- report
def _row(label, vals, fmt='{:.3f}'):
    return f'| {label} | ' + ' | '.join(fmt.format(v) for v in vals) + ' |'


def print_restarts(results, seeds):
    """Print the restart table (``restarts`` per seed); return True when all are <= 1 sigma."""
    print('\n### Compensator restarts (simulated, calibrated on one recording, streamed on '
          'another)\n')
    print('Largest step of a restarted stream against the never-restarted one, at and after '
          'each of 25 restarts, in the restarted stream\'s own 1-sigma (accel / gyro).\n')
    print('| calibrated on -> streamed | ' + ' | '.join(f'seed {s}' for s in seeds) + ' |')
    print('|---|' + '---|' * len(seeds))
    ok = True
    for name in results[0]:
        cells = []
        for r in results:
            st = r[name]['steps']
            cells.append('n/a' if st is None else
                         f'{st[0]:.2f} / {st[1]:.2f} ({r[name]["model"]})')
            ok &= st is None or max(st) <= 1.0
        print(f'| {name} | ' + ' | '.join(cells) + ' |')
    print('\nAcceptance: no restart step beyond 1 sigma: ' + ('PASS' if ok else 'MISS'))
    print('\nThe same restarts resumed from compensator_node\'s state_file (saved 5 s before '
          'a crash, 10 s down; accel / gyro sigma):\n')
    print('| calibrated on -> streamed | ' + ' | '.join(f'seed {s}' for s in seeds) + ' |')
    print('|---|' + '---|' * len(seeds))
    for name in results[0]:
        cells = []
        for r in results:
            st = r[name].get('resumed')
            cells.append('n/a' if st is None else f'{st[0]:.2f} / {st[1]:.2f}')
        print(f'| {name} | ' + ' | '.join(cells) + ' |')
    return ok


def main(argv=None):
    """Run the experiments, print markdown tables and check the acceptance criteria."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    ap.add_argument('--json', help='write the figures here')
    ap.add_argument('--quick', action='store_true', help='one seed, fewer methods')
    ap.add_argument('--only-restarts', action='store_true',
                    help='only experiment 4 (compensator restarts) and its table')
    args = ap.parse_args(argv)
    seeds = args.seeds[:1] if args.quick else args.seeds
    if args.only_restarts:
        figures = {'restarts': [restarts(s) for s in seeds]}
        figures['pass'] = {'restart_within_1_sigma': bool(print_restarts(figures['restarts'],
                                                                         seeds))}
        if args.json:
            with open(args.json, 'w') as f:
                json.dump(figures, f, indent=1, default=float)
        return 0 if figures['pass']['restart_within_1_sigma'] else 1
    methods = METHODS
    t_all = time.perf_counter()
    figures = {'chamber': [], 'lag_warmup': []}
    for s in seeds:
        figures['chamber'].append(chamber(s, methods))
        r = figures['chamber'][-1]
        print(f'chamber-cycle seed {s}: {r["seconds"]:.0f} s, auto chose {r["auto_chose"]}',
              file=sys.stderr)
    for s in seeds:
        figures['lag_warmup'].append(lag_warmup(s, methods))
        print(f'lag-warmup seed {s}: {figures["lag_warmup"][-1]["seconds"]:.0f} s',
              file=sys.stderr)
    figures['restarts'] = [restarts(s) for s in seeds]
    figures['bmi270'] = bmi270(methods)
    w = sim_windows(sim.simulate('chamber-cycle', seeds[0]))
    figures['rvm_timing'] = rvm_timing(w)

    ok = True
    print('### Chamber cycles with hysteresis (simulated, leave one temperature leg out)\n')
    print('Held-out drift RMS; accel in mg, gyro in mdeg/s; median over seeds '
          f'{", ".join(map(str, seeds))}.\n')
    print('| method | accel [mg] | gyro [mdeg/s] | accel vs best cubic | gyro vs best cubic |')
    print('|---|---|---|---|---|')
    med = {m: {s: float(np.median([r['drift'][m][s] for r in figures['chamber']]))
               for s in ('accel', 'gyro')} for m in methods}
    cubic = {s: min(med['px4'][s], med['ardupilot'][s]) for s in ('accel', 'gyro')}
    for m in methods:
        print(f'| {LABEL[m]} | {med[m]["accel"] * MG:.3f} | {med[m]["gyro"] * MDPS:.3f} | '
              f'{100 * (1 - med[m]["accel"] / cubic["accel"]):+.0f} % | '
              f'{100 * (1 - med[m]["gyro"] / cubic["gyro"]):+.0f} % |')
    hyst = np.median([r['hysteresis_accel_mg'] for r in figures['chamber']])
    print(f'\nRaw heating-vs-cooling disagreement at equal reading (hysteresis): {hyst:.2f} mg '
          f'accel, {np.median([r["hysteresis_gyro_mdps"] for r in figures["chamber"]]):.2f} '
          'mdeg/s gyro (RMS).')
    for r in figures['chamber']:
        gain = {s: 1 - r['drift']['auto'][s] / min(r['drift']['px4'][s],
                                                   r['drift']['ardupilot'][s])
                for s in ('accel', 'gyro')}
        r['auto_gain_vs_cubics'] = gain
        ok &= all(v >= 0.2 for v in gain.values())
    print('Acceptance (each seed, accel and gyro): auto beats both cubic fits by >= 20 %: '
          + ('PASS' if ok else 'FAIL') + ' (' + '; '.join(
              f'seed {r["seed"]}: {100 * r["auto_gain_vs_cubics"]["accel"]:.0f} % / '
              f'{100 * r["auto_gain_vs_cubics"]["gyro"]:.0f} %' for r in figures['chamber'])
          + ')')

    print('\n### Warm-up with a 240-s thermal lag (simulated, other recordings of the device)\n')
    print('Calibrated on one 1-h warm-up, drift about the mean of the held-out recording; '
          'accel mg / gyro mdeg/s, median over seeds.\n')
    tests = list(figures['lag_warmup'][0]['drift'])
    print('| method | ' + ' | '.join(f'{t}: accel | {t}: gyro' for t in tests) + ' |')
    print('|---|' + '---|' * (2 * len(tests)))
    lw = {t: {m: {s: float(np.median([r['drift'][t][m][s] for r in figures['lag_warmup']]))
                  for s in ('accel', 'gyro')} for m in methods} for t in tests}
    for m in methods:
        cells = []
        for t in tests:
            cells += [f'{lw[t][m]["accel"] * MG:.3f}', f'{lw[t][m]["gyro"] * MDPS:.3f}']
        print(f'| {LABEL[m]} | ' + ' | '.join(cells) + ' |')
    ok_lag = all(lw[t]['lag']['accel'] <= 0.7 * lw[t]['offset']['accel'] for t in tests)
    print('\nAcceptance: the lag-aware model beats the temperature-only one on held-out '
          'recordings by >= 30 % (accel): ' + ('PASS' if ok_lag else 'FAIL') + ' (' + ', '.join(
              f'{t}: {100 * (1 - lw[t]["lag"]["accel"] / lw[t]["offset"]["accel"]):.0f} %'
              for t in tests) + '); auto chose '
          + ', '.join(r['auto_chose'] for r in figures['lag_warmup']))

    ok_restart = print_restarts(figures['restarts'], seeds)

    b = figures['bmi270']
    if b is not None:
        print('\n### Real BMI270 hot/cold soak: gyro bias (two soaks, halves left out)\n')
        print(f'Soaks at {b["soak_temps_degC"][0]:.1f} and {b["soak_temps_degC"][1]:.1f} '
              f'degC ({b["windows"]} windows of 64 samples); two-point bias slope '
              + ', '.join(f'{v:+.1f}' for v in b['gyro_bias_slope_mdps_per_degC'])
              + ' mdeg/s/degC (x, y, z).\n')
        print('| method | held-out gyro bias error [mdeg/s] |')
        print('|---|---|')
        for m, v in b['drift_gyro_mdps'].items():
            text = f'{v:.1f}' if m not in b['failed'] else b['failed'][m].split(';')[0]
            print(f'| {LABEL[m]} | {text} |')
        print('\nTwo nearly isothermal soaks only pin a line: with a half-soak left out every '
              'model still sees both temperatures, so this checks that the bias-vs-'
              'temperature offset removes the 35-degC bias change; it cannot rank models '
              'on the shape of the curve or on lag (no time base). auto chose '
              + ', '.join(b['auto_chose']) + '.')
    rt = figures['rvm_timing']
    print(f'\nRVM training on {rt["hours"]:.2f} h of segment statistics ({rt["windows"]} windows '
          f'-> {rt["training_points"]} training points, accel + gyro, 3 axes each, '
          f'{rt["grid"]}-kernel grid search by CV included): {rt["seconds"]:.2f} s '
          + ('(< 10 s: PASS)' if rt['seconds'] < 10 else '(FAIL)'))
    total = time.perf_counter() - t_all
    print(f'\nbench time {total:.0f} s', file=sys.stderr)
    figures['pass'] = {'auto_vs_cubics': bool(ok), 'lag_vs_temperature': bool(ok_lag),
                       'restart_within_1_sigma': bool(ok_restart),
                       'rvm_time': bool(rt['seconds'] < 10)}
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(figures, f, indent=1, default=float)
    return 0 if all(figures['pass'].values()) else 1


if __name__ == '__main__':
    sys.exit(main())
