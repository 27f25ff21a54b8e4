"""The gyroscope model of calibrations whose estimator fits only the accelerometer.

Estimators such as ``field`` return no gyro model; ``calibrate_windows`` then asks
``DEFAULT_GYRO[0](ctx, estimate)``. This module installs ``default_gyro``:

* one orientation, fewer than six distinct orientations, a lagged temperature, or too few
  holds to leave some out: the per-axis bias polynomial (``calibrate._gyro_bias``), as
  before;
* otherwise the bias polynomial and the seed 002 static gyro model (thermal bias +
  g-sensitivity C, earth rate removed with the latitude when it is given; ``gyro_fit``)
  are refitted with hold folds left out (at most one hold per face, ``select._hold_folds``)
  and scored on the held-out still windows by | |w| - earth rate |: a still gyro reads the
  earth rate in every pose, so a pose-dependent bias (g-sensitivity) or an earth rate
  absorbed into the bias shows as a spread of |w|. The seed 002 model is kept when it is
  ``GYRO_MARGIN`` better; the note says which and why.

With pose changes (the CLI and the calibrator node collect them) the seed 002 fit also
estimates the gyro scale and misalignment from the rotations.
"""

import numpy as np

#: WGS84 earth rotation rate, rad/s
EARTH_RATE = 7.2921150e-5
#: the seed 002 static gyro model must beat the bias polynomial by this much (relative)
GYRO_MARGIN = 0.25
#: distinct orientations needed: g-sensitivity needs gravity along every axis
MIN_ORIENTATIONS = 6

POLYNOMIAL_NOTE = ('gyroscope: bias polynomial from stationary windows; earth rotation is not '
                   'removed (up to 7.3e-5 rad/s)')


def still_rate_error(gyro):
    """Return | |w| - earth rate | per row of corrected still-gyro readings (rad/s)."""
    return np.abs(np.linalg.norm(gyro, axis=1) - EARTH_RATE)


def _whole_unit_gyro(ctx, rows, acc, accel_model, transitions=None):
    """Fit the seed 002 gyro on the windows ``rows`` (corrected accel ``acc`` per window)."""
    from ..estimation.gyro_fit import fit_gyro
    from ..estimation.observability import Priors
    o, k = ctx.options, ctx.k
    w = ctx.windows.select(rows)
    return fit_gyro(w, ctx.tg[rows] if k else None, acc[rows],
                    ctx.gyro_t0 if k else np.zeros(3), latitude=o.latitude,
                    transitions=transitions, accel_model=accel_model,
                    accel_input=ctx.accel_input, gyro_input=ctx.gyro_input,
                    priors=o.whole_unit_priors or Priors(),
                    order=o.order if k else 0, input_unit=ctx.gyro_unit)


def heldout_gyro(ctx, accel_model, acc):
    """Return ({'polynomial': (m,), 'whole_unit': (m,)} held-out still errors, folds).

    ``acc``: (m, 3) specific force per window corrected by ``accel_model``.
    """
    from ..estimation.calibrate import _gyro_bias
    from .select import _hold_folds, clamp_to_training
    w, o = ctx.windows, ctx.options
    folds, n = _hold_folds(w)
    out = {'polynomial': np.zeros(len(w)), 'whole_unit': np.zeros(len(w))}
    for f in range(n):
        test = folds == f
        train = ~test
        tg = clamp_to_training(ctx.tg, w, train, ctx.gyro_input, o.range_margin)
        poly, _ = _gyro_bias(ctx.subset(train))
        wu = _whole_unit_gyro(ctx, train, acc, accel_model).model
        out['polynomial'][test] = still_rate_error(poly.correct(w.gyro[test], tg[test]))
        out['whole_unit'][test] = still_rate_error(
            wu.correct(w.gyro[test], tg[test], aux={'accel': acc[test]}))
    return out, n


def default_gyro(ctx, est):
    """Return (gyro model, report, notes) for an Estimate without a gyro model."""
    from ..estimation.calibrate import _gyro_bias
    from .select import _hold_folds, _weighted_rms
    poly, rep = _gyro_bias(ctx)
    usable = (est.accel is not None and est.temperature_filter is None
              and ctx.n_orientations >= MIN_ORIENTATIONS
              and not ctx.coverage.get('missing') and _hold_folds(ctx.windows)[1] >= 2)
    if not usable:
        return poly, {'gyro_offset': rep}, [POLYNOMIAL_NOTE]
    acc = est.accel.correct(ctx.windows.accel, ctx.ta)
    res, n_folds = heldout_gyro(ctx, est.accel, acc)
    score = {k: _weighted_rms(v, ctx.windows.n) for k, v in res.items()}
    report = {'gyro_offset': rep, 'gyro_choice': {
        'heldout_still_error_rad_s': score, 'folds': n_folds, 'margin': GYRO_MARGIN}}
    text = (f'held-out still-gyro error | |w| - earth rate | RMS: bias polynomial '
            f'{score["polynomial"]:.2e}, seed 002 static model {score["whole_unit"]:.2e} '
            f'rad/s ({n_folds} hold folds)')
    if score['whole_unit'] >= (1 - GYRO_MARGIN) * score['polynomial']:
        report['gyro_choice']['model'] = 'polynomial'
        return poly, report, [POLYNOMIAL_NOTE + f'; {text}']
    fit = _whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel,
                           ctx.options.transitions or None)
    report['gyro_choice']['model'] = 'whole_unit_gyro'
    report['gyro_whole_unit'] = fit.stats
    notes = [f'gyroscope: seed 002 static model (thermal bias + g-sensitivity C) chosen over '
             f'the bias polynomial: {text}'] + list(fit.notes)
    return fit.model, report, notes


def _install():
    """Install ``default_gyro`` as ``calibrate.DEFAULT_GYRO[0]`` (via ESTIMATOR_MODULES)."""
    from ..estimation import calibrate
    calibrate.DEFAULT_GYRO[0] = default_gyro


_install()
