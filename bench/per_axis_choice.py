"""Would choosing the thermal spec per axis beat one spec per sensor? (exploration, not built)

The one-orientation selection (``selection.time_folds.select_history``) picks one spec per
sensor on the three axes' block drift together. Its figure per fold is
sqrt(sum over axes of each axis' block drift^2), so choosing per axis, each on its own
held-out figure, refines the same objective; it costs three choices instead of one (more
room for selection noise) and a model whose axes may differ in order, terms, lagged input
and weighting (none of the model kinds today).

On the real chamber log's training part (SOURCE.md there; the held-back test leg is never
read), for each sensor:

1. the choice on the selection's own folds (the forward folds of ``time_folds``), jointly
   (``time_folds.choose``: simplest within ``MARGIN`` of the best, never worse than the
   flight stacks' cubic) and per axis (the same rule on each axis' figures);
2. both choices refitted on the rest and scored on blocks the selection never scored: the
   first 25 % and 50 % of the cooling leg held out (``bench_chamber.first_part_table``'s
   folds), per axis and as the 3-vector figure, m/s^2 and rad/s.

    python bench/per_axis_choice.py [--json bench/results/per_axis_choice_chamber.json]
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

from bench_chamber import first_part_folds  # noqa: E402
from thermal_imu_calib.collection.feed import windows_from_columns  # noqa: E402
from thermal_imu_calib.estimation.hysteresis import candidate_specs  # noqa: E402
from thermal_imu_calib.io.csv_logs import read_tofupilot_chamber  # noqa: E402
from thermal_imu_calib.selection.time_folds import (  # noqa: E402
    choose, heldout_figures, time_folds)

CSV = os.path.join(os.path.dirname(HERE), 'test', 'fixtures', 'real', 'tofupilot_chamber',
                   'imu_chamber_train.csv.gz')


def figures(w, sig, specs, t0, folds):
    """Return ({spec: (folds, 3) per-axis figures}, (folds, 3) raw) of one sensor.

    The selection's own ``heldout_figures`` on each axis alone (the other two zeroed: a
    zero axis is fitted as zero and adds nothing to the 3-vector figure).
    """
    raw, out = [], {s: [] for s in specs}
    for a in range(3):
        y = np.zeros_like(getattr(w, sig))
        y[:, a] = getattr(w, sig)[:, a]
        figs, r = heldout_figures(dataclasses.replace(w, **{sig: y}), [0, 0, 0], sig, specs,
                                  t0, folds)
        raw.append(r)
        for s in specs:
            out[s].append(figs[s])
    return {s: np.array(v).T for s, v in out.items()}, np.array(raw).T


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--csv', default=CSV)
    ap.add_argument('--json', default='')
    args = ap.parse_args(argv)
    imu, tc = read_tofupilot_chamber(args.csv)
    w = windows_from_columns([imu], [tc])
    t0 = np.full(3, np.round((w.temp.min() + w.temp.max()) / 2.0, 2))
    folds, kind = time_folds(w)
    other = first_part_folds(w)
    specs = candidate_specs()
    result = {'command': 'bench/per_axis_choice.py ' + ' '.join(
        argv if argv is not None else sys.argv[1:]), 'folds': kind, 'sensors': {}}
    for sig in ('accel', 'gyro'):
        figs, raw = figures(w, sig, specs, t0, folds)
        # the selection's own rule (``choose``) on the 3-vector figures and on each axis'
        joint, _ = choose({s: np.linalg.norm(v, axis=1) for s, v in figs.items()},
                          np.linalg.norm(raw, axis=1))
        per_axis = [choose({s: v[:, a] for s, v in figs.items()}, raw[:, a])[0]
                    for a in range(3)]
        used = list({s: None for s in [joint] + per_axis})
        ofigs, oraw = figures(w, sig, used, t0, other)
        j = ofigs[joint]
        p = np.stack([ofigs[per_axis[a]][:, a] for a in range(3)], 1)
        row = {'joint_choice': joint.label(), 'per_axis_choice': [s.label() for s in per_axis],
               'unseen_folds': [lab for _, _, lab in other],
               'raw_per_axis': oraw.tolist(), 'joint_per_axis': j.tolist(),
               'per_axis_per_axis': p.tolist(),
               'raw_vector': np.linalg.norm(oraw, axis=1).tolist(),
               'joint_vector': np.linalg.norm(j, axis=1).tolist(),
               'per_axis_vector': np.linalg.norm(p, axis=1).tolist()}
        result['sensors'][sig] = row
        print(f'{sig}: joint choice {joint.label()}')
        for a in range(3):
            print(f'  axis {"xyz"[a]}: per-axis choice {per_axis[a].label()}')
        print('  blocks never scored (first 25 % / 50 % of the cooling leg), per axis x, y, z '
              'and the 3-vector:')
        for name, v in (('raw', oraw), ('joint', j), ('per axis', p)):
            print(f'    {name:9s} ' + ' | '.join(
                ' '.join(f'{x:.3g}' for x in v[k]) + f' -> {np.linalg.norm(v[k]):.4g}'
                for k in range(len(other))))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(result, f, indent=1)
        print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
