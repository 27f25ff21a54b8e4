"""After the fact (design only): one-pose accel models re-referenced to the month's first T0.

Each activated ``offset_polynomial`` accelerometer without a constant removes the drift
relative to its own reference temperature T0 and leaves the offset at T0 in the output.
Re-referenced to the month's first such T0, it leaves the offset there instead: the model's
own offset at that T0 (extrapolated when it lies outside the model's range) is added back.
Other accelerometer models are left as activated (counted). Compared with the models as
activated: the steps of the per-activation median error between activations (as
``lifelong_accel_steps.py``) and the last week's drift (``bench_lifelong.drift_rms``),
mm/s^2.

    python bench/lifelong_accel_keep_t0.py 39:/tmp/m39/d39/seed39 [...]
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import (  # noqa: E402
    active_index, drift_rms, months_parser, registry_timeline, scored_stops, stop_error)
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402


def one_pose(cal):
    """Return True for an offset polynomial accelerometer without a constant."""
    return cal.accel is not None and cal.accel.kind == 'offset_polynomial' \
        and not cal.accel.include_constant


def compare(seed, work_seed, days):
    """Return {'as': (step median, max, > 20, last-week drift), 'keep': (...)}, T0, others."""
    m = robot_month(seed, days=days)
    acts, cals = registry_timeline(work_seed, m.start_ns)
    first = next((c.accel.t0.copy() for c in cals if one_pose(c)), None)
    add = [c.accel.offset(first[None, :])[0] if one_pose(c) else np.zeros(3) for c in cals]
    by, last = {}, {'as': [], 'keep': []}
    for seg, ch in scored_stops(m, 1.0 * DAY):
        i = active_index(acts, seg.stop.t0)
        if i < 0:
            continue
        e = stop_error(cals[i], ch)[1]
        by.setdefault(i, []).append((e, e + add[i]))
        if seg.stop.t0 >= days * DAY - 7 * DAY:
            last['as'].append(e)
            last['keep'].append(e + add[i])
    ks = [i for i in sorted(by) if len(by[i]) >= 5]
    out = {}
    for j, name in ((0, 'as'), (1, 'keep')):
        med = {i: np.median(np.array([x[j] for x in by[i]]), 0) for i in ks}
        st = np.array([np.linalg.norm(med[b] - med[a]) * 1e3 for a, b in zip(ks, ks[1:])])
        out[name] = (float(np.median(st)), float(st.max()), int(np.sum(st > 20.0)),
                     drift_rms(np.array(last[name])) * 1e3)
    return out, float(first[0]), sum(not one_pose(c) for c in cals)


def main(argv=None):
    ap = months_parser(__doc__, output=False)
    args = ap.parse_args(argv)
    print('| seed | first T0 degC | other models | step median / max / > 20, as activated '
          '| re-referenced | last week drift: as activated | re-referenced |')
    print('|---|---|---|---|---|---|---|')
    for spec in args.months:
        seed, work = spec.split(':', 1)
        out, t0, others = compare(int(seed), work, args.days)
        a, k = out['as'], out['keep']
        print(f'| {seed} | {t0:.2f} | {others} | {a[0]:.1f} / {a[1]:.1f} / {a[2]} | '
              f'{k[0]:.1f} / {k[1]:.1f} / {k[2]} | {a[3]:.2f} | {k[3]:.2f} |', flush=True)


if __name__ == '__main__':
    main()
