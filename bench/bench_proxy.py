"""Gyro thermal proxy: calibrate the gyro on its resonance frequency (Hz) vs the die temperature.

Device: ``sim.draw_device('mems', seed)``, die temperature published at 1 Hz in 0.125-degC
steps (``mems-coldstart``). ``sim.proxy.with_resonance_proxy`` adds the gyro's drive-mode
resonance frequency f = 25 kHz - 1.5 Hz/degC T_gyro (0.01-Hz steps, 0.005-Hz noise, 10 Hz)
on ``/imu/gyro_resonance``. Calibration: one ``mems-coldstart`` (3 x (six faces + 2 corner-up
poses), 60-90 s holds); once with the die temperature as the only input, once with both
inputs (accel on degC, gyro on Hz, the default mapping), for ``--model auto`` and
``--model whole_unit`` (latitude given). Validation: ``mems-validation`` of the same device
(5.5-6 min holds). Per hold: the gyro bias residual |mean(w) - true rate| (true rate = earth
rate in the body frame, from the simulator's kinematics), RMS over holds; "truth" applies
the true parameters (in degC, and re-expressed in Hz).

Usage: ``python bench/bench_proxy.py [--seeds 0 1 2] [--json FILE]``
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
from thermal_imu_calib.calibration import TemperatureInput  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (CalibrateOptions,  # noqa: E402
                                                    calibrate_windows)
from thermal_imu_calib.collection.metrics import WindowAccumulator  # noqa: E402
from thermal_imu_calib.collection.feed import windows_from_columns  # noqa: E402
from thermal_imu_calib.sim.proxy import (proxy_truth, ResonanceProxy,  # noqa: E402
                                         with_resonance_proxy)

DIE, PROXY = '/imu/temperature', ResonanceProxy().topic
LATITUDE = 45.0


def windows(rec):
    """Return the stationary windows of a proxy recording (inputs: die degC, proxy Hz)."""
    return windows_from_columns(rec.imu_chunks(), [rec.temperatures[DIE],
                                                   rec.temperatures[PROXY]])


def true_rate(rec, w):
    """Return the (m, 3) mean true angular rate over each window, rad/s."""
    acc = WindowAccumulator(w.t0, w.t1)
    for tc in rec.truth_chunks():
        acc.add(tc.stamp_ns * 1e-9, {'w': tc.angular_rate})
    return acc.means('w')


def residual(w, gyro, truth):
    """Return the RMS over holds of |mean(gyro - truth)| (rad/s)."""
    out = []
    for h in w.hold_ids:
        m = w.hold == h
        out.append(np.linalg.norm(np.average(gyro[m] - truth[m], 0, w.n[m])))
    return float(np.sqrt(np.mean(np.square(out))))


def one_input(w):
    """Return the windows with the die temperature as the only input."""
    return dataclasses.replace(w, temp=w.temp[:, :1], temp_rate=w.temp_rate[:, :1])


def run(seed, models):
    """Calibrate and validate one device; returns {label: residual} and timings."""
    t_start = time.perf_counter()
    cal_rec = with_resonance_proxy(sim.simulate('mems-coldstart', seed))
    val_rec = with_resonance_proxy(sim.simulate('mems-validation', seed))
    wc, wv = windows(cal_rec), windows(val_rec)
    rate = true_rate(val_rec, wv)
    die = TemperatureInput('die', DIE)
    both = [die, TemperatureInput('gyro_resonance', PROXY, 'Hz')]
    out = {'raw': residual(wv, wv.gyro, rate)}
    for label, cal, temps in (('truth degC', val_rec.truth, wv.temp[:, :1]),
                              ('truth Hz', proxy_truth(val_rec), wv.temp)):
        out[label] = residual(wv, cal.apply(wv.accel, wv.gyro, temps).gyro, rate)
    for model in models:
        for label, win, inputs, temps in (('degC', one_input(wc), [die], wv.temp[:, :1]),
                                          ('Hz', wc, both, wv.temp)):
            res = calibrate_windows(win, CalibrateOptions(
                model=model, inputs=inputs, latitude=LATITUDE, frame_id='imu_link'))
            cal = res.calibration
            assert cal.gyro.input_unit == label
            out[f'{model} {label}'] = residual(
                wv, cal.apply(wv.accel, wv.gyro, temps).gyro, rate)
    return out, time.perf_counter() - t_start


def main():
    """Run the seeds, print the table, optionally write JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    ap.add_argument('--models', nargs='+', default=['auto', 'whole_unit'])
    ap.add_argument('--json')
    args = ap.parse_args()
    rows, total = {}, 0.0
    for seed in args.seeds:
        rows[seed], dt = run(seed, args.models)
        total += dt
        print(f'seed {seed}: {dt:.1f} s', file=sys.stderr)
    labels = list(rows[args.seeds[0]])
    print('| seed | ' + ' | '.join(labels) + ' |')
    print('|---' * (len(labels) + 1) + '|')
    for seed, r in rows.items():
        print(f'| {seed} | ' + ' | '.join(f'{r[k]:.3g}' for k in labels) + ' |')
    med = {k: float(np.median([r[k] for r in rows.values()])) for k in labels}
    print('| **median** | ' + ' | '.join(f'{med[k]:.3g}' for k in labels) + ' |')
    ratios = {m: med[f'{m} Hz'] / med[f'{m} degC'] for m in args.models}
    print('\ngyro bias residual RMS over validation holds, rad/s; Hz proxy / degC input '
          '(median): ' + ', '.join(f'{m} {v:.2f}' for m, v in ratios.items())
          + f'; {total:.0f} s')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'seeds': {str(k): v for k, v in rows.items()}, 'median': med,
                       'ratio_hz_over_degc': ratios, 'seconds': total}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
