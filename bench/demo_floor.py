"""The standard floor on short sessions: the simulated ``demo`` (each face held twice).

No run of holds in time can be held out there, so the family is judged against the
standard form on hold folds at fixed tilts (``selection/standard_floor.py``). Prints, per
seed, what ``auto`` returns and the held-out figures behind it.

    .venv/bin/python bench/demo_floor.py [--seeds 0 1 2 3 4 5 6 7]
"""

import argparse
import os
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'test'))

from _thermal_data import options, sim_windows  # noqa: E402
from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.estimation.calibrate import calibrate_windows  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=list(range(8)))
    args = ap.parse_args(argv)
    print('| seed | auto | held-out holds | standard form [ug] | family [ug] | paired z |')
    print('|---|---|---|---|---|---|')
    for seed in args.seeds:
        res = calibrate_windows(sim_windows(sim.simulate('demo', seed)), options())
        reason = res.report['model_choice']['reason']
        m = re.search(r'RMS over (\d+) holds, standard ([\d.]+) ug, \S+ ([\d.]+) ug, '
                      r'paired z ([-\d.inf]+)', reason)
        figs = m.groups() if m else ('-', '-', '-', '-')
        print(f'| {seed} | {res.report["model_choice"]["model"]} | ' + ' | '.join(figs) + ' |',
              flush=True)


if __name__ == '__main__':
    main()
