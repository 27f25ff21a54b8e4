"""The batched leave-one-group-out order choice against the plain per-group loop.

``offset_fit.cv_order`` fits every held-out group at once from normal equations; the loop
below is what it replaced (one ``lstsq`` per group). Chosen orders must agree exactly and
the held-out scores to 1e-9, on random designs with degenerate cases (one group, no
temperature span, repeated temperatures, groups too small to fit).
"""

import numpy as np

from thermal_imu_calib.estimation.offset_fit import _polyfit_coef, _vander, cv_order


def loop_cv_order(dt, y, w, groups, orders):
    """The per-group reference: lstsq on every training set."""
    scores = {}
    for order in orders:
        err, wsum = 0.0, 0.0
        for g in np.unique(groups):
            test = groups == g
            train = ~test
            if np.sum(train) <= order + 1 or np.ptp(dt[train]) <= 0:
                err = np.inf
                break
            coef, _ = _polyfit_coef(dt[train], y[train], w[train], order)
            r = y[test] - _vander(dt[test], order) @ coef
            err += float(np.sum((r * w[test]) ** 2))
            wsum += float(np.sum(w[test] ** 2))
        scores[order] = float(np.sqrt(err / wsum)) if wsum else np.inf
    finite = {k: v for k, v in scores.items() if np.isfinite(v)}
    if not finite:
        return min(orders), scores
    best = min(finite.values())
    return min(k for k, v in finite.items() if v <= best * 1.02), scores


def test_batched_order_choice_equals_the_loop():
    rng = np.random.default_rng(0)
    chosen = set()
    for trial in range(200):
        m = int(rng.integers(3, 150))
        groups = np.sort(rng.integers(0, int(rng.integers(1, 30)), m)) * 7 + 3
        dt = rng.uniform(-40, 40, m) * rng.choice([1.0, 1e-3, 0.0])
        if rng.random() < 0.2:
            dt = np.round(dt / 10) * 10                   # a few distinct temperatures
        curve = rng.choice([0.0, 3e-7])
        y = 1e-3 + 2e-5 * dt + curve * dt ** 2 + rng.normal(0, 1e-5, m)
        w = 1 / rng.uniform(1e-6, 1e-5, m)
        ref = loop_cv_order(dt, y, w, groups, (0, 1, 2, 3))
        got = cv_order(dt, y, w, groups, (0, 1, 2, 3))
        assert got[0] == ref[0], (trial, ref, got)
        chosen.add(got[0])
        for k, v in ref[1].items():
            if np.isinf(v):
                assert np.isinf(got[1][k]), (trial, k)
            else:
                assert abs(got[1][k] - v) <= 1e-9 * v + 1e-300, (trial, k, v, got[1][k])
    assert chosen >= {0, 1, 2}                            # the cases exercise the choice
