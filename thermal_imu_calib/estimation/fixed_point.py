"""Anderson-accelerated fixed-point iteration of unit vectors (the two-step field fit's sweeps).

``field_estimator.fit_field_model`` alternates the seed 000 paper's two steps: the thermal
vector given the tilts, the tilts given the thermal vector. That alternation is a map from
the holds' unit tilt vectors to new ones, iterated here to its fixed point.
"""

import numpy as np

#: past sweeps each step extrapolates from (0: the plain alternation, as before 2026-12-07)
ANDERSON_DEPTH = 5


def fixed_point(sweep, c, tol, max_iter):
    """Iterate ``sweep`` (tilts -> tilts, thermal vector, window means) to its fixed point.

    c: (h, 3) unit vectors to start from. ``sweep(c)`` returns (new unit vectors, the
    thermal vector, the fitted window means in m/s^2).

    The plain alternation, c <- sweep(c), converges linearly and slowly where the tilts and
    the bias and scale terms trade off: on a simulated three-log unit (``fleet.simulate``)
    it took ~450 sweeps to move the fitted means by less than 1e-3 of their noise, and then
    was still ~0.05 of their noise from its fixed point. Anderson mixing (type II, Walker
    and Ni 2011, SIAM J. Numer. Anal. 49(4)) of the last ``ANDERSON_DEPTH`` sweeps reaches the same
    fixed point, to ~1e-5 of the noise, in ~60 sweeps (``bench/two_step_speed.py``). Each
    mixed vector is put back on the unit sphere; the memory is dropped (one plain sweep)
    when a sweep moves the vectors more than the one before it, or the mixing is not finite.

    Stops when one sweep moves the fitted window means by less than ``tol`` (m/s^2).
    Returns (vectors, thermal vector, converged, sweeps): the last sweep's output.
    """
    depth = ANDERSON_DEPTH      # read at each call: benches and tests set 0 (the plain one)
    xs, fs = [], []
    pred_prev = None
    f_prev = np.inf
    g = th = None
    it = 0
    for it in range(1, max_iter + 1):
        g, th, pred = sweep(c)
        if pred_prev is not None and np.max(np.abs(pred - pred_prev)) < tol:
            return g, th, True, it
        pred_prev = pred
        f = (g - c).ravel()
        f_norm = float(np.linalg.norm(f))
        if not f_norm < f_prev:          # not shrinking (or not finite): restart the memory
            xs, fs = [], []
        f_prev = f_norm
        xs.append(c.ravel())
        fs.append(f)
        del xs[:-(depth + 1)], fs[:-(depth + 1)]
        nxt = g
        if len(fs) >= 2:
            d_f = np.diff(fs, axis=0).T
            d_x = np.diff(xs, axis=0).T
            gamma = np.linalg.lstsq(d_f, f, rcond=None)[0]
            mixed = (g.ravel() - (d_x + d_f) @ gamma).reshape(g.shape)
            norm = np.linalg.norm(mixed, axis=1, keepdims=True)
            if np.all(np.isfinite(mixed)) and np.all(norm > 0):
                nxt = mixed / norm
        c = nxt
    return g, th, False, it
