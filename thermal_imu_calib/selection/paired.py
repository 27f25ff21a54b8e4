"""The paired held-out test and the accelerometer refits the static comparisons share.

``paired_test``: a one-sided paired test at level ``ALPHA`` on held-out holds (per hold the
difference of squared residuals of the reference and the candidate); ``_fit``: a family
refitted on training windows. Used by ``static_select`` (no temperature span) and
``standard_floor`` (across a temperature span).
"""

import numpy as np

from ..estimation.calibrate import check_faces_up_and_down, CalibrationRefused
from ..estimation.standard_fit import fit_standard_context, StandardFitError
from .multi_select import _field_fit

#: one-sided level of the paired held-out test a richer model or a rule must pass
ALPHA = 0.05
#: fewest held-out holds a comparison needs (fewer: no evidence)
MIN_HELDOUT = 3


def _fit(ctx, name, train):
    """Return an accel model fitted on the ``train`` windows (None: it cannot be fitted).

    ``name`` is a family, optionally with a suffix after '-' (``standard-kept``: the same
    family on other rows, see ``heldout_residuals``).
    """
    family = name.split('-')[0]
    try:
        if family == 'standard':
            return fit_standard_context(ctx, train).model
        if family == 'field':
            sub = ctx.subset(train & (ctx.accel_rows if ctx.accel_rows is not None else True))
            check_faces_up_and_down(sub)
            return _field_fit(ctx, sub.windows, sub.ta, refine=False).model
        from ..estimation.whole_unit_fit import fit_whole_unit_context
        return fit_whole_unit_context(ctx, train).accel.model
    except (StandardFitError, CalibrationRefused, ValueError, np.linalg.LinAlgError):
        return None


def paired_test(r_ref, r_cand, mask=None):
    """Return (z, n) of the paired test over the ``n`` holds both have held out.

    z: how far the candidate's held-out squared residuals are below the reference's, in
    standard errors of the mean paired difference.
    """
    ok = np.isfinite(r_ref) & ~np.isnan(r_cand)
    if mask is not None:
        ok &= mask
    if ok.sum() < MIN_HELDOUT:
        return float('nan'), int(ok.sum())
    if not np.all(np.isfinite(r_cand[ok])):
        return float('-inf'), int(ok.sum())
    d = r_ref[ok] ** 2 - r_cand[ok] ** 2
    sd = float(np.std(d, ddof=1))
    z = float(np.mean(d) / (sd / np.sqrt(len(d)))) if sd > 0 else (
        float('inf') if np.mean(d) > 0 else 0.0)
    return z, int(ok.sum())
