"""Held-out figures on separate placements: the no-harm floor of one orientation's choice.

A robot's stops are separate placements: each hold stands on its own floor, so its level on
the horizontal axes holds g sin(tilt) that no thermal model can predict. With
``CalibrateOptions.placement_floor`` a sensor's chosen thermal model must be no worse than
its output as it is when whole placements are left out (``placement_groups``); the
figure is ``level_drift`` (30-s blocks of the held-out output against the training part's
mean: in one pose the constant is not observable), the model's inputs clamped to the
training range as a calibration from the training part is applied, each fold divided by
the raw figure and averaged (``mean_ratios``). A score above 1 is harm: that sensor gets no
thermal terms. No threshold is added.
"""

import numpy as np

from ..estimation.calibrate import input_margins
from ..estimation.hysteresis import ARDUPILOT_SPEC, ARDUPILOT_TREF, Features, fit_spec, predict
from .heldout import clamp_to_training

#: held-out figure: averaging block, s (the chamber log's scoring window)
BLOCK_S = 30.0
#: at most this many groups of whole holds are held out in turn
MAX_GROUPS = 6


def placement_groups(windows, max_groups=MAX_GROUPS, min_train=8):
    """Return [(train, test, label)]: whole holds (placements) left out, a group at a time.

    The holds in time order are cut into at most ``max_groups`` contiguous groups of
    near-equal hold counts (one hold a group while there are no more holds than that);
    each group is held out in turn and the rest trains, so no test hold has a window in
    training. Folds left with fewer than ``min_train`` training windows are dropped.
    """
    ids = np.unique(windows.hold)
    if len(ids) < 2:
        return []
    first = np.array([windows.t0[windows.hold == h].min() for h in ids])
    groups = np.array_split(ids[np.argsort(first)], min(max_groups, len(ids)))
    out = []
    for g in groups:
        test = np.isin(windows.hold, g)
        if (~test).sum() >= min_train:
            lab = f'hold {g[0]}' if len(g) == 1 else f'holds {g[0]}..{g[-1]} ({len(g)})'
            out.append((~test, test, lab))
    return out


def level_drift(corrected, windows, train, test, block_s=BLOCK_S):
    """Return the held-out figure: RMS over ``block_s`` blocks of |block mean - train mean|.

    ``corrected``: (m, 3) corrected window means; the training mean is weighted by the
    windows' sample counts. The blocks are cut in the held-out windows' mid times.
    """
    idx = np.flatnonzero(test)
    if len(idx) == 0 or not np.any(train):
        return float('nan')
    ref = np.average(corrected[train], axis=0, weights=windows.n[train])
    tm = 0.5 * (windows.t0[idx] + windows.t1[idx])
    blk = np.floor((tm - tm.min()) / block_s).astype(int)
    _, inv = np.unique(blk, return_inverse=True)
    cnt = np.bincount(inv)
    d = np.stack([np.bincount(inv, corrected[idx, a] - ref[a]) / cnt for a in range(3)],
                 axis=1)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def mean_ratios(figs, raw):
    """Return {candidate: mean over the folds of figure / raw figure} (folds with raw > 0)."""
    raw = np.asarray(raw, float)
    ok = raw > 0
    return {k: float(np.mean(np.asarray(v)[ok] / raw[ok])) if ok.any() else float(np.mean(v))
            for k, v in figs.items()}


class ClampedFeatures(Features):
    """``Features`` whose readings and lagged readings pass through ``clamp``."""

    def __init__(self, feats, clamp):
        super().__init__(feats.windows, feats.axis_input, feats.levels is not None)
        self._src, self._clamp = feats, clamp
        self.temp = clamp(feats.temp)

    def lagged(self, taus):
        """Return the (m, 3) lagged readings, clamped."""
        return self._clamp(self._src.lagged(taus))


def floor_margin(ctx):
    """Return the clamp margin of a calibration from these windows (each input's unit)."""
    return input_margins(ctx.windows, ctx.options) if ctx.k else ctx.options.range_margin


def spec_figures(windows, axis_input, signal, specs, t0, folds, margin=None, levels=False):
    """Return {spec: [level_drift per fold]} of hysteresis specs fitted on each training part.

    ``margin``: not None, the inputs are clamped to the fold's training range +- margin
    (``heldout.clamp_to_training``), as the calibration would apply them. ``levels``:
    each placement's level is a random effect in the fits (``Features``).
    """
    feats = Features(windows, axis_input, levels)
    y = getattr(windows, signal)
    used = [feats if margin is None else ClampedFeatures(
        feats, lambda x, tr=train: clamp_to_training(x, windows, tr, axis_input, margin))
        for train, _, _ in folds]
    out = {}
    for s in specs:             # each spec's design once, for every fold (time_folds too)
        ref = np.full(3, ARDUPILOT_TREF) if s is ARDUPILOT_SPEC else t0
        a = feats.design(s, ref)
        out[s] = []
        for (train, test, _), feats_k in zip(folds, used):
            coef, _ = fit_spec(feats, s, y, train, ref, design=a)
            offset = predict(feats_k, s, coef, ref, design=a if margin is None else None)
            out[s].append(level_drift(y - offset, windows, train, test))
    return out


def raw_figures(windows, signal, folds):
    """Return [level_drift of the output as it is, per fold]."""
    y = getattr(windows, signal)
    return [level_drift(y, windows, tr, te) for tr, te, _ in folds]


def harms(score):
    """Return True when a placement score says the model is worse than no model (or unknown)."""
    return not score <= 1.0
