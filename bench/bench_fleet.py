"""Fleet on Dask: speed-up of 2 workers over 1, CPU utilisation, memory; alarm rates.

``speed``: simulate-fleet (default 20 units x 5 logs, seed 0), then ``fleet calibrate`` on
a LocalCluster of 1 and of 2 single-threaded worker processes; prints wall time,
speed-up, CPU utilisation (worker CPU seconds / (wall x workers)) and the peak RSS per
worker. ``alarms``: for each seed, simulate a fleet and calibrate it per 20-day period
(one calibration per log) on a LocalCluster, once: the registry and the truth are cached
in ``--cache`` (default /tmp/alarms_cache/<units>x<logs>/seed_N), so a change of the alarm
statistic re-evaluates in seconds. Then count the alarms (``registry.assess``) on stable
units (false) and on drifting/step units (detected), and summarise the z of the stable
units' tests with the fit's own std (are the stds honest?).

    nice -n 10 .venv/bin/python bench/bench_fleet.py speed
    nice -n 10 .venv/bin/python bench/bench_fleet.py alarms --seeds 20 --units 8 --logs-per-unit 3
    nice -n 10 .venv/bin/python bench/bench_fleet.py alarms --seeds 10 --units 20 --logs-per-unit 5

Results go to bench/results/bench_fleet_speed.json, bench_fleet_alarms.json (8 x 3) or
bench_fleet_alarms_<units>x<logs>.json.
"""

import argparse
import functools
import json
import os
import shutil
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from thermal_imu_calib import cli  # noqa: E402
from thermal_imu_calib.app.fleet import calibrate_unit  # noqa: E402
from thermal_imu_calib.cli.fleet import fleet_settings  # noqa: E402
from thermal_imu_calib.fleet import registry as reg  # noqa: E402
from thermal_imu_calib.fleet.inputs import expand_inputs, GroupBy  # noqa: E402
from thermal_imu_calib.fleet.runner import run_fleet  # noqa: E402
from thermal_imu_calib.fleet.simulate import FleetDesign, read_truth, simulate_fleet  # noqa


def _worker_usage():
    import resource
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return {'cpu_s': ru.ru_utime + ru.ru_stime, 'maxrss_mb': ru.ru_maxrss / 1024.0}


def _calibrate(paths, workers, period=0.0):
    from distributed import Client, LocalCluster
    args = cli.build_parser().parse_args(['fleet', 'calibrate', '-', '-o', '-'])
    reduce_fn = functools.partial(calibrate_unit, fleet_settings(args), None)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=':0') as cluster, Client(cluster) as client:
        client.wait_for_workers(workers)
        before = client.run(_worker_usage)
        t = time.perf_counter()
        units, failed = run_fleet(client, paths, GroupBy('frame_id'), reduce_fn, {},
                                  period, progress=False)
        wall = time.perf_counter() - t
        after = client.run(_worker_usage)
    cpu = sum(after[w]['cpu_s'] - before[w]['cpu_s'] for w in after)
    return units, failed, {'workers': workers, 'wall_s': round(wall, 2),
                           'worker_cpu_s': round(cpu, 2),
                           'cpu_utilisation': round(cpu / (wall * workers), 3),
                           'peak_rss_mb_per_worker': round(max(a['maxrss_mb']
                                                               for a in after.values()), 1)}


def speed(args):
    """2 workers vs 1 on one simulated fleet."""
    d = tempfile.mkdtemp(prefix='bench_fleet_')
    try:
        design = FleetDesign(units=args.units, logs_per_unit=args.logs_per_unit, seed=0)
        from distributed import Client, LocalCluster
        with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=':0') as c, \
                Client(c) as client:
            simulate_fleet(os.path.join(d, 'logs'), design, client)
        paths = expand_inputs([os.path.join(d, 'logs')])
        runs = []
        for n in (1, 2):
            units, failed, stats = _calibrate(paths, n)
            assert not failed and not any(u.error for u in units), 'a unit failed'
            runs.append(stats)
        out = {'units': args.units, 'logs_per_unit': args.logs_per_unit, 'logs': len(paths),
               'cpus': os.cpu_count(), 'load_avg_1min': os.getloadavg()[0], 'runs': runs,
               'speed_up': round(runs[0]['wall_s'] / runs[1]['wall_s'], 2)}
    finally:
        shutil.rmtree(d, ignore_errors=True)
    print('| workers | wall [s] | worker CPU [s] | CPU utilisation | peak RSS/worker [MB] |\n'
          '|---|---|---|---|---|')
    for r in out['runs']:
        print(f'| {r["workers"]} | {r["wall_s"]} | {r["worker_cpu_s"]} | '
              f'{100 * r["cpu_utilisation"]:.0f} % | {r["peak_rss_mb_per_worker"]} |')
    print(f'speed-up 2 vs 1 workers: {out["speed_up"]}x ({out["logs"]} logs, '
          f'{out["cpus"]} CPUs, load average {out["load_avg_1min"]:.2f} at the end)')
    return out


def cache_dir(cache, units, logs_per_unit, seed):
    """Return the cache directory of one simulated and calibrated fleet."""
    return os.path.join(cache, f'{units}x{logs_per_unit}', f'seed_{seed}')


def calibrated_fleet(client, cache, units, logs_per_unit, seed, reduce_fn):
    """Return DIR holding reg/ (the registry) and fleet_truth.csv of one seed, cached.

    Simulates the fleet, calibrates it per 20-day period (one calibration per log) and keeps
    only the registry and the truth (the logs are deleted); a second call reads the cache,
    so a change of the alarm statistic re-evaluates without recalibrating.
    """
    d = cache_dir(cache, units, logs_per_unit, seed)
    if os.path.isfile(os.path.join(d, 'reg', reg.INDEX)):
        return d
    tmp = d + '.tmp'
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    try:
        design = FleetDesign(units=units, logs_per_unit=logs_per_unit, seed=seed)
        logs = os.path.join(tmp, 'logs')
        t = time.perf_counter()
        simulate_fleet(logs, design, client)
        paths = expand_inputs([logs])
        units_out, failed = run_fleet(client, paths, GroupBy('frame_id'), reduce_fn, {},
                                      design.spacing_days * 2 / 3, progress=False)
        reg.add(os.path.join(tmp, 'reg'), [
            (u.sensor, u.result.calibration, u.end_ns, u.start_ns, u.logs)
            for u in units_out if not u.error])
        shutil.copy(os.path.join(logs, 'fleet_truth.csv'), tmp)
        with open(os.path.join(tmp, 'refused.json'), 'w') as f:
            json.dump({'failed_logs': [h.path for h in failed],
                       'failed_units': [[u.sensor, u.error] for u in units_out if u.error],
                       'seconds': round(time.perf_counter() - t, 1)}, f)
        shutil.rmtree(logs)
        os.replace(tmp, d)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return d


def read_rows(d, pooled=True, pooled_k=True):
    """Return the registry rows of a cached fleet; ``pooled`` False: without the terms given S.

    A registry without the columns of ``fleet/pooled_s.py`` is tested on the terms' own
    (marginal) stds, as before they existed: the same calibrations, judged both ways.
    ``pooled_k`` False: without the scale factor's curvature on S, so only the bias is
    tested at the pooled S (as from 2026-12-03 morning to its curvature).
    """
    from thermal_imu_calib.fleet.pooled_s import without_given_s
    rows = reg.read_index(os.path.join(d, 'reg'))
    if not pooled_k:
        rows = [{k: v for k, v in r.items() if '_dss.' not in k} for r in rows]
    return rows if pooled else without_given_s(rows)


def evaluate_seed(d, seed, std_scale=None, pooled=True, pooled_k=True):
    """Return one seed's row: stable units flagged (false) and drifting/step units flagged."""
    rows = read_rows(d, pooled, pooled_k)
    found, info = reg.assess(rows, std_scale=std_scale)
    flagged = {s for s, a in found.items() if a}
    truth = read_truth(d)
    stable = {u for u, t in truth.items() if t['kind'] == 'stable'}
    with open(os.path.join(d, 'refused.json')) as f:
        refused = json.load(f)
    worst = max(stable, key=lambda u: info['max_abs_z'].get(u, 0.0))
    return {'seed': seed, 'stable': len(stable), 'false_alarms': len(flagged & stable),
            'falsely_flagged': {u: found[u] for u in sorted(flagged & stable)},
            'special': len(truth) - len(stable), 'detected': len(flagged - stable),
            'missed': sorted(set(truth) - stable - flagged), 'tests': info['tests'],
            'threshold_sigma': round(info['threshold_sigma'], 3),
            'worst_stable': [worst, round(info['max_abs_z'].get(worst, 0.0), 2)],
            'weakest_special': min(([u, round(info['max_abs_z'][u], 2)]
                                    for u in set(truth) - stable if u in info['max_abs_z']),
                                   key=lambda x: x[1], default=None),
            'refused': len(refused['failed_logs']) + len(refused['failed_units'])}


def stable_z(d, std_scale, pooled=True, pooled_k=True):
    """Return {test kind: z list} of the stable units (truth): consecutive changes, trends.

    With ``std_scale`` {} the fit's own stds: what says whether they are honest. At the
    unit's pooled S when the rows have their terms given S (``pooled``).
    """
    from thermal_imu_calib.fleet.alarms import accel_family
    from thermal_imu_calib.fleet.pooled_s import unit_pools
    truth = read_truth(d)
    rows = [r for r in read_rows(d, pooled, pooled_k)
            if truth[r['sensor']]['kind'] == 'stable']
    out = {}
    for rs in reg.by_sensor(rows).values():
        ps = unit_pools(rs, accel_family)
        for prev, cur in zip(rs, rs[1:]):
            for name, z in reg.compare(prev, cur, std_scale=std_scale,
                                       pooled=ps.get(accel_family(cur))).items():
                out.setdefault(f'{name} change', []).extend(z.tolist())
        if len(rs) >= 3:
            for name in reg.ALARM_ON:
                out.setdefault(f'd{name}0 trend', []).extend(reg.trend(
                    rs, name, std_scale, pooled=ps.get(accel_family(rs[-1]))).tolist())
    return out


def _z_summary(v):
    import numpy as np
    from scipy.stats import kstest
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return {'n': len(v), 'ks_p_vs_normal_0_1': round(float(kstest(v, 'norm').pvalue), 4),
            'mean': round(float(v.mean()), 3), 'std': round(float(v.std()), 3),
            'robust_std': round(float(1.4826 * np.median(np.abs(v - np.median(v)))), 3),
            'frac_abs_gt_2': round(float(np.mean(np.abs(v) > 2)), 4),
            'frac_abs_gt_3': round(float(np.mean(np.abs(v) > 3)), 4),
            'max_abs': round(float(np.abs(v).max()), 2)}


def alarms(args):
    """Alarm rates over seeds: false alarms on stable units, detection of the others."""
    from distributed import Client, LocalCluster
    cargs = cli.build_parser().parse_args(['fleet', 'calibrate', '-', '-o', '-'])
    reduce_fn = functools.partial(calibrate_unit, fleet_settings(cargs), None)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    todo = [s for s in seeds if not os.path.isfile(os.path.join(cache_dir(
        args.cache, args.units, args.logs_per_unit, s), 'reg', reg.INDEX))]
    if todo:
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=':0') as cluster, Client(cluster) as client:
            for seed in todo:
                d = calibrated_fleet(client, args.cache, args.units, args.logs_per_unit, seed,
                                     reduce_fn)
                print(f'seed {seed}: calibrated into {d}', flush=True)
    rows_out, zs_fit = [], {}
    for seed in seeds:
        d = cache_dir(args.cache, args.units, args.logs_per_unit, seed)
        row = evaluate_seed(d, seed, pooled=not args.no_pooled_s,
                            pooled_k=not args.no_pooled_k)
        rows_out.append(row)
        print(row, flush=True)
        for k, v in stable_z(d, {}, pooled=not args.no_pooled_s,
                             pooled_k=not args.no_pooled_k).items():
            zs_fit.setdefault(k, []).extend(v)
    fa = sum(r['false_alarms'] for r in rows_out)
    st = sum(r['stable'] for r in rows_out)
    det = sum(r['detected'] for r in rows_out)
    sp = sum(r['special'] for r in rows_out)
    out = {'units': args.units, 'logs_per_unit': args.logs_per_unit, 'seeds': list(seeds),
           'family_rate': reg.FAMILY_RATE, 'std_scale': reg.STD_SCALE,
           'pooled_s': not args.no_pooled_s,
           'pooled_k': not (args.no_pooled_s or args.no_pooled_k),
           'alarm_on': [f'd{n}0' for n in reg.ALARM_ON],
           'false_alarms': fa, 'stable_units': st, 'false_alarm_rate': fa / max(st, 1),
           'seeds_with_false_alarm': sum(r['false_alarms'] > 0 for r in rows_out),
           'detected': det, 'special_units': sp, 'detection_rate': det / max(sp, 1),
           'stable_z_fit_std': {k: _z_summary(v) for k, v in zs_fit.items()},
           'per_seed': rows_out}
    for k, v in out['stable_z_fit_std'].items():
        print(f'stable units, z of {k} with the fit\'s std: {v}')
    print(f'false alarms: {fa} of {st} stable units ({100 * fa / max(st, 1):.1f} %), '
          f'{out["seeds_with_false_alarm"]} of {len(seeds)} seeds with any; detected '
          f'{det} of {sp} drifting/step units ({100 * det / max(sp, 1):.1f} %)')
    return out


def main():
    """Parse the mode and write bench/results/bench_fleet_<mode>.json."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('mode', choices=('speed', 'alarms'))
    ap.add_argument('--units', type=int, default=None)
    ap.add_argument('--logs-per-unit', type=int, default=None)
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--first-seed', type=int, default=0)
    ap.add_argument('--cache', default='/tmp/alarms_cache',
                    help='alarms: one calibrated registry per fleet size and seed is kept here '
                         '(DIR/<units>x<logs>/seed_N); delete it to recalibrate')
    ap.add_argument('--out', default=None,
                    help='write the JSON here (default bench/results/bench_fleet_<mode>.json)')
    ap.add_argument('--no-pooled-s', action='store_true',
                    help='alarms: test the cached calibrations on their terms\' own stds, '
                         'without the pooled S (fleet/pooled_s.py), as before it existed')
    ap.add_argument('--no-pooled-k', action='store_true',
                    help='alarms: the bias alone at the pooled S (the scale factor on its '
                         'own stds: its curvature on S left out), as before the curvature')
    args = ap.parse_args()
    big = args.mode == 'speed'
    args.units = args.units or (20 if big else 8)
    args.logs_per_unit = args.logs_per_unit or (5 if big else 3)
    out = speed(args) if big else alarms(args)
    os.makedirs(os.path.join(HERE, 'results'), exist_ok=True)
    name = args.mode if big or (args.units, args.logs_per_unit) == (8, 3) else \
        f'alarms_{args.units}x{args.logs_per_unit}'
    path = args.out or os.path.join(HERE, 'results', f'bench_fleet_{name}.json')
    with open(path, 'w') as f:
        json.dump(out, f, indent=1)
    print(f'wrote {path}')


if __name__ == '__main__':
    main()
