"""After the fact: the gyro beyond its range, clamped, continued, or as the history says.

For finished ``bench_lifelong.py month`` runs (``SEED:WORK_SEED_DIR``), every scored stop
is given to the calibration the month had active then (the registry is the timeline).
Stops outside that calibration's gyro range are scored three ways (gyro error against the
true rate, sample-weighted, as ``bench_lifelong.py`` scores them): as the month activated
it, clamped (the default), continued linearly (``linear_gyro``, capped at the range's
width) and as
``LifelongConfig.gyro_continuation='history'`` would choose for that activation: the
package's ``lifelong.continuation.verdict`` on the stops outside the ranges of the
calibrations active before it (each stop's clamped and continued error and its noise,
``sigma sqrt(3 / n)``), with the swap gate's ``swap_sigmas``.

Printed and written per seed: the stops outside the range (RMS mrad/s) and the last
week's stops (all of them; those inside are the same three ways), and how many
activations the rule continued. Pooled: RMS over every outside stop of all seeds, and the
geometric mean of the last weeks.

This is not the loop: the loop's evidence is its holds (the detector's and the hints'
stops, the earth rate handled by the gate's formula instead of the true rate), rows after
a change alarm's cut are dropped there and not here, and a different gyro changes what the
gate and the alarms decide next. ``bench_lifelong.py month --gyro-continuation history``
runs the loop.

    python bench/lifelong_continuation.py 39:/tmp/m39/d39/seed39 \\
        --output bench/results/lifelong_continuation.json
"""

import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import (  # noqa: E402
    active_index, months_parser, registry_timeline, scored_stops, stop_error)
from thermal_imu_calib.lifelong import continuation  # noqa: E402
from thermal_imu_calib.lifelong.config import LifelongConfig  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

WAYS = ('clamp', 'linear_gyro', 'history', 'as_activated')


def gyro_error(cal, ch):
    """Return |sample-weighted mean gyro error| (rad/s) of one stop (``stop_error``)."""
    return float(np.linalg.norm(stop_error(cal, ch)[0]))


def score_seed(seed, work_seed, days, sigmas):
    m = robot_month(seed, days=days)
    spec, rate = m.device.spec, m.config.imu_rate
    sigma = np.sqrt(spec.gyro_noise_density ** 2 * rate + spec.gyro_lsb ** 2 / 12)
    acts, cals = registry_timeline(work_seed, m.start_ns)
    clamp = [dataclasses.replace(c, out_of_range='clamp') for c in cals]
    cont = [dataclasses.replace(c, out_of_range='linear_gyro') for c in cals]
    # (activation, t0 s, outside, clamped error, continued error, se, as activated)
    rec = []
    for seg, ch in scored_stops(m):
        i = active_index(acts, seg.stop.t0)
        if i < 0:
            continue
        _, oor = cals[i].axis_temperatures(ch['temp'], 'gyro')
        e_c = gyro_error(clamp[i], ch)
        e_l = gyro_error(cont[i], ch) if oor.any() else e_c
        e_a = {'clamp': e_c, 'linear_gyro': e_l}.get(cals[i].out_of_range)
        rec.append((i, seg.stop.t0, bool(oor.any()), e_c, e_l,
                    float(sigma * np.sqrt(3.0 / ch['n'].sum())),
                    gyro_error(cals[i], ch) if e_a is None else e_a))
    chosen, texts = [], []
    for i in range(len(cals)):
        rows = [[r[1], r[3], r[4], r[5]] for r in rec if r[0] < i and r[2]]
        go, text = continuation.verdict(rows, sigmas)
        chosen.append(go)
        texts.append(text)
    pick = {'clamp': lambda r: r[3], 'linear_gyro': lambda r: r[4],
            'history': lambda r: r[4] if chosen[r[0]] else r[3],
            'as_activated': lambda r: r[6]}
    out = {'seed': seed, 'activations': len(cals), 'continued': int(sum(chosen)),
           'first_continued_day': (float(acts[chosen.index(True)] / DAY)
                                   if any(chosen) else None),
           'outside_stops': int(sum(r[2] for r in rec)),
           'last_week_stops': int(sum(r[1] >= days * DAY - 7 * DAY for r in rec)),
           'outside_sq': {}, 'last_week_sq': {}, 'outside_mrad_s': {},
           'last_week_mrad_s': {}, 'verdicts': texts}
    for way, f in pick.items():
        o = [f(r) ** 2 for r in rec if r[2]]
        lw = [f(r) ** 2 for r in rec if r[1] >= days * DAY - 7 * DAY]
        out['outside_sq'][way], out['last_week_sq'][way] = float(np.sum(o)), float(np.sum(lw))
        out['outside_mrad_s'][way] = float(np.sqrt(np.mean(o)) * 1e3) if o else None
        out['last_week_mrad_s'][way] = float(np.sqrt(np.mean(lw)) * 1e3) if lw else None
    return out


def main(argv=None):
    ap = months_parser(__doc__)
    args = ap.parse_args(argv)
    sigmas = LifelongConfig().swap_sigmas
    seeds = []
    print('| seed | outside stops | ' + ' | '.join(WAYS) + ' | last week: '
          + ' | '.join(WAYS) + ' | activations the rule continued (first day) |')
    print('|---|---|' + '---|' * (2 * len(WAYS) + 1))
    for spec in args.months:
        seed, work = spec.split(':', 1)
        r = score_seed(int(seed), work, args.days, sigmas)
        seeds.append(r)
        o, lw = r['outside_mrad_s'], r['last_week_mrad_s']
        first = f'{r["first_continued_day"]:.2f}' if r['first_continued_day'] is not None \
            else '-'
        print(f'| {r["seed"]} | {r["outside_stops"]} | '
              + ' | '.join(f'{o[w]:.3f}' for w in WAYS) + ' | '
              + ' | '.join(f'{lw[w]:.4f}' for w in WAYS)
              + f' | {r["continued"]} of {r["activations"]} ({first}) |', flush=True)
    n = sum(r['outside_stops'] for r in seeds)
    pooled = {w: float(np.sqrt(sum(r['outside_sq'][w] for r in seeds) / n) * 1e3)
              for w in WAYS}
    geo = {w: float(np.exp(np.mean([np.log(r['last_week_mrad_s'][w]) for r in seeds])))
           for w in WAYS}
    worse = {w: int(sum(r['outside_mrad_s'][w] > r['outside_mrad_s']['clamp'] * (1 + 1e-9)
                        for r in seeds)) for w in WAYS}
    print(f'pooled over {n} outside stops, mrad/s: '
          + ', '.join(f'{w} {pooled[w]:.3f}' for w in WAYS))
    print('last week, geometric mean over seeds, mrad/s: '
          + ', '.join(f'{w} {geo[w]:.4f}' for w in WAYS))
    print('seeds worse than clamp outside: ' + ', '.join(f'{w} {worse[w]}' for w in WAYS))
    if args.output:
        with open(args.output, 'w') as f:
            json.dump({'command': 'bench/lifelong_continuation.py ' + ' '.join(
                argv if argv is not None else sys.argv[1:]),
                'pooled_outside_mrad_s': pooled, 'last_week_geomean_mrad_s': geo,
                'seeds_worse_than_clamp_outside': worse, 'seeds': seeds}, f, indent=1)
        print(f'wrote {args.output}')


if __name__ == '__main__':
    main()
