"""What the gyro ageing rate would give if the calibration carried it forward in time.

A lifelong estimate may fit the gyro with its ageing removed (``lifelong.ageing``,
``variants.with_ageing``): the windows are moved to the estimate's time along the resolved
per-axis rates, so the gyro model is the bias *at that time*. The calibration file then
holds that bias, and between this swap and the next the sensor keeps ageing: at a rate r
(rad/s per day) a calibration d days old errs by about r d. This diagnostic scores every
stop of finished ``bench_lifelong.py month`` runs as the bench does (the calibration active
when the stop began, from the registry; the stop's sample-weighted mean error), and again
with the active gyro's rate carried forward from its estimate's time:
error - r (t - t_estimate), with r the rate of the estimate the active gyro came from
(none when that estimate's fit did not use the ageing; a one-sensor swap of the
accelerometer keeps the gyro's). Printed per seed, over the last week and over the whole
month: the gyro error RMS as it is, carried forward without a bound, and carried forward
for at most ``--cap-days`` (the bound a file would have to state); the true model's.

    python bench/lifelong_ageing_forward.py 143:/tmp/acc/143/seed143 144:/tmp/acc/144/seed144

A what-if on the months as they ran: carrying the rate would also change what the gate and
the alarm saw, so a loop run with it is the judgement, not this. Units: mrad/s in print,
days. No ROS import.
"""

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import active_stops, registry_timeline, stop_error  # noqa: E402
from thermal_imu_calib.lifelong.ageing import Trend  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def gyro_rates(work_seed, start_s, starts, unused=False):
    """Return per activation (rate (3,) rad/s per day, estimate time s since the start).

    The activation at ``starts[i]`` (``registry_timeline``) is matched to the decision
    logged at that time; its gyro came from that estimate unless the swap took the
    accelerometer alone, when the previous activation's gyro (and rate) stays.
    """
    with open(os.path.join(work_seed, 'decisions.jsonl')) as f:
        rows = [json.loads(line) for line in f]
    swaps = [d for d in rows if d.get('action') == 'swap']
    t_swap = np.array([d['time'] - start_s for d in swaps])
    out, prev = [], (np.zeros(3), 0.0)
    for t in starts:
        # a registry entry is named to the second (``registry.parse_time``)
        j = int(np.argmin(np.abs(t_swap - t))) if len(t_swap) else -1
        d = swaps[j] if j >= 0 and abs(t_swap[j] - t) < 1.5 else None
        if d is None:
            out.append((np.zeros(3), float(t)))     # first estimate or not matched: no rate
        elif (d.get('one_sensor') or {}).get('sensor') == 'accel':
            out.append(prev)
        else:
            ag = d.get('ageing') or {}
            rate = np.zeros(3)
            if 'rate_rad_s_per_day' in ag and (ag.get('used') or unused):
                # the rates ``ageing.detrended`` applies: the resolved axes only
                rate = Trend(np.asarray(ag['rate_rad_s_per_day'], float),
                             np.asarray(ag['std_rad_s_per_day'], float), 0, 0.0).applied
            out.append((rate, float(t)))
        prev = out[-1]
    return out


def score(seed, work_seed, days, caps, unused=False):
    """Return per stop (day, error as is, carried for each cap (3,) rad/s, true model's)."""
    m = robot_month(seed, days=days)
    starts, cals = registry_timeline(work_seed, m.start_ns)
    rates = gyro_rates(work_seed, m.start_ns * 1e-9, starts, unused)
    rows = []
    for seg, ch, i, cal in active_stops(m, starts, cals):
        s = seg.stop
        g, _ = stop_error(cal, ch)
        rate, t_est = rates[i]
        t_mid = 0.5 * (s.t0 + s.t1)
        age = max(t_mid - t_est, 0.0) / DAY
        carried = [g - rate * min(age, c) for c in caps]
        rows.append((s.t0 / DAY, g, carried, stop_error(m.true_calibration(s.t0), ch)[0]))
    return rows


def rms(v):
    v = np.asarray(v, float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(v ** 2, 1)))) * 1e3 if len(v) else float('nan')


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('runs', nargs='+', help='SEED:WORK_DIR/seedSEED of a finished month run')
    ap.add_argument('--days', type=float, default=30.0)
    ap.add_argument('--cap-days', type=float, nargs='+', default=[1.0, 3.0])
    ap.add_argument('--unused', action='store_true',
                    help="also carry the resolved rates of estimates whose fit did not use them")
    ap.add_argument('--output', default='')
    args = ap.parse_args()
    caps = [np.inf] + list(args.cap_days)
    names = ['as is', 'carried'] + [f'carried <= {c:g} d' for c in args.cap_days]
    result = {'command': ' '.join(sys.argv), 'seeds': {}}
    for spec in args.runs:
        seed, d = spec.split(':', 1)
        rows = score(int(seed), d, args.days, caps, args.unused)
        res = {}
        for period, lo in (('last week', args.days - 7), ('month', 0.0)):
            sel = [r for r in rows if r[0] >= lo]
            figs = [rms([r[1] for r in sel])]
            figs += [rms([r[2][k] for r in sel]) for k in range(len(caps))]
            res[period] = {'stops': len(sel), 'true_mrad_s': rms([r[3] for r in sel]),
                           **{n: f for n, f in zip(names, figs)}}
            print(f'seed {seed}, {period} ({len(sel)} stops): gyro mrad/s ' + ', '.join(
                f'{n} {f:.4f}' for n, f in zip(names, figs))
                + f'; true model {res[period]["true_mrad_s"]:.4f}', flush=True)
        result['seeds'][seed] = res
    if args.output:
        with open(args.output, 'w') as f:
            json.dump(result, f, indent=1)


if __name__ == '__main__':
    main()
