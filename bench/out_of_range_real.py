"""Beyond the valid range on a real sensor: clamp, linear continuation or the model's own.

The real chamber log's training part (``test/fixtures/real/tofupilot_chamber``; its held-back
test leg is never read): one IMU, one orientation, cooled 51.6 -> -17.6 degC, heated to 74.
A calibration is used forward in time, so the default (``calibrate_windows``, default
options, what ``thermal-imu-calib calibrate`` does) is fitted on the history before a cut
and streamed over the whole log; the rows after the cut whose temperature is beyond the
fitted valid range are scored:

* cuts on the cooling leg where it reaches 30, 15 and 0 degC (fitted from 51.6 down to
  there; beyond: the cold end, the heating start and the hot end above 51.6);
* cuts on the heating leg where it reaches 20, 35 and 50 degC (fitted on -17.6..51.6;
  beyond: the hot end).

Three policies, as ``lifelong_error_sources.py`` scores them on the simulated months:
clamped at the range (``out_of_range: clamp``), continued linearly from the edge
(``linear``: the slope over the last 1 degC inside, no further than the range's width),
and the models' own extrapolation.
The sensor is static, so the true output is constant: the reference is the compensated
output's mean over the fitted rows, and the figure is the RMS over 30-s blocks of
|block mean - reference| (3-vector; gyro mrad/s, accelerometer mm/s^2), by how far beyond
the range the block is.

    python bench/out_of_range_real.py [--json bench/results/out_of_range_real.json]
"""

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_chamber import CSV, TOPIC  # noqa: E402
from thermal_imu_calib.calibration import TemperatureInput  # noqa: E402
from thermal_imu_calib.collection.feed import windows_from_columns  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (calibrate_windows,  # noqa: E402
                                                    CalibrateOptions)
from thermal_imu_calib.io.csv_logs import read_tofupilot_chamber  # noqa: E402

POLICIES = ('clamp', 'linear', 'extrapolate')
BLOCK_S = 30.0
#: how far beyond the range (degC) the policies are compared by, as lifelong_error_sources
EXCESS_BANDS = ((0.0, 2.0), (2.0, 5.0), (5.0, np.inf))
COOL_CUTS_DEGC = (30.0, 15.0, 0.0)
HEAT_CUTS_DEGC = (20.0, 35.0, 50.0)


def policy_outputs(cal, t, imu, temp):
    """Return {policy: (accel, gyro)} of ``cal`` streamed over the log, and the excess (degC).

    Each policy is the calibration's own ``out_of_range`` (``Calibration.apply``); linear:
    the edge value plus the slope over the last ``LINEAR_STEP_DEGC`` inside, times the
    excess.
    """
    out = {}
    for p in POLICIES:
        r = dataclasses.replace(cal, out_of_range=p).stream().apply(
            t, imu.accel, imu.gyro, temp[:, None])
        out[p] = (r.accel, r.gyro)
    lo, hi = cal.valid_range[0]
    excess = np.where(temp > hi, temp - hi, np.where(temp < lo, lo - temp, 0.0))
    return out, excess


def block_errors(t, y, rows, ref):
    """Return (block means - ref) over ``BLOCK_S`` blocks of ``rows``, and the block index."""
    blk = np.floor((t[rows] - t[0]) / BLOCK_S).astype(int)
    ids, inv = np.unique(blk, return_inverse=True)
    cnt = np.bincount(inv)
    means = np.stack([np.bincount(inv, y[rows, a]) / cnt for a in range(3)], 1)
    return means - ref, ids


def score_cut(w, t, imu, temp, cut_t, name):
    """Fit the default before ``cut_t``; return per-block errors beyond the range."""
    wm = 0.5 * (w.t0 + w.t1)
    wl = w.select(wm < cut_t)
    r = calibrate_windows(wl, CalibrateOptions(inputs=[TemperatureInput(TOPIC)]))
    cal = r.calibration
    outs, excess = policy_outputs(cal, t, imu, temp)
    fitted = t < cut_t
    beyond = (t >= cut_t) & (excess > 0)
    rows = {'cut': name, 'valid_range_degC': [float(v) for v in cal.valid_range[0]],
            'model': cal.fit.get('model_choice', {}).get('chosen', ''),
            'rows_beyond': int(beyond.sum()), 'blocks': {}}
    if not beyond.any():
        return rows
    blk = np.floor((t[beyond] - t[0]) / BLOCK_S).astype(int)
    ids, inv = np.unique(blk, return_inverse=True)
    rows['block_excess_degC'] = (np.bincount(inv, excess[beyond])
                                 / np.bincount(inv)).tolist()
    for p, (a, g) in outs.items():
        ea, _ = block_errors(t, a, beyond, a[fitted].mean(0))
        eg, _ = block_errors(t, g, beyond, g[fitted].mean(0))
        rows['blocks'][p] = {'accel_mm_s2': (1e3 * ea).tolist(),
                             'gyro_mrad_s': (1e3 * eg).tolist()}
    return rows


def rms(v):
    """Return the RMS norm of (n, 3) vectors (nan for none)."""
    v = np.asarray(v, float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(v ** 2, 1)))) if len(v) else float('nan')


def pooled(cuts, band):
    """Return {policy: (gyro, accel)} RMS over every cut's blocks in the excess band."""
    lo, hi = band
    out = {}
    for p in POLICIES:
        g, a = [], []
        for c in cuts:
            if not c['blocks']:
                continue
            ex = np.asarray(c['block_excess_degC'])
            sel = (ex > lo) & (ex <= hi)
            g.extend(np.asarray(c['blocks'][p]['gyro_mrad_s'])[sel])
            a.extend(np.asarray(c['blocks'][p]['accel_mm_s2'])[sel])
        out[p] = (rms(g), rms(a), len(g))
    return out


def main(argv=None):
    """Score every cut; print the table (and write JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--csv', default=CSV)
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    imu, tc = read_tofupilot_chamber(args.csv)
    w = windows_from_columns([imu], [tc])
    temp = tc.temperature
    t = imu.stamp_ns * 1e-9
    i_turn = int(np.argmin(temp))
    cuts = []
    for tc_ in COOL_CUTS_DEGC:
        i = int(np.argmax(temp[:i_turn] <= tc_))
        cuts.append(score_cut(w, t, imu, temp, t[i], f'cooling at {tc_:g} degC'))
    for tc_ in HEAT_CUTS_DEGC:
        i = i_turn + int(np.argmax(temp[i_turn:] >= tc_))
        cuts.append(score_cut(w, t, imu, temp, t[i], f'heating at {tc_:g} degC'))
    print('real chamber log (training part): the default fitted before a cut, scored beyond '
          'its range after it; 30-s blocks about the fitted rows\' mean')
    print(f'{"cut":22s} {"range degC":>16s} {"blocks":>6s} | gyro mrad/s: clamp / linear / '
          'extrapolate | accel mm/s^2: clamp / linear / extrapolate')
    for c in cuts:
        n = len(c.get('block_excess_degC', []))
        g = [rms(c['blocks'][p]['gyro_mrad_s']) if n else float('nan') for p in POLICIES]
        a = [rms(c['blocks'][p]['accel_mm_s2']) if n else float('nan') for p in POLICIES]
        lo, hi = c['valid_range_degC']
        print(f'{c["cut"]:22s} {lo:7.1f}..{hi:6.1f} {n:6d} | '
              + ' / '.join(f'{v:.3f}' for v in g) + ' | '
              + ' / '.join(f'{v:.1f}' for v in a))
    bands = {}
    for band in EXCESS_BANDS + ((0.0, np.inf),):
        key = f'{band[0]:g}-{band[1]:g} degC'
        bands[key] = pooled(cuts, band)
        b = bands[key]
        print(f'pooled, beyond by {key:10s} ({b["clamp"][2]:4d} blocks): gyro '
              + ' / '.join(f'{b[p][0]:.3f}' for p in POLICIES) + '  accel '
              + ' / '.join(f'{b[p][1]:.1f}' for p in POLICIES))
    seconds = time.perf_counter() - t_start
    print(f'{seconds:.0f} s')
    if args.json:
        with open(args.json, 'w') as f:
            pooled_out = {k: {p: {'gyro_mrad_s': v[0], 'accel_mm_s2': v[1], 'blocks': v[2]}
                              for p, v in b.items()} for k, b in bands.items()}
            json.dump({'command': 'bench/out_of_range_real.py', 'seconds': seconds,
                       'cuts': cuts, 'pooled': pooled_out}, f, indent=1)


if __name__ == '__main__':
    main()
