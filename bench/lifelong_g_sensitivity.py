"""After the fact: what the gyro g-sensitivity stage would change on finished robot months.

For finished ``bench_lifelong.py month`` runs (``SEED:WORK_SEED_DIR``), each calibration
the month activated (the registry is the timeline) is given the g-sensitivity that
``lifelong.g_sensitivity.learn`` finds for it on the month's stops before its activation
(the last ``--pool-days``; each stop one hold, each <= 60-s chunk of its still samples one
window, as ``bench_lifelong.stop_chunks`` cuts them), and ``attach`` applies when the
newest of them, held out, support it. Every stop of the last week is then scored as
``bench_lifelong.py`` scores it (gyro error against the true rate, sample-weighted), with
the calibration as activated and with the coupling. Printed per seed: the last week's gyro
RMS (mrad/s) of all stops, of the slope stops and of the level ones, without / with, and
how many activations took a coupling.

This is not the loop: the lifelong store keeps only the stops its detector and hints
accept, compacts old ones into temperature bins, and the swap gate and the alarms would
see the coupled gyro. ``bench_lifelong.py month --gyro-g-sensitivity`` runs the loop.

    python bench/lifelong_g_sensitivity.py 39:/tmp/m39/d39/seed39 \\
        --latitude 45 --output bench/results/lifelong_g_sensitivity.json
"""

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import (  # noqa: E402
    active_index, registry_timeline, scored_stops, stop_error)
from lifelong_error_sources import rms  # noqa: E402
from thermal_imu_calib.collection.segments import Windows  # noqa: E402
from thermal_imu_calib.lifelong import g_sensitivity  # noqa: E402
from thermal_imu_calib.lifelong.config import LifelongConfig  # noqa: E402
from thermal_imu_calib.lifelong.pose import main_pose_mask  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def stop_windows(rows):
    """Return ``Windows`` of (stop, chunks) rows: one hold per stop, a window per chunk."""
    parts = []
    for h, (s, ch) in enumerate(rows):
        m = len(ch['n'])
        parts.append(Windows(np.full(m, h), np.full(m, s.t0), np.full(m, s.t1),
                             ch['n'].astype(int), ch['accel'], ch['gyro'],
                             np.zeros((m, 3)), np.zeros((m, 3)), ch['temp'],
                             np.zeros((m, ch['temp'].shape[1]))))
    return Windows.concat(parts)


def score_seed(seed, work_seed, days, latitude, pool_days, pose_deg):
    m = robot_month(seed, days=days)
    acts, cals = registry_timeline(work_seed, m.start_ns)
    rows = list(scored_stops(m))
    ends = np.array([seg.stop.t1 for seg, _ in rows])
    coupled, notes = {}, []
    out = {'all': ([], []), 'slope': ([], []), 'level': ([], [])}
    for seg, ch in rows:
        s = seg.stop
        if s.t0 < days * DAY - 7 * DAY:
            continue
        i = active_index(acts, s.t0)
        if i < 0:
            continue
        if i not in coupled:
            pool = [(r[0].stop, r[1]) for r, e in zip(rows, ends)
                    if acts[i] - pool_days * DAY <= e < acts[i]]
            win = stop_windows(pool)
            c = g_sensitivity.learn(cals[i], win, main_pose_mask(win, pose_deg),
                                    cals[i].gravity, latitude)
            coupled[i] = g_sensitivity.attach(cals[i], c)[0]
            notes.append({'activation': int(i), 'day': float(acts[i] / DAY), 'used': c.used,
                          'text': c.text})
        e0 = stop_error(cals[i], ch)[0]
        e1 = stop_error(coupled[i], ch)[0]
        for k in ('all', 'slope' if s.slope_deg > 0 else 'level'):
            out[k][0].append(e0)
            out[k][1].append(e1)
    return out, notes


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('runs', nargs='+', help='SEED:WORK_DIR/seedSEED of a finished month run')
    ap.add_argument('--days', type=float, default=30.0)
    ap.add_argument('--latitude', type=float, default=None)
    ap.add_argument('--pool-days', type=float, default=14.0,
                    help='stops before an activation the coupling is learned from (days)')
    ap.add_argument('--output', default='')
    args = ap.parse_args()
    pose = LifelongConfig().pose_deg
    result = {'command': ' '.join(sys.argv), 'seeds': {}}
    pooled = {k: ([], []) for k in ('all', 'slope', 'level')}
    for spec in args.runs:
        seed, d = spec.split(':', 1)
        out, notes = score_seed(int(seed), d, args.days, args.latitude, args.pool_days, pose)
        r = {k: {'stops': len(v[0]), 'without_mrad_s': rms(v[0]) * 1e3,
                 'with_mrad_s': rms(v[1]) * 1e3}
             for k, v in out.items()}
        r['activations_scored'] = len(notes)
        r['activations_coupled'] = sum(n['used'] for n in notes)
        r['notes'] = notes
        result['seeds'][seed] = r
        for k in pooled:
            pooled[k][0].extend(out[k][0])
            pooled[k][1].extend(out[k][1])
        print(f'seed {seed}: last week gyro mrad/s without / with: ' + '; '.join(
            f'{k} {r[k]["stops"]}: {r[k]["without_mrad_s"]:.4f} / {r[k]["with_mrad_s"]:.4f}'
            for k in ('all', 'slope', 'level')) + f'; coupled {r["activations_coupled"]} of '
            f'{r["activations_scored"]} activations', flush=True)
    result['pooled'] = {k: {'stops': len(v[0]), 'without_mrad_s': rms(v[0]) * 1e3,
                            'with_mrad_s': rms(v[1]) * 1e3} for k, v in pooled.items()}
    print('pooled: ' + '; '.join(f'{k} {v["stops"]}: {v["without_mrad_s"]:.4f} / '
                                 f'{v["with_mrad_s"]:.4f}'
                                 for k, v in result['pooled'].items()))
    if args.output:
        with open(args.output, 'w') as f:
            json.dump(result, f, indent=1)


if __name__ == '__main__':
    main()
