"""The paired held-out test and the pieces the static comparisons share.

``paired_test``: a one-sided paired test (Wilcoxon signed-rank) at level ``ALPHA`` on
held-out holds (per hold the difference of squared residuals of the reference and the
candidate); ``_fit``: a family refitted on training windows; ``hold_positions``: windows
to holds; ``hold_magnitudes`` and ``window_rms``: per hold the |a| - g of its mean, or the
RMS of its windows' |a| - g. Used by ``static_select`` (no temperature span) and
``standard_floor`` (across a temperature span).
"""

import numpy as np
from scipy.special import ndtri

from ..estimation.calibrate import check_faces_up_and_down, CalibrationRefused
from ..estimation.standard_fit import fit_standard_context, StandardFitError
from .multi_select import _field_fit

#: one-sided level of the paired held-out test a richer model or a rule must pass
ALPHA = 0.05
#: fewest held-out holds a comparison needs (fewer: no evidence)
MIN_HELDOUT = 3


def hold_positions(ids, hold):
    """Return, per window, the index in ``ids`` of its hold id ``hold`` (ids in any order).

    ``ids`` are distinct (``Windows.hold_ids``: order of appearance, which need not be
    ascending: a store that renumbers, holds merged from several sources); every value of
    ``hold`` must be among them.
    """
    ids = np.asarray(ids)
    order = np.argsort(ids, kind='stable')
    return order[np.searchsorted(ids[order], hold)]


def hold_magnitudes(accel, n, pos, n_holds, gravity):
    """Return (held, r): per hold whether it has rows, and |mean accel| - g (m/s^2).

    ``accel`` (m, 3) corrected window means with ``n`` (m,) samples each, ``pos`` (m,)
    their hold positions (``hold_positions``) among ``n_holds``; the hold mean is
    sample-weighted. ``r`` is 0 where ``held`` is False.
    """
    wsum = np.bincount(pos, n, n_holds)
    mean = np.stack([np.bincount(pos, n * accel[:, i], n_holds) for i in range(3)], 1)
    held = wsum > 0
    r = np.zeros(n_holds)
    r[held] = np.linalg.norm(mean[held] / wsum[held, None], axis=1) - gravity
    return held, r


def window_rms(accel, n, pos, n_holds, gravity):
    """Return (held, r): per hold whether it has rows, and the RMS of its windows' |a| - g.

    ``accel`` (m, 3) corrected window means with ``n`` (m,) samples each (the weights) and
    ``pos`` (m,) their hold positions. A hold of a warm-up spans a temperature range that
    the hold's mean would average away; its windows keep it. m/s^2.
    """
    nt = np.asarray(n, float)
    wsum = np.bincount(pos, nt, n_holds)
    held = wsum > 0
    e2 = (np.linalg.norm(accel, axis=1) - gravity) ** 2
    r = np.zeros(n_holds)
    r[held] = np.sqrt(np.bincount(pos, nt * e2, n_holds)[held] / wsum[held])
    return held, r


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

    Per hold the difference of squared residuals ``d = r_ref^2 - r_cand^2``; the test is
    Wilcoxon's signed-rank test (``scipy.stats.wilcoxon``, one-sided: the candidate's
    residuals are smaller), robust to the heavy tails of ``d`` (a few holds far from the
    rest carry the mean of ``d`` and its standard deviation alike, so a z of the mean has
    little power on a dozen holds even when the candidate wins on every one). z is its
    one-sided p-value as a standard normal quantile (``z > -ndtri(ALPHA)`` is
    ``p < ALPHA``); exact p for up to 50 holds, the normal approximation above.
    """
    ok = np.isfinite(r_ref) & ~np.isnan(r_cand)
    if mask is not None:
        ok &= mask
    if ok.sum() < MIN_HELDOUT:
        return float('nan'), int(ok.sum())
    if not np.all(np.isfinite(r_cand[ok])):
        return float('-inf'), int(ok.sum())
    d = r_ref[ok] ** 2 - r_cand[ok] ** 2
    if not np.any(d != 0):
        return 0.0, int(ok.sum())
    # imported here: scipy.stats costs ~0.1-0.3 s of start-up, which a calibration that
    # compares nothing (``--model field``) should not pay (docs/speed.md)
    from scipy.stats import wilcoxon
    p = float(wilcoxon(d, alternative='greater').pvalue)
    return float(-ndtri(p)), int(ok.sum())
