"""Fleet on Dask: speed-up of 2 workers over 1, CPU utilisation, memory; alarm rates.

``speed``: simulate-fleet (default 20 units x 5 logs, seed 0), then ``fleet calibrate`` on
a LocalCluster of 1 and of 2 single-threaded worker processes; prints wall time,
speed-up, CPU utilisation (worker CPU seconds / (wall x workers)) and the peak RSS per
worker. ``alarms``: for each seed, simulate a fleet, calibrate it per 20-day period
and count the alarms on stable units (false) and on drifting/step units (detected).

    .venv/bin/python bench/bench_fleet.py speed
    .venv/bin/python bench/bench_fleet.py alarms --seeds 20 --units 8 --logs-per-unit 3

Results go to bench/results/bench_fleet_<mode>.json and a markdown table on stdout.
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
from thermal_imu_calib.cli_fleet import calibrate_args  # noqa: E402
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
    reduce_fn = functools.partial(cli.calibrate_collected, calibrate_args(args))
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


def alarms(args):
    """Alarm rates over seeds: false alarms on stable units, detection of the others."""
    from distributed import Client, LocalCluster
    rows_out = []
    cargs = cli.build_parser().parse_args(['fleet', 'calibrate', '-', '-o', '-'])
    reduce_fn = functools.partial(cli.calibrate_collected, calibrate_args(cargs))
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=':0') as cluster, Client(cluster) as client:
        for seed in range(args.seeds):
            d = tempfile.mkdtemp(prefix='bench_fleet_alarm_')
            try:
                design = FleetDesign(units=args.units, logs_per_unit=args.logs_per_unit,
                                     seed=seed)
                simulate_fleet(os.path.join(d, 'logs'), design, client)
                paths = expand_inputs([os.path.join(d, 'logs')])
                units, failed = run_fleet(client, paths, GroupBy('frame_id'), reduce_fn, {},
                                          design.spacing_days * 2 / 3, progress=False)
                reg.add(os.path.join(d, 'reg'), [
                    (u.sensor, u.result.calibration, u.end_ns, u.start_ns, u.logs)
                    for u in units if not u.error])
                flagged = {s for s, a in reg.alarms(reg.read_index(os.path.join(d, 'reg')))
                           .items() if a}
                truth = read_truth(os.path.join(d, 'logs'))
                stable = {u for u, t in truth.items() if t['kind'] == 'stable'}
                row = {'seed': seed, 'stable': len(stable),
                       'false_alarms': len(flagged & stable),
                       'special': len(truth) - len(stable), 'detected': len(flagged - stable),
                       'refused': sum(bool(u.error) for u in units) + len(failed)}
                rows_out.append(row)
                print(row, flush=True)
            finally:
                shutil.rmtree(d, ignore_errors=True)
    fa = sum(r['false_alarms'] for r in rows_out)
    st = sum(r['stable'] for r in rows_out)
    det = sum(r['detected'] for r in rows_out)
    sp = sum(r['special'] for r in rows_out)
    out = {'units': args.units, 'logs_per_unit': args.logs_per_unit, 'seeds': args.seeds,
           'per_seed': rows_out, 'false_alarm_rate': fa / max(st, 1),
           'detection_rate': det / max(sp, 1),
           'seeds_with_false_alarm': sum(r['false_alarms'] > 0 for r in rows_out)}
    print(f'false alarms: {fa} of {st} stable units ({100 * fa / max(st, 1):.1f} %), '
          f'{out["seeds_with_false_alarm"]} of {args.seeds} seeds with any; detected '
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
    args = ap.parse_args()
    big = args.mode == 'speed'
    args.units = args.units or (20 if big else 8)
    args.logs_per_unit = args.logs_per_unit or (5 if big else 3)
    out = speed(args) if big else alarms(args)
    os.makedirs(os.path.join(HERE, 'results'), exist_ok=True)
    path = os.path.join(HERE, 'results', f'bench_fleet_{args.mode}.json')
    with open(path, 'w') as f:
        json.dump(out, f, indent=1)
    print(f'wrote {path}')


if __name__ == '__main__':
    main()
