"""Model choice for one orientation by held-out blocks of the thermal history.

A calibration is used forward in time, on a thermal history it has not seen. Random holds
or windows do not test that: their neighbours share the history, so memorising it scores
well. The folds here are contiguous blocks of the history, each fitted on the rest:

* a cycle with three or more temperature legs (``thermal_lag.legs``): each leg is held out
  in turn (its training part still holds both heating and cooling);
* otherwise (one turn: cool then heat, or heat then cool): the last part of the history
  is held out, fitted on everything before it; the cuts lie at ``FORWARD_CUTS`` of the
  last leg, so every training part holds both directions, as the final calibration does.
  (A single monotonic leg, a warm-up, is not handled here: ``history_select``.)

Held-out figure (the one the chamber log is scored by): the corrected output averaged over
``BLOCK_S`` blocks, its change within the held-out part (block mean minus the part's
mean), RMS over the blocks of the 3-vector norm. Only held-out windows inside the training
temperature range are scored when there are at least ``MIN_TEST_WINDOWS`` of them (a leg
is judged over the temperatures both sides cover); else all of them, the models evaluated
as fitted (a clamped input would score every shape alike: as the raw drift).

Every candidate of ``estimation.hysteresis.candidate_specs`` (order, history terms, lags,
weighting; no thermal terms at all, whose figure is the raw one), and the RVM in the
reading (``RVM``, kernels searched inside each fold), gets the mean over the folds of its
figure divided by the raw figure; the simplest candidate within ``MARGIN`` of the best is
chosen per sensor, and never one whose figure is worse than the flight stacks' cubic
(``ARDUPILOT_SPEC``), which is then chosen.
"""

import dataclasses
import time

import numpy as np
from scipy.optimize import minimize_scalar

from ..estimation.hysteresis import (ARDUPILOT_SPEC, ARDUPILOT_TREF, candidate_specs,
                                     Features, fit_spec, NO_THERMAL_SPEC, predict, Spec)
from ..estimation.rvm_fit import fit_rvm_offset
from ..estimation.thermal_lag import cv_groups, legs
from .heldout import clamp_to_training
from .placements import (BLOCK_S, floor_margin, harms, level_drift, mean_ratios,
                         placement_groups, raw_figures, spec_figures)

#: forward folds: the last leg after this fraction of its time span is held out
FORWARD_CUTS = (0.25, 0.5, 0.75)
#: fewest held-out windows inside the training range for the range to be used
MIN_TEST_WINDOWS = 12
#: a richer candidate must be this much better (relative) than a simpler one
MARGIN = 0.03
#: the RVM family (seed 003, in the reading) among the candidates: ranked after every spec
RVM = 'rvm'


def label(key):
    """Return a candidate's name: a spec's label, or 'rvm'."""
    return key.label() if isinstance(key, Spec) else str(key)


def complexity(key):
    """Return the parsimony rank: a spec's parameter count; the RVM after every spec."""
    return key.n_params if isinstance(key, Spec) else 100


def turns_both_ways(ctx):
    """Return True when the windows hold both a heating and a cooling leg.

    Within one monotonic leg (a warm-up) the temperature rate is a function of the
    temperature, so a history term cannot be told from the temperature shape and a
    held-out last part is an extrapolation; such logs keep ``select.select_single``
    (lag search at equal order, contiguous time blocks).
    """
    if ctx.k == 0 or len(ctx.windows) == 0:
        return False
    _, info = legs(ctx.windows)
    return len({leg['direction'] for leg in info}) == 2


#: appended to a fold description when the holds are separate placements (``whole_holds``)
PLACED = "; a test hold's other windows out of training (holds are separate placements)"


def whole_holds(windows, folds, min_train=8):
    """Return ``folds`` with every test hold's other windows taken out of training.

    For holds that are separate placements (``CalibrateOptions.placement_folds``): a
    hold's level holds its unknown pose, so a model that can tell holds apart (a lagged
    input barely moves inside one) would otherwise learn a test hold's level from its own
    training windows. Folds left with fewer than ``min_train`` training windows are dropped.
    """
    out = []
    for train, test, lab in folds:
        train = train & ~np.isin(windows.hold, np.unique(windows.hold[test]))
        if train.sum() >= min_train:
            out.append((train, test, lab))
    return out


def time_folds(windows, column=0, placements=False):
    """Return (list of (train mask, test mask, label), kind) of contiguous history blocks.

    ``placements``: the holds are separate placements (``whole_holds``).
    """
    tm = 0.5 * (windows.t0 + windows.t1)
    leg_ids, info = legs(windows, column)
    folds = []
    if len(info) >= 3:
        for leg in info:
            test = leg_ids == leg['leg']
            folds.append((~test, test, f'leg {leg["leg"]} ({leg["direction"]} '
                                       f'{leg["t_min"]:.1f}..{leg["t_max"]:.1f} degC)'))
        kind = f'leave one of {len(info)} temperature legs out'
    else:
        last = leg_ids == (info[-1]['leg'] if info else 0)
        t_lo, t_hi = (tm[last].min(), tm[last].max()) if last.any() else (0.0, 0.0)
        for f in FORWARD_CUTS:
            cut = t_lo + f * (t_hi - t_lo)
            train = tm < cut
            if train.sum() >= 8 and (~train).sum() >= 2:
                folds.append((train, ~train, f'after {100 * f:.0f} % of the last leg'))
        kind = (f'last part of the history held out, fitted on what came before (cuts at '
                f'{", ".join(f"{100 * f:.0f}" for f in FORWARD_CUTS)} % of the last leg)')
    if placements:
        folds = whole_holds(windows, folds)
    return folds, kind + (PLACED if placements else '')


def block_drift(values, t_mid, rows, block_s=BLOCK_S):
    """Return the RMS over ``block_s`` blocks of |block mean - mean of the blocks| (norm)."""
    idx = np.flatnonzero(rows)
    if len(idx) == 0:
        return float('nan')
    t = t_mid[idx]
    blk = np.floor((t - t.min()) / block_s).astype(int)
    _, inv = np.unique(blk, return_inverse=True)
    cnt = np.bincount(inv)
    means = np.stack([np.bincount(inv, values[idx, a]) / cnt for a in range(values.shape[1])],
                     axis=1)
    d = means - means.mean(0)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def _scored_rows(temps, train, test):
    """Return the held-out rows to score: those inside the training range, if enough."""
    lo, hi = temps[train].min(0), temps[train].max(0)
    inside = test & np.all((temps >= lo) & (temps <= hi), axis=1)
    if inside.sum() >= MIN_TEST_WINDOWS:
        return inside
    return test


def heldout_figures(windows, axis_input, signal, specs, t0, folds, levels=False):
    """Return ({spec: [figure per fold]}, [raw figure per fold]) for one sensor.

    ``levels``: each placement's level is a random effect in the fits (``Features``).
    """
    feats = Features(windows, axis_input, levels)
    y = getattr(windows, signal)
    tm = 0.5 * (windows.t0 + windows.t1)
    scored = [_scored_rows(feats.temp, train, test) for train, test, _ in folds]
    raw = [block_drift(y, tm, rows) for rows in scored]
    out = {}
    for s in specs:             # each spec's design once, for every fold
        ref = np.full(3, ARDUPILOT_TREF) if s is ARDUPILOT_SPEC else t0
        a = feats.design(s, ref)
        out[s] = []
        for (train, _, _), rows in zip(folds, scored):
            coef, _ = fit_spec(feats, s, y, train, ref, design=a)
            out[s].append(block_drift(y - predict(feats, s, coef, ref, design=a), tm, rows))
    return out, raw


def rvm_fold_models(windows, axis_input, signal, t0, folds):
    """Yield (train, test, per-axis readings, model) of the RVM in the reading per fold.

    The model is fitted on the fold's training part, its kernels searched there.
    """
    temps = windows.temp[:, list(axis_input)]
    for train, test, _ in folds:
        wt = windows.select(train)
        model, _ = fit_rvm_offset(wt, temps[train], signal, signal, cv_groups(wt)[0],
                                  offset_only=signal == 'accel', t_ref=t0)
        yield train, test, temps, model


def rvm_figures(windows, axis_input, signal, t0, folds):
    """Return [figure per fold] of the RVM in the reading, kernels searched in each fold.

    Scored like the specs (the rows of ``_scored_rows``, the model evaluated as fitted).
    """
    y = getattr(windows, signal)
    tm = 0.5 * (windows.t0 + windows.t1)
    return [block_drift(model.correct(y, temps), tm, _scored_rows(temps, train, test))
            for train, test, temps, model in rvm_fold_models(windows, axis_input, signal, t0,
                                                             folds)]


def export_figures(windows, axis_input, signal, spec, t0, folds, levels=False):
    """Return the per-fold figure of ``spec`` written as a flight stack's cubic.

    PX4 and ArduPilot compensate with a cubic of the reading and no history: the exporters
    (``formats``) refit the model at thermal equilibrium, where the history terms vanish
    and a lagged input equals the reading. That is the spec's polynomial alone, in T.
    """
    feats = Features(windows, axis_input, levels)
    y = getattr(windows, signal)
    tm = 0.5 * (windows.t0 + windows.t1)
    flat = dataclasses.replace(spec, base=(), terms=(), name='')
    out = []
    for train, test, _ in folds:
        rows = _scored_rows(feats.temp, train, test)
        coef, _ = fit_spec(feats, spec, y, train, t0)
        out.append(block_drift(y - predict(feats, flat, coef[:spec.order + 1], t0), tm, rows))
    return out


def scaled(spec, factor):
    """Return ``spec`` with every lag time constant (not the rate's smoothing) times factor."""
    def sc(taus):
        return tuple(round(float(t) * factor, 1) for t in taus)
    terms = tuple((k, t if k == 'rate' else sc(t)) for k, t in spec.terms)
    return dataclasses.replace(spec, base=sc(spec.base), terms=terms, name='')


def refine(windows, axis_input, signal, spec, t0, folds, raw, levels=False):
    """Refine the lags of ``spec`` by the held-out figure; returns (spec, figures).

    A bounded 1-D search of a common factor on its time constants (x0.6 .. x1.6, the
    neighbouring grid cells), scored like the grid (mean over the folds of figure / raw).
    Specs without a lag (and the RVM) are returned unchanged (figures None).
    """
    if not isinstance(spec, Spec) or (not spec.base
                                      and all(k == 'rate' for k, _ in spec.terms)):
        return spec, None
    raw = np.asarray(raw, float)
    ok = raw > 0

    def figures(factor):
        s = scaled(spec, factor)
        return s, heldout_figures(windows, axis_input, signal, [s], t0, folds, levels)[0][s]

    def objective(log_f):
        v = np.asarray(figures(float(np.exp(log_f)))[1])
        return float(np.mean(v[ok] / raw[ok])) if ok.any() else float(np.mean(v))
    res = minimize_scalar(objective, bounds=(np.log(0.6), np.log(1.6)), method='bounded',
                          options={'xatol': 0.02})
    return figures(float(np.exp(res.x)))


def choose(figures, raw, incumbent=None):
    """Return (chosen spec, {spec: score}): simplest within MARGIN of the best, >= floor.

    ``incumbent`` (a key of ``figures``, ``CalibrateOptions.incumbent_specs``): chosen
    whenever it is in that pool, so the spec in use changes only when held-out blocks say
    it is more than ``MARGIN`` worse than the best.
    """
    raw = np.asarray(raw, float)
    ok = raw > 0
    scores = {s: float(np.mean(np.asarray(v)[ok] / raw[ok])) if ok.any() else float(np.mean(v))
              for s, v in figures.items()}
    scores = {s: v for s, v in scores.items() if np.isfinite(v)}
    best = min(scores.values())
    floor = scores.get(ARDUPILOT_SPEC, np.inf)
    pool = [s for s in scores if scores[s] <= best * (1 + MARGIN) and scores[s] <= floor]
    if incumbent is not None and incumbent in pool:
        return incumbent, scores
    chosen = min(pool, key=lambda s: (complexity(s), scores[s])) if pool else ARDUPILOT_SPEC
    return chosen, scores


def family(spec):
    """Return the family of a spec for the summary: its kind of history and weighting."""
    if spec is ARDUPILOT_SPEC:
        return 'ardupilot'
    if spec == NO_THERMAL_SPEC:
        return 'no thermal terms'
    if not isinstance(spec, Spec):
        return label(spec)
    kinds = {'rate' if k == 'rate' else ('two-state lag' if len(t) > 1 else 'lag difference')
             for k, t in spec.terms}
    what = 'lagged T' if spec.base else (' + '.join(sorted(kinds)) if kinds else 'T only')
    return f'{what} ({spec.weighting})'


def family_best(figs):
    """Return {family: best mean held-out figure} over the candidates (summary text)."""
    out = {}
    for s, v in figs.items():
        f = family(s)
        if f != 'ardupilot':
            out[f] = min(out.get(f, np.inf), float(np.mean(v)))
    return dict(sorted(out.items()))


def _floor_score(ctx, sig, idx, t0, spec, folds):
    """Return the placement score (of raw) of the chosen ``spec`` or RVM for one sensor."""
    w, margin = ctx.windows, floor_margin(ctx)
    if isinstance(spec, Spec):
        figs = spec_figures(w, idx, sig, [spec], t0, folds, margin,
                            ctx.options.levels(sig))[spec]
    else:                       # the RVM in the reading, kernels searched in each fold
        y = getattr(w, sig)
        figs = [level_drift(model.correct(y, clamp_to_training(temps, w, train, idx, margin)),
                            w, train, test)
                for train, test, temps, model in rvm_fold_models(w, idx, sig, t0, folds)]
    return mean_ratios({'m': figs}, raw_figures(w, sig, folds))['m']


def incumbent_note(inc, spec, scores):
    """Return the summary's words on the spec in use (``choose``'s ``incumbent``), or ''."""
    if inc is None:
        return ''
    return (f'; the calibration in use\'s {label(inc)} {scores.get(inc, np.nan):.3f} of raw, '
            + ('kept (within the margin of the best)' if spec == inc else 'replaced'))


def select_history(ctx, signals=('accel', 'gyro')):
    """Choose the history model per sensor; returns a dict for Selection and the estimator.

    ``{'specs': {sensor: Spec}, 'table': {label: {sensor: figure, ...}}, 'folds': [...],
    'kind': str, 'reason': str, 'seconds': float}``
    """
    t_start = time.perf_counter()
    w = ctx.windows
    folds, kind = time_folds(w, placements=ctx.options.placement_folds)
    floor_folds = placement_groups(w) if ctx.options.placement_floor else []
    specs = candidate_specs()
    units = {'accel': 'm/s^2', 'gyro': 'rad/s'}
    chosen, table, texts, export_loss = {}, {}, [], {}
    for sig, idx, t0 in (('accel', ctx.accel_input, ctx.t0), ('gyro', ctx.gyro_input,
                                                              ctx.gyro_t0)):
        if sig not in signals:
            continue
        lv = ctx.options.levels(sig)
        inc = (ctx.options.incumbent_specs or {}).get(sig)
        extra = [inc] if isinstance(inc, Spec) and inc not in specs else []
        figs, raw = heldout_figures(w, idx, sig, specs + extra, np.asarray(t0, float), folds,
                                    lv)
        if not lv:      # the RVM cannot take a random level per placement (no candidate)
            figs[RVM] = rvm_figures(w, idx, sig, np.asarray(t0, float), folds)
        inc = inc if inc in figs else None
        spec, _ = choose(figs, raw, inc)
        if spec != inc:
            fine, fine_figs = refine(w, idx, sig, spec, np.asarray(t0, float), folds, raw, lv)
            if fine_figs is not None and fine not in figs:
                figs[fine] = fine_figs
        spec, scores = choose(figs, raw, inc)
        placed = incumbent_note(inc, spec, scores)
        if len(floor_folds) >= 2 and spec != NO_THERMAL_SPEC:
            held = _floor_score(ctx, sig, idx, np.asarray(t0, float), spec, floor_folds)
            placed += (f'; placement floor ({len(floor_folds)} groups of whole holds held '
                       f'out): {held:.3f} of raw')
            if harms(held):
                placed += f', so no thermal terms instead of {label(spec)}'
                spec = NO_THERMAL_SPEC
        chosen[sig] = spec
        table.setdefault('raw', {})[sig] = float(np.mean(raw))
        for s in figs:
            row = table.setdefault(label(s), {})
            row[sig] = float(np.mean(figs[s]))
            row[f'{sig}_per_fold'] = [float(v) for v in figs[s]]
            row[f'{sig}_score'] = scores.get(s, float('nan'))
        ref = np.full(3, ARDUPILOT_TREF) if spec is ARDUPILOT_SPEC else np.asarray(t0, float)
        if isinstance(spec, Spec):
            exported = export_figures(w, idx, sig, spec, ref, folds, lv)
            export_loss[sig] = {'model': float(np.mean(figs[spec])),
                                'as_cubic_without_history': float(np.mean(exported)),
                                'unit': units[sig], 'per_fold': [float(v) for v in exported]}
        floor = float(np.mean(figs[ARDUPILOT_SPEC]))
        best = float(np.mean(figs[spec]))
        fam = ', '.join(f'{k} {v:.3g}' for k, v in family_best(figs).items())
        texts.append(f'{sig} ({units[sig]}): raw {np.mean(raw):.3g}, ardupilot cubic '
                     f'{floor:.3g}; best of each family: {fam}; chose {label(spec)} '
                     f'{best:.3g} ({len(figs)} candidates, lags refined by the held-out '
                     'figure)' + placed)
    reason = (f'one orientation; held-out blocks of the thermal history ({kind}; '
              f'{BLOCK_S:.0f}-s drift RMS, mean over {len(folds)} folds): ' + '; '.join(texts))
    return {'specs': chosen, 'table': table, 'kind': kind, 'export_loss': export_loss,
            'folds': [lab for _, _, lab in folds], 'reason': reason,
            'seconds': time.perf_counter() - t_start}
