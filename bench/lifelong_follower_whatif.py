"""What a gyro follower would have given on finished month runs (a design what-if).

The follower (``lifelong.follower``, ``LifelongConfig.gyro_follow``) takes off the
published gyro the active model's mean error on the newest holds. This diagnostic scores
every stop of finished ``bench_lifelong.py month`` runs as the bench does (the calibration
active when the stop began, from the registry; the stop's sample-weighted mean error) and
again less a follower's offset from the stops *before* it: their compensated gyro means
under the same calibration, less the known vertical earth rate along their specific force,
weighted ``exp(-age / tau)`` (equal per stop) with optionally a Gaussian kernel in
temperature, over the last ``--horizon-days``; none below ``--min-stops`` effective stops.
Stops after the month's knock use only stops after it (the loop's alarm cuts or shifts
its store; here the knock time is the simulation's). Printed per seed: the gyro last week
over the true model's, as run and per variant.

    python bench/lifelong_follower_whatif.py 144:/tmp/acc3/w144/seed144 ...

A what-if on truly still samples and the months as they ran, not the loop: the loop's
follower uses the store's detected holds. Units: days, degC; ratios. No ROS import.
"""

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import active_index, registry_timeline, scored_stops, stop_error  # noqa: E402
from thermal_imu_calib.estimation.gyro_static import earth_rate_parts  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def load(seed, work_seed, days=30.0):
    """Return per stop of a finished month: times, active index, compensated means, truth."""
    m = robot_month(seed, days=days)
    starts, cals = registry_timeline(work_seed, m.start_ns)
    chs, t0, t1, idx = [], [], [], []
    for seg, ch in scored_stops(m):
        i = active_index(starts, seg.stop.t0)
        if i >= 0:
            chs.append(ch)
            t0.append(seg.stop.t0)
            t1.append(seg.stop.t1)
            idx.append(i)
    sid = np.concatenate([np.full(len(c['n']), k) for k, c in enumerate(chs)])
    cat = {k: np.concatenate([c[k] for c in chs])
           for k in ('n', 't', 'accel', 'gyro', 'w', 'temp')}
    ns = np.bincount(sid, cat['n'])

    def smean(x):
        return np.stack([np.bincount(sid, x[:, j] * cat['n']) for j in range(3)], 1) \
            / ns[:, None]
    comp_g, comp_a = {}, {}
    for k in sorted(set(idx)):               # each calibration on every stop at once
        res = cals[k].apply(cat['accel'], cat['gyro'], cat['temp'][:, :1], stamps=cat['t'])
        comp_g[k], comp_a[k] = smean(res.gyro), smean(res.accel)
    true_err = np.array([stop_error(m.true_calibration(a), ch)[0] for a, ch in zip(t0, chs)])
    return {'t0': np.array(t0), 't1': np.array(t1), 'idx': np.array(idx), 'w': smean(cat['w']),
            'temp': np.bincount(sid, cat['temp'][:, 0] * cat['n']) / ns, 'comp_g': comp_g,
            'comp_a': comp_a, 'true_err': true_err, 'knock': m.knock_t,
            'lat': m.config.latitude}


def follow(d, tau_days, temp_scale=None, min_stops=5, horizon_days=2.0):
    """Return (error as run, error less the follower's offset), (stops, 3) rad/s each."""
    vertical, _ = earth_rate_parts(d['lat'])
    n = len(d['t0'])
    err, off = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        g, a = d['comp_g'][d['idx'][i]], d['comp_a'][d['idx'][i]]
        err[i] = g[i] - d['w'][i]
        prior = np.flatnonzero((d['t1'] <= d['t0'][i])
                               & (d['t1'] > d['t0'][i] - horizon_days * DAY))
        if d['t0'][i] >= d['knock']:
            prior = prior[d['t0'][prior] >= d['knock']]
        if not len(prior):
            continue
        up = a[prior] / np.linalg.norm(a[prior], axis=1, keepdims=True)
        wt = np.exp(-(d['t0'][i] - d['t1'][prior]) / (tau_days * DAY))
        if temp_scale:
            wt = wt * np.exp(-0.5 * ((d['temp'][prior] - d['temp'][i]) / temp_scale) ** 2)
        if wt.sum() ** 2 / np.sum(wt ** 2) >= min_stops:
            off[i] = wt @ (g[prior] - vertical * up) / wt.sum()
    return err, err - off


def rms(v):
    return float(np.sqrt(np.mean(np.sum(np.asarray(v) ** 2, 1))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('runs', nargs='+', help='SEED:WORK_DIR/seedSEED of a finished month run')
    ap.add_argument('--days', type=float, default=30.0)
    ap.add_argument('--tau-days', type=float, nargs='+', default=[0.1, 0.25, 0.5, 1.0, 2.0])
    ap.add_argument('--temp-scale', type=float, nargs='*', default=[3.0],
                    help='also each tau with this temperature kernel (degC)')
    ap.add_argument('--horizon-days', type=float, default=2.0)
    ap.add_argument('--min-stops', type=float, default=5.0)
    ap.add_argument('--output', default='')
    args = ap.parse_args()
    variants = [(tau, None) for tau in args.tau_days] + \
        [(tau, ts) for ts in args.temp_scale for tau in args.tau_days]
    out = {'command': ' '.join(sys.argv), 'seeds': {}}
    for spec in args.runs:
        seed, path = spec.split(':', 1)
        d = load(int(seed), path, args.days)
        last = d['t0'] >= (args.days - 7) * DAY
        true = rms(d['true_err'][last])
        res = {'true_mrad_s': true * 1e3}
        for tau, ts in variants:
            err, fol = follow(d, tau, ts, args.min_stops, args.horizon_days)
            res['as run'] = rms(err[last]) / true
            res[f'tau {tau:g} d' + (f', {ts:g} degC' if ts else '')] = rms(fol[last]) / true
        out['seeds'][seed] = res
        print(f'seed {seed}: gyro last week / true model: ' + ', '.join(
            f'{k} {v:.2f}' for k, v in res.items() if k != 'true_mrad_s'), flush=True)
    if args.output:
        with open(args.output, 'w') as f:
            json.dump(out, f, indent=1)


if __name__ == '__main__':
    main()
