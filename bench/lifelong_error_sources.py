"""Where the gyro error of a lifelong month comes from, and what to do outside the range.

For finished ``bench_lifelong.py month`` runs (``SEED:WORK_SEED_DIR`` pairs, the
``--work`` directory's ``seedN``), every stop is scored as ``bench_lifelong.py`` scores
it, with the calibration active when it began (the registry is the timeline), and with
the true calibration at that time. Printed:

* **last week, by source** (the acceptance figure's stops, each scored with the calibration
  as the month served it, its own ``out_of_range``): the gyro error RMS (mrad/s)
  of the stops outside the active calibration's valid range (where neither sensor's model
  clamps), on a slope (the mount tilted 3-12 degC: the gyro's g-sensitivity, which a fit
  of one mounting pose cannot resolve), and the level stops inside the range; each also
  as the systematic part (active minus true) and as its share of the week's squared error;
  the level stops inside also by the age of the calibration active at the stop (days since
  its activation, ``AGE_BANDS``): a systematic part that grows with the age is the gyro
  bias ageing since the last swap, one that does not is the fit; and the stops outside
  split by whose range they are beyond: the gyro's own, or only the accelerometer's;
* **outside the valid range, all month**: every stop beyond the active's range scored
  three ways, each the calibration's own ``out_of_range``: clamped at the range
  (``clamp``, the default, as PX4 and ArduPilot do), continued linearly from the edge
  (``linear``: the slope of the last 1 degC inside, no further than the range's width),
  and the models' own extrapolation (``extrapolate``); gyro error and the accelerometer
  error about the median of the same calibration's inside stops (the drift), by how far
  outside the stop is.

    python bench/lifelong_error_sources.py 0:/tmp/w/seed0 1:/tmp/w/seed1 \
        --output bench/results/lifelong_error_sources.json
"""

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import (  # noqa: E402
    active_stops, registry_timeline, stop_error, vertical_earth_rate)
from thermal_imu_calib.lifelong import compose  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

POLICIES = ('clamp', 'linear', 'extrapolate')
#: how far outside (degC) the policies are compared by
EXCESS_BANDS = ((0.0, 2.0), (2.0, 5.0), (5.0, np.inf))
#: the age bands (days since the active calibration's activation) of the level stops inside
AGE_BANDS = ((0.0, 1.0), (1.0, 3.0), (3.0, np.inf))


def stop_errors(cal, ch, policy='clamp', earth=0.0):
    """Return the sample-weighted (gyro, accel) error vectors of one stop (rad/s, m/s^2).

    ``earth``: the vertical earth rate (3,) rad/s a calibration fitted without the latitude
    took in, added to its gyro error (``bench_lifelong.py --earth-rate-in-model``).
    """
    g, a = stop_error(dataclasses.replace(cal, out_of_range=policy), ch)
    return g + earth, a


def score_seed(seed, work_seed, days, dock_fraction=0.0, in_model=False):
    """Return every scored stop of one seed's month (dicts, errors under each policy).

    ``dock_fraction`` and ``in_model``: as the month was run and scored
    (``bench_lifelong.py month|follower --dock-fraction``, ``--earth-rate-in-model``).
    """
    m = robot_month(seed, days=days, dock_fraction=dock_fraction)
    acts, cals = registry_timeline(work_seed, m.start_ns)
    stops = []
    for seg, ch, i, cal in active_stops(m, acts, cals):
        s = seg.stop
        lo, hi = compose.common_range(cal)[0]
        temp = ch['temp'][:, 0]
        excess = max(lo - temp.min(), temp.max() - hi, 0.0)
        g_lo, g_hi = np.asarray(cal.own_range('gyro'), float)[0]
        gyro_excess = max(g_lo - temp.min(), temp.max() - g_hi, 0.0)
        pol = POLICIES if excess > 0 else ('clamp',)
        earth = vertical_earth_rate(m, ch) if in_model else 0.0
        errors = {p: stop_errors(cal, ch, p, earth) for p in pol}
        # as the month served it (the calibration's own out_of_range: a gyro continued by
        # ``gyro_continuation`` is 'linear_gyro'; a policy scored above is not scored again);
        # inside the range every policy is the same
        own = cal.out_of_range if excess > 0 else 'clamp'
        errors['activated'] = errors[own] if own in errors else stop_errors(
            cal, ch, own, earth)
        stops.append({'day': s.t0 / DAY, 'activation': (seed, int(i)), 'excess': float(excess),
                      'gyro_excess': float(gyro_excess),
                      'slope': bool(s.slope_deg > 0), 'age_days': (s.t0 - acts[i]) / DAY,
                      'errors': errors,
                      'true': stop_errors(m.true_calibration(s.t0), ch)})
    return stops


def rms(vectors):
    v = np.array(vectors, float).reshape(-1, 3) if len(vectors) else np.zeros((0, 3))
    return float(np.sqrt(np.mean(np.sum(v ** 2, 1)))) if len(v) else float('nan')


def figures(group):
    """Return the stops, gyro error RMS and its systematic part (mrad/s) of a group of stops."""
    act = [s['errors']['activated'][0] for s in group]
    return {'stops': len(group), 'gyro_mrad_s': rms(act) * 1e3,
            'systematic_mrad_s': rms([a - s['true'][0] for a, s in zip(act, group)]) * 1e3}


def last_week(stops, days):
    week = [s for s in stops if s['day'] >= days - 7]
    total = np.sum([np.sum(s['errors']['activated'][0] ** 2) for s in week])
    out = {'stops': len(week),
           'gyro_mrad_s': rms([s['errors']['activated'][0] for s in week]) * 1e3,
           'true_mrad_s': rms([s['true'][0] for s in week]) * 1e3}
    groups = {'outside the range': lambda s: s['excess'] > 0,
              'slope, inside': lambda s: s['excess'] == 0 and s['slope'],
              'level, inside': lambda s: s['excess'] == 0 and not s['slope']}
    for name, sel in groups.items():
        g = [s for s in week if sel(s)]
        squared = np.sum(np.square([s['errors']['activated'][0] for s in g]))
        out[name] = {**figures(g), 'share_of_squared_error': float(squared / total)
                     if total > 0 else float('nan')}
    # the stops outside split by whose range they are beyond: the gyro's own (its model
    # clamps or continues there) or only the accelerometer's (the gyro is inside its own)
    out['outside, by sensor'] = {
        "beyond the gyro's own range": figures([s for s in week if s['gyro_excess'] > 0]),
        "beyond the accelerometer's only": figures(
            [s for s in week if s['excess'] > 0 and s['gyro_excess'] == 0])}
    level = [s for s in week if groups['level, inside'](s)]
    out['level, inside, by age'] = {
        f'{lo:g}-{hi:g} d': figures([s for s in level if lo <= s['age_days'] < hi])
        for lo, hi in AGE_BANDS}
    return out


def outside(stops):
    """Return per excess band: stops, gyro RMS (mrad/s) and accel drift RMS (mm/s^2)."""
    centre = {}
    for s in stops:
        if s['excess'] == 0:
            centre.setdefault(s['activation'], []).append(s['errors']['clamp'][1])
    centre = {k: np.median(v, 0) for k, v in centre.items()}
    out = {}
    for lo, hi in EXCESS_BANDS + ((0.0, np.inf),):
        sel = [s for s in stops if lo < s['excess'] <= hi]
        acc = [s for s in sel if s['activation'] in centre]
        out[f'{lo:g}-{hi:g} degC'] = {
            'stops': len(sel),
            'gyro_mrad_s': {p: rms([s['errors'][p][0] for s in sel]) * 1e3 for p in POLICIES},
            'true_gyro_mrad_s': rms([s['true'][0] for s in sel]) * 1e3,
            'accel_drift_mm_s2': {p: rms([s['errors'][p][1] - centre[s['activation']]
                                          for s in acc]) * 1e3 for p in POLICIES}}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('runs', nargs='+', help='SEED:WORK_DIR/seedSEED of a finished month run')
    ap.add_argument('--days', type=float, default=30.0)
    ap.add_argument('--dock-fraction', type=float, default=0.0,
                    help='as the months were run (RobotMonthConfig.dock_fraction)')
    ap.add_argument('--earth-rate-in-model', action='store_true',
                    help='months run without the latitude: score the gyro in the '
                         "calibrations' own convention, as bench_lifelong.py does")
    ap.add_argument('--output', default='')
    args = ap.parse_args()
    result, every = {'command': ' '.join(sys.argv), 'seeds': {}}, []
    for spec in args.runs:
        seed, d = spec.split(':', 1)
        stops = score_seed(int(seed), d, args.days, args.dock_fraction,
                           args.earth_rate_in_model)
        every += stops
        r = {'last_week': last_week(stops, args.days), 'outside': outside(stops)}
        result['seeds'][seed] = r
        lw = r['last_week']
        print(f'seed {seed}: last week {lw["gyro_mrad_s"]:.3f} mrad/s (true '
              f'{lw["true_mrad_s"]:.3f}), ' + '; '.join(
                  f'{k} {v["stops"]}: {v["gyro_mrad_s"]:.3f} '
                  f'({100 * v["share_of_squared_error"]:.0f} %)'
                  for k, v in lw.items() if isinstance(v, dict) and 'stops' in v), flush=True)
        print('  level inside by the active calibration\'s age: ' + '; '.join(
            f'{k} {v["stops"]}: {v["gyro_mrad_s"]:.3f} (systematic {v["systematic_mrad_s"]:.3f})'
            for k, v in lw['level, inside, by age'].items()), flush=True)
        print('  outside, by sensor: ' + '; '.join(
            f'{k} {v["stops"]}: {v["gyro_mrad_s"]:.3f} (systematic {v["systematic_mrad_s"]:.3f})'
            for k, v in lw['outside, by sensor'].items()), flush=True)
    result['outside_all_seeds'] = outside(every)
    for band, v in result['outside_all_seeds'].items():
        print(f'outside {band}: {v["stops"]} stops; gyro mrad/s ' + ', '.join(
            f'{p} {v["gyro_mrad_s"][p]:.3f}' for p in POLICIES) + f' (true '
            f'{v["true_gyro_mrad_s"]:.3f}); accel drift mm/s^2 ' + ', '.join(
            f'{p} {v["accel_drift_mm_s2"][p]:.1f}' for p in POLICIES))
    if args.output:
        with open(args.output, 'w') as f:
            json.dump(result, f, indent=1)


if __name__ == '__main__':
    main()
