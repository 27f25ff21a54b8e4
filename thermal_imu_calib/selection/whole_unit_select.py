"""``--model auto`` on several orientations: the whole-unit model (seed 002) against field.

Whole-unit (seed 002): when the field model was chosen, the field calibration (field model
+ gyro bias polynomial) and the whole-unit one are refitted with the same hold folds and
scored on the held-out holds by the gravity-norm residual |a| - g (the one accelerometer
score both admit without the held-out tilts) and by the still gyro's |w| (the earth rate
at most; a pose-dependent bias such as g-sensitivity makes it larger). This runs only with
``WHOLE_UNIT_MIN_TILTED`` holds off the six faces (misalignment is what the field model
lacks without a lab prior) and ``WHOLE_UNIT_MIN_FOLDS`` folds. The whole-unit model is
chosen when it is ``WHOLE_UNIT_MARGIN`` better on |a| - g and no more than
``WHOLE_UNIT_GYRO_SLACK`` worse on |w|. It then also fits the gyro's scale and
misalignment from the pose changes.
"""

import time

import numpy as np

from ..collection.segments import face_of
from ..estimation.observability import FitNotConverged
from .heldout import _weighted_rms, _whole_unit_folds, clamp_to_training, fold_masks
from .multi_select import _field_fit

#: several orientations with tilted holds: the whole-unit model must beat the field model's
#: held-out gravity-norm residual by this much (relative) to be chosen
WHOLE_UNIT_MARGIN = 0.25
#: ... while its still-gyro residual is at most this much worse
WHOLE_UNIT_GYRO_SLACK = 0.05
#: holds off the six faces needed before the whole-unit model is tried (misalignment)
WHOLE_UNIT_MIN_TILTED = 3
#: hold folds needed (every face held this often): with two folds a fit sees one hold
#: per face and the held-out score is dominated by extrapolation (simulated demo: field
#: 16 mg vs whole_unit 1.1 mg held out, but on the next cold start 117 vs 453 ug)
WHOLE_UNIT_MIN_FOLDS = 3
#: a candidate whose held-out residual is more than this many times the best one's is
#: never kept, whatever the margins above
KEEP_RATIO = 1.5


def heldout_whole_unit(ctx):
    """Held-out static residuals of the field and whole-unit calibrations; (dict, folds).

    Both are refitted on the training holds of each fold (``_hold_folds``) and applied to
    the held-out windows, inputs clamped to the training range. Returns per window
    ``{'accel': {'field': |a| - g, 'whole_unit': ...}, 'gyro': {...: |w_corrected|}}``:
    the gyro of a still IMU should read the earth rate (<= 7.3e-5 rad/s) in every pose,
    so a pose-dependent bias (g-sensitivity) shows as a larger held-out |w|. The field
    calibration's gyro is the default bias polynomial (``calibrate._gyro_bias``).
    """
    from ..estimation.calibrate import _gyro_bias
    from ..estimation.whole_unit_fit import fit_whole_unit_context
    w, o = ctx.windows, ctx.options
    folds, n = _whole_unit_folds(w)
    out = {s: {'field': np.full(len(w), np.nan), 'whole_unit': np.full(len(w), np.nan)}
           for s in ('accel', 'gyro')}
    for test, train in fold_masks(folds, n):
        ta = clamp_to_training(ctx.ta, w, train, ctx.accel_input, o.range_margin)
        tg = clamp_to_training(ctx.tg, w, train, ctx.gyro_input, o.range_margin)
        sub = ctx.subset(train)
        fm = _field_fit(ctx, sub.windows, sub.ta, refine=False).model
        gm, _ = _gyro_bias(sub)
        wu = fit_whole_unit_context(ctx, train)
        for name, am, gmod in (('field', fm, gm),
                               ('whole_unit', wu.accel.model, wu.gyro.model)):
            a = am.correct(w.accel[test], ta[test])
            out['accel'][name][test] = np.linalg.norm(a, axis=1) - o.gravity
            g = gmod.correct(w.gyro[test], tg[test], aux={'accel': a})
            out['gyro'][name][test] = np.linalg.norm(g, axis=1)
    return out, n


def select_whole_unit(ctx, sel):
    """Return ``sel`` or a whole-unit Selection when it wins held out (see the docstring).

    Whatever the margins, a candidate whose held-out |a| - g is more than ``KEEP_RATIO``
    times the other's is never kept. Without a temperature input the margin is 0.
    """
    if sel.model != 'field' or sel.groups != 'holds':
        return sel
    ids, means = ctx.windows.hold_means()
    tilted = sum(face_of(m) == 'tilted' for m in means)
    if ctx.k and tilted < WHOLE_UNIT_MIN_TILTED:
        return sel          # misalignment unobservable: whole_unit is not a candidate
    folds, n_folds = _whole_unit_folds(ctx.windows)
    if n_folds < 2 or (folds.min() >= 0 and n_folds < WHOLE_UNIT_MIN_FOLDS):
        sel.reason += (f'; whole-unit check skipped: {n_folds} hold folds (the held-out score '
                       'would be dominated by extrapolation)')
        return sel
    t_start = time.perf_counter()
    try:
        res, n_folds = heldout_whole_unit(ctx)
    except FitNotConverged as e:
        sel.reason += f'; whole_unit not a candidate: on a training fold {e.what}'
        return sel
    g = ctx.options.gravity
    held = np.isfinite(res['accel']['field'])
    n = ctx.windows.n[held]
    acc = {k: _weighted_rms(v[held], n) / g * 1e6 for k, v in res['accel'].items()}
    gyr = {k: _weighted_rms(v[held], n) for k, v in res['gyro'].items()}
    for k in acc:
        sel.table[f'{k} |a|-g'] = {'residual_ug': acc[k]}
        sel.table[f'{k} |w| still'] = {'residual_rad_s': gyr[k]}
    sel.seconds += time.perf_counter() - t_start
    kept = [k for k in acc if acc[k] <= KEEP_RATIO * min(acc.values())]
    # no temperature input: both models are constant, whole_unit only adds the
    # misalignment the tilted holds observe, so it needs no margin
    margin = WHOLE_UNIT_MARGIN if ctx.k else 0.0
    if len(kept) == 1:
        wins = kept[0] == 'whole_unit'
        why = (f'{"field" if wins else "whole_unit"} is more than {KEEP_RATIO:g}x worse held '
               'out on |a|-g')
    else:
        wins = (tilted >= WHOLE_UNIT_MIN_TILTED
                and acc['whole_unit'] < (1 - margin) * acc['field']
                and gyr['whole_unit'] <= (1 + WHOLE_UNIT_GYRO_SLACK) * gyr['field'])
        better = (f'{100 * margin:.0f} % better' if margin else
                  'better (no margin: without a temperature input both are constant)')
        why = (f'whole_unit {better} on |a|-g with the gyro no worse and >= '
               f'{WHOLE_UNIT_MIN_TILTED} tilted holds' if wins else
               f'whole_unit not {better} on |a|-g with the gyro no worse, or fewer than '
               f'{WHOLE_UNIT_MIN_TILTED} tilted holds')
    text = (f'; candidates compared held out: field, whole_unit ({tilted} of {len(ids)} '
            f'holds off the six faces, {n_folds} folds): |a|-g RMS field {acc["field"]:.1f} '
            f'ug, whole_unit {acc["whole_unit"]:.1f} ug; still-gyro |w| RMS field '
            f'{gyr["field"]:.2e}, whole_unit {gyr["whole_unit"]:.2e} rad/s; {why}: ')
    if wins:
        sel.model = 'whole_unit'
        sel.reason += text + 'chose whole_unit (seed 002)'
    else:
        sel.reason += text + 'field'
    return sel
