"""Should a history that turns once also hold out blocks of its first leg? (issue 22)

For one orientation across a temperature history that turns once (cool then heat, like the
real chamber log's training part), ``selection.time_folds`` holds out the last part of the
last leg, fitted on what came before. Those folds test one direction only (the last
leg's); the calibration is then used on the next leg, which runs the other way. The
question is whether adding folds that hold out the first part of the first leg (fitted on
what came after; ``with_backward_folds`` wraps ``time_folds.time_folds`` for the run, the
package itself has no such option) chooses models that predict the next leg better.

Judged on data neither the fit nor the choice saw: simulated ``chamber-2hz`` logs (one
pose, -20..75 degC at 1 degC/min, 10-min dwells, errors through a 300-s lag) with two
cycles and the unmodelled effects of ``sim.unmodelled`` on top (cubic drift, a second
time constant, per-axis temperature offsets, tanh hysteresis, 1/f bias wander). Per seed
two splits: legs 0-1 (heat, cool) calibrated, leg 2 (heat) tested; legs 1-2 (cool, heat)
calibrated, leg 3 (cool) tested, the real chamber log's structure. The calibration is
``calibrate_windows`` with default options on the training windows (what
``thermal-imu-calib calibrate`` does), streamed over every window of the log from its
start (the history terms see the history a compensator would), scored on the test leg's
windows inside the training temperature range: RMS over 30-s blocks of |block mean - leg
mean| (3-vector), the chamber log's figure. The ArduPilot-style cubic fitted on the same
windows is printed beside.

Criteria, written before the first run: the backward folds (cuts at 25, 50, 75 % of the
first leg) are adopted only if, over all cases (seeds x 2 splits), (1) the geometric
mean of backward/today is <= 0.97 for one sensor and <= 1.00 for the other, (2) no case
is worse than 1.10x, (3) the cool+heat -> cool split alone has a geometric mean <= 1.00
for both sensors. Otherwise the folds stay as they are, and the result is documented.

Usage: ``python bench/turn_once_folds.py [--seeds 0 1 2 3 4 5 6 7] [--json FILE]``
"""

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.calibration import TemperatureInput  # noqa: E402
from thermal_imu_calib.collection.feed import windows_from_columns  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (calibrate_windows,  # noqa: E402
                                                    CalibrateOptions)
from thermal_imu_calib.estimation.hysteresis import ARDUPILOT_SPEC  # noqa: E402
from thermal_imu_calib.estimation.thermal_lag import legs  # noqa: E402
from thermal_imu_calib.selection import time_folds  # noqa: E402
from thermal_imu_calib.sim.unmodelled import with_unmodelled  # noqa: E402

sys.path.insert(0, os.path.join(ROOT, 'bench'))
from bench_chamber import block_drift, spec_calibration  # noqa: E402

TOPIC = '/imu/temperature'
SPLITS = {'heat+cool -> heat': ((0, 1), 2), 'cool+heat -> cool': ((1, 2), 3)}


def score(cal, w, rows):
    """Stream ``cal`` over every window (time order); return (accel, gyro) drift on rows."""
    t = 0.5 * (w.t0 + w.t1)
    order = np.argsort(t, kind='stable')
    res = cal.stream().apply(t[order], w.accel[order], w.gyro[order], w.temp[order][:, :1])
    sel = rows[order]
    return (block_drift(t[order][sel], res.accel[sel]),
            block_drift(t[order][sel], res.gyro[sel]))


def with_backward_folds(forward, cuts=time_folds.FORWARD_CUTS):
    """Return ``time_folds.time_folds`` plus, for a history that turns once, backward folds.

    The first leg before each fraction ``cuts`` of its time span is held out, fitted on what
    came after it (at least 8 training and 2 test windows, as the forward folds).
    """
    def folds_of(windows, column=0):
        folds, kind = forward(windows, column)
        leg_ids, info = legs(windows, column)
        if len(info) == 2:
            tm = 0.5 * (windows.t0 + windows.t1)
            first = tm[leg_ids == info[0]['leg']]
            for f in cuts:
                test = tm < first.min() + f * (first.max() - first.min())
                if (~test).sum() >= 8 and test.sum() >= 2:
                    folds.append((~test, test, f'before {100 * f:.0f} % of the first leg'))
        return folds, kind
    return folds_of


def run_case(w, ids, train_legs, test_leg):
    """Return {method: (accel, gyro)} and the default's choices for one split."""
    train = np.isin(ids, train_legs)
    wt = w.select(train)
    lo, hi = wt.temp[:, 0].min(), wt.temp[:, 0].max()
    rows = (ids == test_leg) & (w.temp[:, 0] >= lo) & (w.temp[:, 0] <= hi)
    opts = CalibrateOptions(inputs=[TemperatureInput(TOPIC)])
    out, chose = {}, {}
    t = 0.5 * (w.t0 + w.t1)
    out['raw'] = (block_drift(t[rows], w.accel[rows]), block_drift(t[rows], w.gyro[rows]))
    forward = time_folds.time_folds
    for name, folds in (('today', forward), ('backward', with_backward_folds(forward))):
        time_folds.time_folds = folds
        try:
            r = calibrate_windows(wt, opts)
        finally:
            time_folds.time_folds = forward
        out[name] = score(r.calibration, w, rows)
        mc = r.calibration.fit.get('model_choice', {})
        chose[name] = {k: mc.get(k) for k in ('accel', 'gyro', 'family') if k in mc}
        chose[name]['reason'] = str(mc.get('reason', ''))[:400]
    t0 = np.round(np.full(3, 0.5 * (lo + hi)), 2)
    out['ArduPilot-style cubic'] = score(spec_calibration(wt, ARDUPILOT_SPEC, t0), w, rows)
    return out, chose


def main(argv=None):
    """Run the experiment; print a table and the verdict (and write JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=list(range(8)))
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    cases = []
    for seed in args.seeds:
        t_start = time.perf_counter()
        rec = with_unmodelled(sim.simulate('chamber-2hz', seed, cycles=2))
        w = windows_from_columns(rec.imu_chunks(),
                                 [rec.temperatures[t] for t in rec.config.temp_topics])
        ids, info = legs(w)
        if len(info) < 4:
            print(f'seed {seed}: {len(info)} legs, skipped')
            continue
        for split, (train_legs, test_leg) in SPLITS.items():
            res, chose = run_case(w, ids, train_legs, test_leg)
            cases.append({'seed': seed, 'split': split, 'figures': res, 'chose': chose})
            r = {k: v for k, v in res.items()}
            print(f'seed {seed} {split:18s} raw {r["raw"][0]:.4f} {r["raw"][1]:.6f} | '
                  f'cubic {r["ArduPilot-style cubic"][0]:.4f} '
                  f'{r["ArduPilot-style cubic"][1]:.6f} | today {r["today"][0]:.4f} '
                  f'{r["today"][1]:.6f} | backward {r["backward"][0]:.4f} '
                  f'{r["backward"][1]:.6f} | ratio {r["backward"][0] / r["today"][0]:.3f} '
                  f'{r["backward"][1] / r["today"][1]:.3f}', flush=True)
        print(f'  ({time.perf_counter() - t_start:.0f} s)', flush=True)
    verdict = {}
    for sig, k in (('accel', 0), ('gyro', 1)):
        ratios = np.array([c['figures']['backward'][k] / c['figures']['today'][k]
                           for c in cases])
        cool = np.array([c['figures']['backward'][k] / c['figures']['today'][k]
                         for c in cases if c['split'] == 'cool+heat -> cool'])
        verdict[sig] = {'geomean': float(np.exp(np.mean(np.log(ratios)))),
                        'worst': float(ratios.max()),
                        'geomean_cool_heat_cool': float(np.exp(np.mean(np.log(cool))))}
    g = sorted(v['geomean'] for v in verdict.values())
    ok = (g[0] <= 0.97 and g[1] <= 1.00 and all(v['worst'] <= 1.10 for v in verdict.values())
          and all(v['geomean_cool_heat_cool'] <= 1.00 for v in verdict.values()))
    print('verdict: ' + json.dumps(verdict) + (' -> ADOPT' if ok else ' -> not adopted'))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'cases': cases, 'verdict': verdict, 'adopt': bool(ok)}, f, indent=1)


if __name__ == '__main__':
    main()
