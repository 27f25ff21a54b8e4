"""`calibrate` of a robot's log: the mounting pose's holds only, or every hold.

Usage (from the repository root; about 25 s a seed)::

    .venv/bin/python bench/robot_log_calibrate.py [--seeds 24 25 ...] [--fit-days 3]
        [--score-days 2] [--work DIR] [--out FILE]

A simulated robot (``sim.robot_month``, ``--latitude`` unknown, level stops within 0.3 deg,
10 % of the stops on 3-12 deg slopes) is written as a log of ``fit_days + score_days``; the
holds of its first ``fit_days`` are calibrated the way ``thermal-imu-calib calibrate`` does
(``app.calibrate.collect``, then ``estimation.calibrate.calibrate_windows`` with the CLI's
options), twice:

* ``mounting pose``: the default since 2026-11-29 (holds more than
  ``collection.segments.MOUNTING_POSE_DEG`` from the mounting pose are not fitted);
* ``every hold``: the same with that step disabled (the default before).

Each calibration is scored against the truth on the stops of the next ``score_days``
(``bench_lifelong.stop_error``: 30-s chunk means of the still samples, compensated minus
the true specific force / angular rate): the accelerometer's drift (RMS of the error
vectors less their median) over the level stops inside the calibration's valid
temperature range, the gyro RMS over every stop inside it, and the raw and true-model
figures beside them. Writes ``--out`` (default ``bench/results/robot_log_calibrate.json``).
"""

import argparse
import json
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

from bench_lifelong import drift_rms, scored_stops, stop_error  # noqa: E402
from thermal_imu_calib.app.calibrate import CalibrateSettings, collect, options  # noqa: E402
from thermal_imu_calib.collection.collected import (merge_transitions,  # noqa: E402
                                                    merge_windows)
from thermal_imu_calib.estimation import calibrate as estimation  # noqa: E402
from thermal_imu_calib.sim.robot_month import robot_month, write_robot_month  # noqa: E402

DAY = 86400.0
TOPIC = '/imu/data_raw'


def _every_hold(windows, o):
    return windows, o, []


def calibrations(log, fit_s, start_s):
    """Return {variant: Calibration} of the holds ending before ``start_s + fit_s``."""
    s = CalibrateSettings(gravity=9.80665)
    c = collect(s, log, TOPIC)
    w = merge_windows([c])
    w = w.select(w.t1 < start_s + fit_s)
    o = options(s, [c], merge_transitions([c]))
    out = {'mounting pose': estimation.calibrate_windows(w, o).calibration}
    default = estimation._mounting_pose_only
    estimation._mounting_pose_only = _every_hold
    try:
        out['every hold'] = estimation.calibrate_windows(w, o).calibration
    finally:
        estimation._mounting_pose_only = default
    return out


def rms(g):
    return float(np.sqrt(np.mean(np.sum(g ** 2, 1)))) if len(g) else float('nan')


def run_seed(seed, fit_days, score_days, work):
    """Return the row of one seed (every figure in m/s^2 and rad/s)."""
    days = fit_days + score_days
    log = os.path.join(work, f'robot_{seed}_{days:g}d.mcap')
    if not os.path.exists(log):
        write_robot_month(log, seed, days=days)
    m = robot_month(seed, days=days)
    first = next(iter(scored_stops(m)))[0]
    # the month's start as a header stamp (s): the first stop's still samples begin at t0
    still0 = first.imu.stamp_ns[np.flatnonzero(first.still)[0]] * 1e-9
    start_s = still0 - first.stop.t0
    cals = calibrations(log, fit_days * DAY, start_s)
    stops = list(scored_stops(m, fit_days * DAY, days * DAY))
    level = np.array([abs(sg.stop.slope_deg) < 1.0 for sg, _ in stops])
    raw = [stop_error(None, ch) for _, ch in stops]
    true = [stop_error(m.true_calibration(sg.stop.t0), ch) for sg, ch in stops]
    row = {'seed': seed, 'fit_days': fit_days, 'score_days': score_days,
           'stops': len(stops), 'slope_stops': int((~level).sum()), 'variants': {}}
    for name, cal in cals.items():
        lo, hi = np.asarray(cal.valid_range)[0]
        inside = np.array([lo <= ch['temp'].min() and ch['temp'].max() <= hi
                           for _, ch in stops])
        sel = level & inside
        err = [stop_error(cal, ch) for _, ch in stops]

        def acc(e, rows):
            return drift_rms(np.array([x[1] for x in e])[rows])

        def gyr(e, rows):
            return rms(np.array([x[0] for x in e])[rows])
        row['variants'][name] = {
            'holds': int(cal.fit['holds']),
            'accel_choice': next((n.split(' (weighting')[0] for n in cal.notes
                                  if n.startswith('accel: ')), None),
            'level_stops_inside': int(sel.sum()), 'stops_inside': int(inside.sum()),
            'accel_drift': acc(err, sel), 'accel_drift_raw': acc(raw, sel),
            'accel_drift_true': acc(true, sel),
            'gyro': gyr(err, inside), 'gyro_raw': gyr(raw, inside),
            'gyro_true': gyr(true, inside)}
    a, b = row['variants']['mounting pose'], row['variants']['every hold']
    row['accel_ratio'] = a['accel_drift'] / b['accel_drift']
    row['gyro_ratio'] = a['gyro'] / b['gyro']
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--seeds', type=int, nargs='+', default=list(range(24, 32)),
                   help='robot seeds (default 24-31, the ones the rule was judged on)')
    p.add_argument('--fit-days', type=float, default=3.0)
    p.add_argument('--score-days', type=float, default=2.0)
    p.add_argument('--work', default=None)
    p.add_argument('--out', default=os.path.join(HERE, 'results', 'robot_log_calibrate.json'))
    a = p.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='robot_log_calibrate_')
    os.makedirs(work, exist_ok=True)
    rows = []
    for seed in a.seeds:
        r = run_seed(seed, a.fit_days, a.score_days, work)
        rows.append(r)
        v = r['variants']
        print(f"seed {seed}: accel drift (level, in range) mounting pose "
              f"{v['mounting pose']['accel_drift'] * 1e3:.2f} / every hold "
              f"{v['every hold']['accel_drift'] * 1e3:.2f} mm/s^2 (raw "
              f"{v['every hold']['accel_drift_raw'] * 1e3:.2f}, true "
              f"{v['every hold']['accel_drift_true'] * 1e3:.2f}); gyro "
              f"{v['mounting pose']['gyro'] * 1e3:.4f} / {v['every hold']['gyro'] * 1e3:.4f} "
              f"mrad/s (true {v['every hold']['gyro_true'] * 1e3:.4f})", flush=True)
    ga = float(np.exp(np.mean(np.log([r['accel_ratio'] for r in rows]))))
    gg = float(np.exp(np.mean(np.log([r['gyro_ratio'] for r in rows]))))
    print(f'geometric mean ratio (mounting pose / every hold): accel drift {ga:.3f}, '
          f'gyro {gg:.3f}; worst accel ratio {max(r["accel_ratio"] for r in rows):.3f}')
    with open(a.out, 'w') as f:
        json.dump({'command': 'bench/robot_log_calibrate.py ' + ' '.join(
            argv if argv is not None else sys.argv[1:]),
            'geomean_accel_ratio': ga, 'geomean_gyro_ratio': gg, 'rows': rows}, f, indent=1)
    print(f'wrote {a.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
