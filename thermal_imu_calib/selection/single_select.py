"""``--model auto`` on one orientation: the thermal offset models compared held out.

One orientation: only an offset per axis as a function of temperature is observable (the
bias and scale of an axis separate only between its up and down poses). Every candidate
below is such an offset model; they differ in the shape of the dependence, which needs the
temperature to move. (When the degC inputs span less than ``select.SINGLE_MIN_SPAN``,
``select.auto_policy`` ends at ``offset`` before any comparison.)

One orientation across a temperature span (warm-up, chamber cycle): the lag search
(thermal_lag.estimate_tau, same polynomial order with and without the lag) decides whether
the models see a first-order lagged temperature. The candidates are the offset polynomial
(order per axis by CV, 0..3) with and without that lag and the RVM (seed 003) with the
chosen filter. Every candidate is refitted with one temperature leg (chamber cycle), hold,
or contiguous time block (single warm-up) left out, and scored on it: the held-out drift is
the corrected output minus its mean over the training part (the constant is not observable
in one pose), inputs clamped to the training range, RMS over windows and axes, divided by
the raw signal's held-out drift, averaged over accelerometer and gyroscope. Among the
candidates with the chosen filter the simplest within 5 % of the best wins (order: offset,
lag, rvm, rvm-lag).

When the temperature turns both ways (``time_folds.turns_both_ways``), the history models
are compared instead (``select_single_history``).
"""

import time

import numpy as np

from ..estimation.calibrate import input_margins
from ..estimation.offset_fit import fit_offset_model
from ..estimation.rvm_fit import fit_rvm_offset
from ..estimation.thermal_lag import cv_groups, estimate_tau, lagged_axis_temperatures, tau_or_none
from .heldout import (_filter_ok, _lagged_inputs, _rms, _weighted_mean, clamp_to_training,
                      Selection)
from .time_folds import select_history

#: candidates in order of complexity (parsimony prefers the earlier one on a near tie)
SINGLE_CANDIDATES = ('offset', 'lag', 'rvm', 'rvm-lag')
#: a more complex single-orientation candidate must be this much better (relative)
SINGLE_MARGIN = 0.05
#: the lag is used when it cuts the held-out error of the lag search by this much
LAG_MIN_IMPROVEMENT = 0.10


def fit_single(ctx, family, tau, windows=None, groups=None, kernels=None, rvm_settings=None,
               signals=('accel', 'gyro'), no_thermal=()):
    """Fit accel and gyro offset models of ``family`` ('poly'/'rvm') on lagged inputs.

    Returns (accel model, gyro model, report); a sensor not in ``signals`` gets None.
    ``windows`` defaults to the context's; ``groups`` are its CV groups (legs, holds,
    time blocks). A sensor in ``no_thermal`` gets an offset polynomial of order 0 (no
    thermal terms: the gyro's bias; nothing for an offset-only accelerometer).
    """
    w = ctx.windows if windows is None else windows
    if groups is None:
        groups, _ = cv_groups(w)
    kernels = kernels or {}
    out, rep = {}, {}
    for sig, idx in (('accel', ctx.accel_input), ('gyro', ctx.gyro_input)):
        if sig not in signals:
            out[sig], rep[sig] = None, None
            continue
        temps = lagged_axis_temperatures(w, tau, idx)
        single_accel = sig == 'accel'    # one pose: the constant is gravity, not bias
        ref = ctx.t0 if single_accel else ctx.gyro_t0
        if family == 'poly' or sig in no_thermal:
            out[sig], rep[sig] = fit_offset_model(w, temps, ref, sig, sig,
                                                  include_constant=not single_accel,
                                                  orders=(0,) if sig in no_thermal else
                                                  (0, 1, 2, 3), groups=groups,
                                                  levels=ctx.options.levels(sig))
        else:
            out[sig], rep[sig] = fit_rvm_offset(w, temps, sig, sig, groups,
                                                offset_only=single_accel, t_ref=ref,
                                                settings=rvm_settings,
                                                kernels=kernels.get(sig))
    return out['accel'], out['gyro'], rep


def heldout_single(ctx, family, tau, groups, kernels=None, rvm_settings=None,
                   signals=('accel', 'gyro')):
    """Return the per-axis held-out drift RMS {'accel': (3,), 'gyro': (3,)} of a candidate.

    Each group is left out in turn; the drift of a held-out window is its corrected
    output minus the n-weighted mean corrected output of the training windows. Inputs
    are clamped to the training range as a calibration from the training part would.
    """
    w = ctx.windows
    ta = lagged_axis_temperatures(w, tau, ctx.accel_input)
    tg = lagged_axis_temperatures(w, tau, ctx.gyro_input)
    margin = input_margins(w, ctx.options) if ctx.k else ctx.options.range_margin
    sse = {s: np.zeros(3) for s in signals}
    for g in np.unique(groups):
        test = groups == g
        train = ~test
        wt = w.select(train)
        if family == 'raw':
            models = {'accel': None, 'gyro': None}
        else:
            acc, gyr, _ = fit_single(ctx, family, tau, wt, groups[train], kernels,
                                     rvm_settings, signals)
            models = {'accel': acc, 'gyro': gyr}
        for sig, temps, idx in (('accel', ta, ctx.accel_input), ('gyro', tg, ctx.gyro_input)):
            if sig not in signals:
                continue
            y = getattr(w, sig)
            m = models[sig]
            c = y if m is None else m.correct(y, clamp_to_training(temps, w, train, idx,
                                                                   margin))
            ref = _weighted_mean(c[train], w.n[train])
            sse[sig] += np.sum((c[test] - ref) ** 2, axis=0)
    return {k: np.sqrt(v / len(w)) for k, v in sse.items()}


def select_single(ctx, rvm_settings=None, candidates=SINGLE_CANDIDATES,
                  signals=('accel', 'gyro')):
    """Compare the single-orientation candidates; returns a ``Selection``.

    ``signals`` limits the score to the accelerometer or the gyroscope (e.g. a gyro-only
    comparison across soaks in different orientations).
    """
    t_start = time.perf_counter()
    w = ctx.windows
    groups, kind = cv_groups(w)
    if len(np.unique(groups)) < 2:
        return Selection('offset', 'too few windows for held-out validation: offset '
                         'polynomial', groups=kind)
    lag = estimate_tau(w, ctx.accel_input, ctx.gyro_input, groups, group_kind=kind,
                       signals=signals, lagged=_lagged_inputs(ctx),
                       levels=ctx.options.level_sensors())
    if ctx.options.level_sensors():
        # the RVM cannot take a random level per placement: it would read them as
        # temperature, so it is no candidate when the holds are separate placements
        candidates = tuple(c for c in candidates if not c.startswith('rvm'))
    tau = tau_or_none(lag, LAG_MIN_IMPROVEMENT)
    lag_note = (f'lag search: tau {np.max(lag.tau_s):.0f} s cuts the held-out error of a '
                f'quadratic by {100 * lag.improvement:.0f} % (used above '
                f'{100 * LAG_MIN_IMPROVEMENT:.0f} %)')
    if tau is not None and not _filter_ok(ctx):
        lag_note += ' (not used: this calibrate.py cannot store a temperature filter)'
        tau = None
    kernels = {}
    if 'rvm' in candidates or 'rvm-lag' in candidates:
        # the RVM (the costly candidate) only with the filter the lag search chose
        for name, tt in (('rvm', None), ('rvm-lag', tau)):
            if name not in candidates or (name == 'rvm-lag') != (tau is not None):
                continue
            acc, gyr, _ = fit_single(ctx, 'rvm', tt, groups=groups, rvm_settings=rvm_settings,
                                     signals=signals)
            kernels[name] = {s: m.kernel_list for s, m in (('accel', acc), ('gyro', gyr))
                             if m is not None}
    raw = heldout_single(ctx, 'raw', None, groups, signals=signals)
    table = {'raw': {s: _rms(v) for s, v in raw.items()}}
    spec = {'offset': ('poly', None), 'lag': ('poly', tau), 'rvm': ('rvm', None),
            'rvm-lag': ('rvm', tau)}
    scores = {}
    for name in candidates:
        family, tt = spec[name]
        if (name.endswith('lag') and tt is None) or (family == 'rvm' and name not in kernels):
            continue
        err = heldout_single(ctx, family, tt, groups, kernels.get(name), rvm_settings, signals)
        table[name] = {s: _rms(v) for s, v in err.items()}
        ratios = [table[name][s] / table['raw'][s] for s in signals if table['raw'][s] > 0]
        scores[name] = float(np.mean(ratios))
        table[name]['score'] = scores[name]
    # the filter comes from the lag search (same polynomial order with and without the
    # lag, so the comparison is not confounded by the order); the family by held-out error
    pool = [n for n in candidates if n in scores and n.endswith('lag') == (tau is not None)]
    best = min(scores[n] for n in pool)
    chosen = next(n for n in pool if scores[n] <= best * (1 + SINGLE_MARGIN))
    units = {'accel': 'm/s^2', 'gyro': 'rad/s'}
    parts = ', '.join(n + ' ' + ' / '.join(f'{table[n][s]:.3g} {units[s]}' for s in signals)
                      for n in ['raw'] + list(scores))
    reason = (f'one orientation; held-out drift (leave one of {len(np.unique(groups))} '
              f'{kind} out, {" / ".join(signals)} RMS): {parts}; {lag_note}; chose {chosen} '
              f'(score {scores[chosen]:.3f} of raw)')
    return Selection(chosen, reason, tau if chosen.endswith('lag') else None, table,
                     lag.report(), kind, kernels, time.perf_counter() - t_start)


def select_single_history(ctx, res=None):
    """Return the Selection of the one-orientation history path (``time_folds``).

    The model is 'hysteresis' (``history_select``), which refits the chosen specs
    (``res``: already chosen, e.g. by ``one_way_select``).
    """
    res = res or select_history(ctx)
    sel = Selection('hysteresis', res['reason'], None, res['table'], None, res['kind'],
                    seconds=res['seconds'])
    sel.history = res
    return sel
