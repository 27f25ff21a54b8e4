"""The mixed two-step sweeps against the plain alternation on 48 synthetic sessions.

test_standard_floor's sessions (six faces along a 20-40 degC warm-up, 3 windows a hold):
visits 2, 3 and 5 of each face, holds on the faces or tilted 0.05 rad, a scale factor
constant or changing 1e-4 per degC, seeds 0-3. Each is fitted without the joint
refinement twice: mixed (``estimation.fixed_point``, the defaults) and plain
(``ANDERSON_DEPTH`` 0) to tol 1e-9 with at most 30,000 sweeps. Prints per session (visits,
tilt, slope, seed, mixed sweeps, converged, plain sweeps, converged, the largest distance
of the two fits' window means in standard errors), then the counts.

    .venv/bin/python bench/two_step_sessions.py
"""

import itertools
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, '..'))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, '..', 'test'))

from test_standard_floor import _session, G  # noqa: E402
from thermal_imu_calib.estimation import fixed_point  # noqa: E402
from two_step_speed import _means, _run, _se  # noqa: E402


def main():
    rows = []
    t0 = np.full(3, 30.0)
    for visits, tilt, slope, seed in itertools.product((2, 3, 5), (0.0, 0.05), (0.0, 1e-4),
                                                       range(4)):
        w = _session(slope, visits=visits, seed=seed, tilt=tilt)
        a = (w, np.repeat(w.temp, 3, 1), G, t0)
        mixed, _ = _run(a, {}, fixed_point.ANDERSON_DEPTH)
        plain, _ = _run(a, {}, 0, tol=1e-9, max_iter=30000)
        d = float(np.max(np.abs(_means(mixed, a) - _means(plain, a)) / _se(w)))
        rows.append((visits, tilt, slope, seed, mixed.iterations, mixed.converged,
                     plain.iterations, plain.converged, d))
        print(rows[-1], flush=True)
    print('mixed unconverged', sum(not r[5] for r in rows), 'of', len(rows),
          '| plain (tol 1e-9, 30000 sweeps) unconverged', sum(not r[7] for r in rows),
          '| where both converged, largest distance (standard errors)',
          max(r[8] for r in rows if r[5] and r[7]))


if __name__ == '__main__':
    main()
