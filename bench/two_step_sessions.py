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
sys.path.insert(0, os.path.join(HERE, '..', 'test'))

from test_standard_floor import _session, G  # noqa: E402
from thermal_imu_calib.estimation import field_estimator as fe, fixed_point  # noqa: E402


def main():
    rows = []
    t0 = np.full(3, 30.0)
    depth = fixed_point.ANDERSON_DEPTH
    for visits, tilt, slope, seed in itertools.product((2, 3, 5), (0.0, 0.05), (0.0, 1e-4),
                                                       range(4)):
        w = _session(slope, visits=visits, seed=seed, tilt=tilt)
        ta = np.repeat(w.temp, 3, 1)
        se = np.sqrt(np.maximum(w.accel_var, 1e-30) / w.n[:, None])
        hold_idx = np.unique(w.hold, return_inverse=True)[1]

        def means(fit):
            return fit.model.forward(G * fit.tilts[hold_idx], ta)
        mixed = fe.fit_field_model(w, ta, G, t0, refine=False)
        fixed_point.ANDERSON_DEPTH = 0
        try:
            plain = fe.fit_field_model(w, ta, G, t0, refine=False, tol=1e-9, max_iter=30000)
        finally:
            fixed_point.ANDERSON_DEPTH = depth
        d = float(np.max(np.abs(means(mixed) - means(plain)) / se))
        rows.append((visits, tilt, slope, seed, mixed.iterations, mixed.converged,
                     plain.iterations, plain.converged, d))
        print(rows[-1], flush=True)
    print('mixed unconverged', sum(not r[5] for r in rows), 'of', len(rows),
          '| plain (tol 1e-9, 30000 sweeps) unconverged', sum(not r[7] for r in rows),
          '| where both converged, largest distance (standard errors)',
          max(r[8] for r in rows if r[5] and r[7]))


if __name__ == '__main__':
    main()
