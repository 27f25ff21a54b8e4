"""After the fact: how far the accelerometer's constant moves from one activation to the next.

For finished ``bench_lifelong.py month`` runs (``SEED:WORK_SEED_DIR``), every scored stop
after the first day is given to the calibration active then (the registry is the
timeline), and its accelerometer error against the true specific force (sample-weighted
mean, m/s^2) is taken. Per activation with at least 5 stops: the median error vector.
Between consecutive such activations: the step of that median, in mm/s^2, per axis and
as a length. In one mounting pose the horizontal constant is not observable (the floor's
tilt from stop to stop and the mount's tilt look the same) and the swap gate scores
|mean accel| about its median, so a swap can move the output's constant without any held-out
figure seeing it; the user sees it as a step in the level.

    python bench/lifelong_accel_steps.py 39:/tmp/m39/d39/seed39 [...] \\
        [--repin-cubic] [--output bench/results/lifelong_accel_steps.json]

``--repin-cubic``: every activated one-pose accelerometer model built about ArduPilot's
35 degC (the flight stacks' cubic before e5f5922) is re-pinned, the same polynomial, at
the middle of its own range (what ``history_select`` builds since): the after-the-fact
view of that fix on months run before it.
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
from thermal_imu_calib.estimation.hysteresis import ARDUPILOT_TREF  # noqa: E402
from thermal_imu_calib.formats.ardupilot import reexpand  # noqa: E402
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

MIN_STOPS = 5


def repinned(cal):
    """Return ``cal`` with a one-pose accel model about 35 degC re-pinned mid-range, or None."""
    acc = cal.accel
    if not (isinstance(acc, OffsetPolynomialModel) and not acc.include_constant
            and np.all(acc.t0 == ARDUPILOT_TREF)):
        return None
    rng = cal.own_range('accel')
    mid = float(np.round((rng[0, 0] + rng[0, 1]) / 2.0, 2))
    c = reexpand(acc.coeffs, ARDUPILOT_TREF, mid)
    c[0] = 0.0
    new = OffsetPolynomialModel(np.full(3, mid), c, 'accel', False, acc.coeff_std,
                                input_unit=acc.input_unit)
    return dataclasses.replace(cal, accel=new)


def steps(seed, work_seed, days, repin=False):
    """Return {'steps': [{day, step_mm_s2 (3,), length}], ...} of one month."""
    m = robot_month(seed, days=days)
    acts, cals = registry_timeline(work_seed, m.start_ns)
    n_repinned = 0
    if repin:
        for i, c in enumerate(cals):
            r = repinned(c)
            if r is not None:
                cals[i], n_repinned = r, n_repinned + 1
    by = {}
    for seg, ch in scored_stops(m, 1.0 * DAY):
        i = active_index(acts, seg.stop.t0)
        if i < 0:
            continue
        by.setdefault(i, []).append(stop_error(cals[i], ch)[1])
    keep = [i for i in sorted(by) if len(by[i]) >= MIN_STOPS]
    med = {i: np.median(np.array(by[i]), 0) for i in keep}
    out = []
    for a, b in zip(keep, keep[1:]):
        d = (med[b] - med[a]) * 1e3
        out.append({'day': float(acts[b] / DAY), 'step_mm_s2': [float(x) for x in d],
                    'length_mm_s2': float(np.linalg.norm(d))})
    length = np.array([s['length_mm_s2'] for s in out])
    return {'seed': seed, 'activations_scored': len(keep), 'steps': out,
            'repinned': n_repinned,
            'median_mm_s2': float(np.median(length)) if len(length) else None,
            'max_mm_s2': float(length.max()) if len(length) else None,
            'over_20_mm_s2': int(np.sum(length > 20.0))}


def main(argv=None):
    ap = months_parser(__doc__)
    ap.add_argument('--repin-cubic', action='store_true',
                    help='re-pin accel models about 35 degC at the middle of their range')
    args = ap.parse_args(argv)
    rows = []
    print('| seed | activations (>= 5 stops) | step median mm/s^2 | max | > 20 mm/s^2 '
          '(day: x, y, z) |')
    print('|---|---|---|---|---|')
    for spec in args.months:
        seed, work = spec.split(':', 1)
        r = steps(int(seed), work, args.days, args.repin_cubic)
        rows.append(r)
        big = '; '.join(f'{s["day"]:.1f}: ' + ', '.join(f'{x:.0f}' for x in s['step_mm_s2'])
                        for s in r['steps'] if s['length_mm_s2'] > 20.0)
        print(f'| {r["seed"]} | {r["activations_scored"]} | {r["median_mm_s2"]:.1f} | '
              f'{r["max_mm_s2"]:.1f} | {r["over_20_mm_s2"]} ({big}) |', flush=True)
    if args.output:
        with open(args.output, 'w') as f:
            json.dump({'command': 'bench/lifelong_accel_steps.py ' + ' '.join(
                argv if argv is not None else sys.argv[1:]), 'seeds': rows}, f, indent=1)
        print(f'wrote {args.output}')


if __name__ == '__main__':
    main()
