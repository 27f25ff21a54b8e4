"""``--model auto`` for one orientation on a history that runs one way (a warm-up, one leg).

Within one monotonic leg the temperature rate has one sign, so a term in the thermal
history (the lag difference, the rate) is fitted from the rate's variation only and flips
sign on the other direction; such logs keep the lag decision of the previous path
(``select.select_single``: ``thermal_lag.estimate_tau`` at equal order, contiguous time
blocks, used above 10 %), whose choice is the *incumbent* here. The issue-22 rules apply
on top of it:

* the flight stacks' cubic (``ARDUPILOT_SPEC``, ArduPilot's form for one orientation) is
  always a candidate, and so are no thermal terms (``NO_THERMAL_SPEC``: the output as it
  is) and offset polynomials of order 1..3 in the input the lag
  search chose (the reading, or the reading through its lag), each time-weighted or uniform
  in temperature (``estimation.hysteresis.fit_weights``);
* every candidate is scored on **held-out contiguous temperature bands** inside the range:
  the span is cut into ``N_BANDS`` equal bands and each interior band (not the coldest or
  the hottest one, which would be an extrapolation, clamped in use) is held out in turn and
  predicted from a fit on the rest. In one leg a band is also a contiguous block of time;
* figure per fold: the corrected held-out output minus the training part's mean corrected
  output (one pose: the constant is not observable), averaged over ``BLOCK_S`` blocks, RMS
  of the 3-vector norm; so a level error across the band counts, as it does when a leg is
  tested against another one; every fold divided by the raw figure, mean over the folds;
* per sensor, the pool is the candidates within ``MARGIN`` of the best that are not worse
  than the cubic. The incumbent stays when it is in the pool of both sensors; otherwise
  each sensor gets the simplest spec of its pool (the cubic when the pool is empty), fitted
  by ``history_select`` (model ``hysteresis``). A spec offered as the one in use
  (``CalibrateOptions.incumbent_specs``, the lifelong loop's) is scored too and is that
  sensor's pick whenever it is in the pool, if it is a candidate here or a polynomial in
  the reading (one with history terms or a lagged input is not offered here: one leg
  cannot tell those, see above).

With ``placement_floor`` (the holds are separate placements: a robot's stops) a candidate
is also scored with whole placements left out (``placements.placement_groups``; inputs
clamped to the training range, as a calibration from the training part is applied), and
for a sensor only the candidates no worse there than the output as it is (score <= 1, no
thermal terms always) stay eligible; the pool, the floor and the pick are then taken among
them. It adds no threshold: the bands and the placements are both held-out data, and a
model is kept only when neither says it harms.

``fit.model_choice`` lists every candidate's per-fold figure (``heldout``).
"""

import time

import numpy as np

from ..estimation.calibrate import input_units
from ..estimation.hysteresis import (ARDUPILOT_SPEC, Features, fit_spec,
                                     NO_THERMAL_SPEC, predict, Spec)
from ..estimation.thermal_lag import lagged_axis_temperatures
from ..input_units import is_temperature
from .heldout import clamp_to_training
from .placements import (BLOCK_S, floor_margin, harms, level_drift,  # noqa: F401 (re-export)
                         mean_ratios, placement_groups, raw_figures, spec_figures)
from .time_folds import (complexity, incumbent_note, label, MARGIN, MIN_TEST_WINDOWS, PLACED,
                         RVM, whole_holds)

#: the temperature span is cut into this many equal bands; the interior ones are held out
#: (the granularity of the previous path's six time blocks, without its two end blocks)
N_BANDS = 6
#: name of the previous path's choice in the tables
INCUMBENT = 'incumbent'


def _label(key, incumbent):
    """Return a candidate's name in the tables and the summary."""
    return f'{INCUMBENT} ({incumbent.model})' if key == INCUMBENT else label(key)


def band_folds(windows, column=0, n_bands=N_BANDS, placements=False):
    """Return (list of (train, test, label), kind): interior temperature bands held out.

    ``placements``: the holds are separate placements (``time_folds.whole_holds``).
    """
    if windows.n_inputs == 0 or len(windows) == 0:
        return [], 'no temperature'
    temp = windows.temp[:, column]
    lo, hi = float(temp.min()), float(temp.max())
    if hi <= lo:
        return [], 'no temperature span'
    band = np.minimum(((temp - lo) / (hi - lo) * n_bands).astype(int), n_bands - 1)
    folds = []
    for b in range(1, n_bands - 1):
        test = band == b
        if test.sum() >= MIN_TEST_WINDOWS and (~test).sum() >= 8:
            a, z = lo + b * (hi - lo) / n_bands, lo + (b + 1) * (hi - lo) / n_bands
            folds.append((~test, test, f'band {a:.1f}..{z:.1f} degC'))
    if placements:
        folds = whole_holds(windows, folds)
    return folds, (f'{len(folds)} interior temperature bands of {n_bands} equal ones held '
                   'out, each fitted on the rest' + (PLACED if placements else ''))


def candidate_specs(tau):
    """Return (eligible specs simplest first, floor spec, specs reported only).

    Always ``NO_THERMAL_SPEC`` (the output as it is: its figure is the raw one). Without a
    lag: the flight stacks' cubic (``ARDUPILOT_SPEC``, the floor) and offset
    polynomials of order 1..3 in the reading, time-weighted or uniform in temperature.
    With the lag the lag search chose: the same polynomials in the lagged reading, the floor
    being ArduPilot's form (cubic, time-weighted) in that input; the cubic in the reading
    is reported but not eligible, since bands of one leg cannot tell the reading from its
    lag (the lag was decided on time blocks).
    """
    base = () if tau is None else (round(float(np.max(tau)), 1),)
    out = [NO_THERMAL_SPEC] + ([] if base else [ARDUPILOT_SPEC])
    for weighting in ('time', 'temperature'):
        for order in (1, 2, 3):
            out.append(Spec(order, base, (), weighting))
    floor = ARDUPILOT_SPEC if not base else Spec(3, base, (), 'time')
    out = sorted(out, key=lambda s: (s.n_params, s is not ARDUPILOT_SPEC))
    return out, floor, ([ARDUPILOT_SPEC] if base else [])


def export_figures(windows, axis_input, signal, spec, t0, folds, levels=False):
    """Return the per-fold figure of ``spec`` refitted as the exporters write it (in T).

    A spec in a lagged input is exported as the same polynomial in the reading (thermal
    equilibrium); specs in the reading export unchanged.
    """
    feats = Features(windows, axis_input, levels)
    y = getattr(windows, signal)
    flat = Spec(spec.order, (), (), spec.weighting)
    out = []
    for train, test, _ in folds:
        coef, _ = fit_spec(feats, spec, y, train, t0)
        out.append(level_drift(y - predict(feats, flat, coef, t0), windows, train, test))
    return out


def _family_figures(ctx, name, tau, kernels, fit_single, folds, margin=None):
    """Return {sensor: [figure per fold]} of a family of the previous path, or None.

    ``kernels``: the RVM kernels chosen on every window; only their presence is used (the
    family was fitted), each fold searches its own. ``margin``: not None, the inputs are
    clamped to each fold's training range +- margin (``heldout.clamp_to_training``).
    """
    family = {'offset': 'poly', 'lag': 'poly', 'rvm': 'rvm', 'rvm-lag': 'rvm'}.get(name)
    if family is None or (family == 'rvm' and not kernels):
        return None
    w = ctx.windows
    tau = tau if name.endswith('lag') else None
    out = {'accel': [], 'gyro': []}
    temps = {'accel': lagged_axis_temperatures(w, tau, ctx.accel_input),
             'gyro': lagged_axis_temperatures(w, tau, ctx.gyro_input)}
    for train, test, _ in folds:
        # the RVM's kernels are searched again on the training part of each fold: kernels
        # chosen on every window would have seen the held-out band
        acc, gyr, _ = fit_single(ctx, family, tau, w.select(train))
        for sig, m, idx in (('accel', acc, ctx.accel_input), ('gyro', gyr, ctx.gyro_input)):
            y = getattr(w, sig)
            x = (temps[sig] if margin is None else
                 clamp_to_training(temps[sig], w, train, idx, margin))
            out[sig].append(level_drift(m.correct(y, x), w, train, test))
    return out


def _placement_scores(ctx, sig, idx, t0, keys, incumbent, fit_single, floor_folds, cache):
    """Return {candidate: score of raw} with whole placements held out (inputs clamped)."""
    w = ctx.windows
    margin = floor_margin(ctx)
    specs = [k for k in keys if isinstance(k, Spec)]
    figs = spec_figures(w, idx, sig, specs, t0, floor_folds, margin,
                        ctx.options.levels(sig))
    for key, name, tau in ((INCUMBENT, incumbent.model, incumbent.tau_s), (RVM, RVM, None)):
        if key in keys:
            if key not in cache:
                cache[key] = _family_figures(ctx, name, tau, incumbent.kernels.get(name),
                                             fit_single, floor_folds, margin)
            if cache[key] is not None:
                figs[key] = cache[key][sig]
    return mean_ratios(figs, raw_figures(w, sig, floor_folds))


def floor_family(ctx, sel, fit_single):
    """Apply the placement floor to the previous path's family as it stays; returns a note.

    Each sensor's model of ``sel``'s family is refitted with whole placements left out;
    a sensor it harms there is listed in ``sel.no_thermal`` (the estimator then fits it
    with no thermal terms). '' when the option is off or fewer than 2 groups remain.
    """
    folds = placement_groups(ctx.windows) if ctx.options.placement_floor else []
    if len(folds) < 2:
        return ''
    figs = _family_figures(ctx, sel.model, sel.tau_s, sel.kernels.get(sel.model), fit_single,
                           folds, floor_margin(ctx))
    if figs is None:
        return ''
    held = {s: mean_ratios({s: figs[s]}, raw_figures(ctx.windows, s, folds))[s]
            for s in ('accel', 'gyro')}
    sel.no_thermal = tuple(s for s, v in held.items() if harms(v))
    return (f'placement floor ({len(folds)} groups of whole holds held out): {sel.model} '
            + ', '.join(f'{s} {v:.3f} of raw' for s, v in held.items())
            + (f'; no thermal terms for the {" and ".join(sel.no_thermal)}'
               if sel.no_thermal else ''))


def select_one_way(ctx, incumbent, fit_single):
    """Decide between the previous path's choice and the spec candidates on held-out bands.

    ``incumbent``: the ``Selection`` of ``select.select_single``; ``fit_single``: its fit
    helper (passed in: ``select`` imports this module). Returns (None, note) when the
    incumbent stays, or becomes the RVM for both sensors (the note is appended to its reason
    by the caller), else (res, note)
    with ``res`` the dict ``history_select.estimate_hysteresis`` refits
    (``{'specs', 'table', 'kind', 'folds', 'reason', 'seconds', 'export_loss'}``).
    """
    t_start = time.perf_counter()
    w = ctx.windows
    if not all(is_temperature(u) for u in input_units(ctx.options, ctx.k)):
        return None, ('one-way history with an input that is not a temperature (a proxy): '
                      'the flight stacks\' cubic and the band candidates are temperature '
                      'models, kept')
    folds, kind = band_folds(w, placements=ctx.options.placement_folds)
    if len(folds) < 2:
        floor = floor_family(ctx, incumbent, fit_single)
        return None, (f'one-way history: {kind}; fewer than 2 held-out bands, kept'
                      + (f'; {floor}' if floor else ''))
    lag = incumbent.tau_s if incumbent.model.endswith('lag') else None
    specs, floor_spec, shown = candidate_specs(lag)
    inc = _family_figures(ctx, incumbent.model, incumbent.tau_s,
                          incumbent.kernels.get(incumbent.model), fit_single, folds)
    # the RVM (seed 003) in the reading, with the kernels the previous path chose for it;
    # not in a lagged input: its filter would also lag the other sensor's history model
    rvm = (_family_figures(ctx, RVM, None, incumbent.kernels.get(RVM), fit_single, folds)
           if lag is None and incumbent.model != RVM else None)
    units = {'accel': 'm/s^2', 'gyro': 'rad/s'}
    table, pools, picks, texts, export_loss = {}, {}, {}, [], {}
    floor_folds = placement_groups(w) if ctx.options.placement_floor else []
    floor_on, floor_cache = len(floor_folds) >= 2, {}
    for sig, idx, t0 in (('accel', ctx.accel_input, ctx.t0),
                         ('gyro', ctx.gyro_input, ctx.gyro_t0)):
        t0 = np.asarray(t0, float)
        raw = raw_figures(w, sig, folds)
        # the spec in use, if it is one this path may choose: a candidate here, or a
        # polynomial in the reading (history terms and lags are decided on time blocks)
        offered = (ctx.options.incumbent_specs or {}).get(sig)
        offered = offered if isinstance(offered, Spec) and offered not in shown and (
            offered in specs or not (offered.base or offered.terms)) else None
        extra = [offered] if offered is not None and offered not in specs else []
        figs = spec_figures(w, idx, sig, specs + shown + extra, t0, folds,
                            levels=ctx.options.levels(sig))
        if inc is not None:
            figs[INCUMBENT] = inc[sig]
        if rvm is not None:
            figs[RVM] = rvm[sig]
        scores = {k: v for k, v in mean_ratios(figs, raw).items() if np.isfinite(v)}
        eligible = {k: v for k, v in scores.items() if k not in shown}
        placed = ''
        if floor_on:
            held = _placement_scores(ctx, sig, idx, t0, list(eligible), incumbent, fit_single,
                                     floor_folds, floor_cache)
            harm = [k for k in eligible if k is not NO_THERMAL_SPEC
                    and harms(held.get(k, np.inf))]
            eligible = {k: v for k, v in eligible.items() if k not in harm}
            for k, v in held.items():
                table.setdefault(_label(k, incumbent), {})[f'{sig}_placement_score'] = v
            placed = (f'; placement floor ({len(floor_folds)} groups of whole holds held '
                      f'out): {len(harm)} worse than the output as it is' +
                      (' (' + ', '.join(_label(k, incumbent) for k in harm) + ')' if harm
                       else ''))
        best = min(eligible.values())
        floor = eligible.get(floor_spec, np.inf)
        pools[sig] = [k for k in eligible if eligible[k] <= best * (1 + MARGIN)
                      and eligible[k] <= floor]
        spec_pool = [k for k in pools[sig] if k != INCUMBENT]
        if floor_on and not spec_pool:
            # the incumbent alone qualified, and may not stay (the other sensor): the
            # specs within the margin of the best spec the placements did not reject
            specs_left = {k: v for k, v in eligible.items() if isinstance(k, Spec)}
            spec_best = min(specs_left.values())
            spec_pool = [k for k, v in specs_left.items()
                         if v <= spec_best * (1 + MARGIN) and v <= floor]
        picks[sig] = (offered if offered in spec_pool else
                      min(spec_pool, key=lambda s: (complexity(s), scores[s])) if spec_pool
                      else floor_spec)
        placed += incumbent_note(offered if offered in scores else None, picks[sig], scores)
        table.setdefault('raw', {})[sig] = float(np.mean(raw))
        table['raw'][f'{sig}_per_fold'] = [float(v) for v in raw]
        for k, v in figs.items():
            label = _label(k, incumbent)
            row = table.setdefault(label, {})
            row[sig] = float(np.mean(v))
            row[f'{sig}_per_fold'] = [float(x) for x in v]
            row[f'{sig}_score'] = scores.get(k, float('nan'))
        if isinstance(picks[sig], Spec) and picks[sig].base:
            ref = t0
            exported = export_figures(w, idx, sig, picks[sig], ref, folds,
                                      ctx.options.levels(sig))
            export_loss[sig] = {'model': float(np.mean(figs[picks[sig]])),
                                'as_cubic_without_history': float(np.mean(exported)),
                                'unit': units[sig],
                                'per_fold': [float(v) for v in exported]}
        parts = ', '.join(f'{_label(k, incumbent)} '
                          f'{scores[k]:.3f}' for k in sorted(eligible, key=eligible.get)[:4])
        texts.append(f'{sig}: raw {np.mean(raw):.3g} {units[sig]}; best (score of raw) '
                     f'{parts}; floor {floor_spec.label()} {floor:.3f}' +
                     ''.join(f'; {k.label()} {scores[k]:.3f} (reported only: the lag '
                             'search chose the lagged input)' for k in shown if k in scores)
                     + placed)
    keep = inc is not None and all(INCUMBENT in pools[s] for s in pools)
    verdict = (f'kept {incumbent.model}' if keep else
               'chose ' + ', '.join(f'{s} {_label(p, incumbent)}' for s, p in picks.items()))
    note = (f'one-way history, {kind} ({len(folds)} folds, {BLOCK_S:.0f}-s drift against '
            f'the training mean): ' + '; '.join(texts) + f'; {verdict} (candidates within '
            f'{100 * MARGIN:.0f} % of the best and not worse than the floor; the previous '
            'choice stays when it qualifies for both sensors)')
    if keep or all(p == RVM for p in picks.values()):
        # the previous path's Selection, or the same turned to its RVM (its estimator
        # reuses the kernels chosen on every window)
        if not keep:
            incumbent.model, incumbent.tau_s = RVM, None
        incumbent.table['one_way'] = table
        return None, note
    res = {'specs': picks, 'table': table, 'kind': kind,
           'folds': [lab for _, _, lab in folds], 'reason': f'{incumbent.reason}; {note}',
           'seconds': incumbent.seconds + time.perf_counter() - t_start,
           'export_loss': export_loss, 'rvm_kernels': incumbent.kernels.get(RVM)}
    return res, note
