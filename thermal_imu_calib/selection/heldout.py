"""What every held-out comparison of ``--model auto`` shares: folds, clamping, scores.

``Selection`` is the outcome a comparison returns (kept on the Context for the estimators).
Folds: ``_hold_folds`` (the k-th hold of each face in fold k, so a fold leaves out at most
one hold per face), ``_whole_unit_folds`` (also when a face was held once), ``fold_masks``.
A model is evaluated on held-out data as a calibration from the training part would be:
its inputs clamped to the training range (``clamp_to_training``). Which inputs a thermal
lag applies to (``_lagged_inputs``: the degC ones) and whether a temperature filter can be
stored (``_filter_ok``) are shared by the one- and several-orientation comparisons.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import Dict, Optional

import numpy as np

from ..collection.segments import face_of
from ..estimation.calibrate import Estimate, input_units
from ..input_units import is_temperature

#: at most this many hold folds in the several-orientation comparison (fewer when a face
#: was held fewer times)
MULTI_FOLDS = 5
#: Estimate carries a temperature filter into the Calibration (calibrate.py support)
FILTER_SUPPORTED = 'temperature_filter' in {f.name for f in dataclasses.fields(Estimate)}


@dataclass
class Selection:
    """The outcome of the automatic choice, kept on the Context for the estimators."""

    model: str
    reason: str
    tau_s: Optional[np.ndarray] = None
    table: Dict[str, dict] = field(default_factory=dict)
    lag: Optional[dict] = None
    groups: str = ''
    kernels: Dict[str, list] = field(default_factory=dict)
    seconds: float = 0.0
    #: sensors fitted with no thermal terms (``placements``: the model harmed them)
    no_thermal: tuple = ()

    def report(self):
        """Return a plain dict for the calibration file's fit section."""
        out = {'model': self.model, 'reason': self.reason, 'cv_groups': self.groups,
               'heldout': self.table, 'lag': self.lag, 'seconds': round(self.seconds, 2)}
        if self.no_thermal:
            out['no_thermal'] = list(self.no_thermal)
        return out


def _weighted_mean(x, n):
    return np.average(x, axis=0, weights=n)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else float('nan')


def clamp_to_training(temps, windows, train, axis_input, margin):
    """Clamp model inputs to the training readings' range +- margin (each input's unit).

    What ``Calibration.apply`` does with the default ``clamp`` policy and the valid range
    of a calibration made from the training windows. ``margin``: scalar or (k,) per input.
    """
    if windows.n_inputs == 0:
        return temps
    margin = np.broadcast_to(np.asarray(margin, float), (windows.n_inputs,))[axis_input]
    lo = windows.temp[train].min(0)[axis_input] - margin
    hi = windows.temp[train].max(0)[axis_input] + margin
    return np.clip(temps, lo, hi)


def _hold_folds(windows, n_folds=MULTI_FOLDS):
    """Return (fold per window, number of folds): the k-th hold of each face goes to fold k.

    A fold then leaves out at most one hold per face, so every axis keeps an up and a down
    pose in training (needed to separate bias from scale factor). When a face was held only
    once that is impossible: fewer than 2 folds are returned (no comparison is made; the
    folds are then a plain round robin of the holds, for the RVM's own kernel search).
    """
    ids, means = windows.hold_means()
    faces = [face_of(m) for m in means]
    names = sorted(set(faces))
    counts = [faces.count(f) for f in names if f != 'tilted']
    n = min([n_folds] + counts) if counts else 0
    seen, fold_of = {}, {}
    for i, (h, f) in enumerate(zip(ids, faces)):
        k = seen.get(f, 0)
        seen[f] = k + 1
        # shifted per face, so a fold mixes repetitions (temperatures) instead of being one
        # time block of a warm-up; else a plain round robin
        fold_of[int(h)] = (k + names.index(f)) % n if n >= 2 else i % n_folds
    return np.array([fold_of[int(h)] for h in windows.hold]), n


def _weighted_rms(x, n):
    return float(np.sqrt(np.sum(n * x * x) / np.sum(n)))


def _whole_unit_folds(windows):
    """Return (fold per window, number of folds) for the whole-unit check.

    ``_hold_folds`` when every face was held at least twice; else (a face held once)
    each hold that can leave without taking a face's last hold away (a repeated face, or a
    tilted pose) is a fold of its own (at most ``MULTI_FOLDS``, round robin), and the other
    holds (fold -1) always train. A short hand-held session (six faces once, a few repeats
    and tilts) is then still compared held out.
    """
    folds, n = _hold_folds(windows)
    if n >= 2:
        # every face twice or more: the face folds (fewer than WHOLE_UNIT_MIN_FOLDS of them
        # skip the check, see there)
        return folds, n
    ids, means = windows.hold_means()
    faces = [face_of(m) for m in means]
    seen, fold_of, k = {}, {}, 0
    for h, f in zip(ids, faces):
        seen[f] = seen.get(f, 0) + 1
        if f == 'tilted' or seen[f] > 1:
            fold_of[int(h)] = k % MULTI_FOLDS
            k += 1
        else:
            fold_of[int(h)] = -1
    return np.array([fold_of[int(h)] for h in windows.hold]), min(k, MULTI_FOLDS)


def fold_masks(folds, n):
    """Yield (test, train) bool masks of folds 0..n-1 of ``folds`` (empty ones skipped)."""
    for f in range(n):
        test = folds == f
        if test.any():
            yield test, ~test


def _lagged_inputs(ctx):
    """Return the inputs a thermal lag applies to: the degC ones (a proxy has none)."""
    return [is_temperature(u) for u in input_units(ctx.options, ctx.k)]


def _filter_ok(ctx):
    return FILTER_SUPPORTED or getattr(ctx, 'filter_ok', False)
