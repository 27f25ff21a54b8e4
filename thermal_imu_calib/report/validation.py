"""Report figures of a thermal log's validation: held-out blocks and the flight-stack cubic.

For a calibration whose model was chosen on held-out blocks of the thermal history
(``selection.time_folds``, or the interior temperature bands of a one-way history,
``selection.one_way_select``; ``fit.selection.folds``):

* ``heldout_residuals``: every fold's held-out part, each candidate family's best spec (as
  in the summary), the ArduPilot-style cubic and raw refitted on the fold's training part;
  their held-out output averaged over 30-s blocks, minus the part's mean (the figure the
  choice was made on), norm over the axes, against time; fitted with a random level per
  hold for the sensors whose choice was (``fit.placement_levels``);
* ``side_by_side``: the whole log, raw, compensated (the calibration streamed over the
  windows' history) and the ArduPilot-style cubic fitted on the same windows, each as
  its 30-s drift about its mean, per axis, against time.
"""

import numpy as np

from ..estimation.hysteresis import (ARDUPILOT_SPEC, ARDUPILOT_TREF, candidate_specs,
                                     Features, fit_spec, predict)
from ..selection.one_way_select import band_folds
from ..selection.time_folds import BLOCK_S, family, heldout_figures, time_folds
from .figures import _subplots, COLORS, stream_windows

SCALE = {'accel': (1.0, 'm/s^2'), 'gyro': (1.0, 'rad/s')}


def has_validation(cal):
    """Return True when the calibration was chosen on held-out history blocks."""
    sel = (cal.fit or {}).get('selection') or {}
    return bool(sel.get('folds')) and cal.inputs and cal.accel is not None


def _blocks(t, y, rows):
    """Return (block mid times, |block mean - mean of the blocks|) over ``rows``."""
    idx = np.flatnonzero(rows)
    tt = t[idx]
    blk = np.floor((tt - tt.min()) / BLOCK_S).astype(int)
    u, inv = np.unique(blk, return_inverse=True)
    cnt = np.bincount(inv)
    means = np.stack([np.bincount(inv, y[idx, a]) / cnt for a in range(y.shape[1])], 1)
    mids = np.bincount(inv, tt) / cnt
    return mids, np.linalg.norm(means - means.mean(0), axis=1)


def _levels(cal, signal):
    """Return whether the calibration's fits of ``signal`` took a random level per hold."""
    return signal in ((cal.fit or {}).get('placement_levels') or ())


def _family_specs(windows, axis_input, signal, t0, folds, levels=False):
    """Return [(label, spec)]: the best spec of each family by the held-out figure."""
    specs = candidate_specs()
    figs, _ = heldout_figures(windows, axis_input, signal, specs, t0, folds, levels)
    best = {}
    for s, v in figs.items():
        f = family(s)
        if f == 'ardupilot':
            continue
        if f not in best or np.mean(v) < np.mean(figs[best[f]]):
            best[f] = s
    return [(f, s) for f, s in sorted(best.items())]


def _folds(cal, windows):
    """Return the folds the calibration was chosen on: history blocks or interior bands."""
    groups = str(((cal.fit or {}).get('selection') or {}).get('cv_groups', ''))
    return band_folds(windows) if 'interior temperature bands' in groups else \
        time_folds(windows)


def heldout_residuals(cal, windows):
    """Figure: per fold and sensor, each family's held-out 30-s drift against time."""
    folds, kind = _folds(cal, windows)
    tm = 0.5 * (windows.t0 + windows.t1)
    t_rel = tm - tm.min()
    fig, grid = _subplots(2, 1, figsize=(11, 7), sharex=True)
    for row, (sig, idx, t0) in enumerate((('accel', cal.accel_input, cal.accel.t0),
                                          ('gyro', cal.gyro_input,
                                           getattr(cal.gyro, 't0', cal.accel.t0)))):
        ax = grid[row]
        lv = _levels(cal, sig)      # fitted as the choice was (placement_levels)
        feats = Features(windows, idx, lv)
        y = getattr(windows, sig)
        fams = _family_specs(windows, idx, sig, np.asarray(t0, float), folds, lv)
        cmap = [f'C{i}' for i in range(10)]
        for k, (train, test, label) in enumerate(folds):
            lo, hi = feats.temp[train].min(0), feats.temp[train].max(0)
            inside = test & np.all((feats.temp >= lo) & (feats.temp <= hi), axis=1)
            rows = inside if inside.sum() >= 12 else test
            first = k == 0
            mids, d = _blocks(t_rel, y, rows)
            ax.plot(mids, d, color='0.6', lw=2, label='raw' if first else None)
            for j, (name, spec) in enumerate([('ardupilot', ARDUPILOT_SPEC)] + fams):
                ref = np.full(3, ARDUPILOT_TREF) if spec is ARDUPILOT_SPEC else \
                    np.asarray(t0, float)
                coef, _ = fit_spec(feats, spec, y, train, ref)
                mids, d = _blocks(t_rel, y - predict(feats, spec, coef, ref), rows)
                style = dict(color='k', lw=2) if spec is ARDUPILOT_SPEC else \
                    dict(color=cmap[j % 10], lw=1)
                ax.plot(mids, d, label=(name if spec is ARDUPILOT_SPEC else
                                        f'{name}: {spec.label()}') if first else None,
                        **style)
            ax.axvline(t_rel[test].min(), color='0.3', ls=':', lw=0.8)
        unit = SCALE[sig][1]
        ax.set_ylabel(f'{sig} held-out 30-s drift [{unit}]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2, loc='upper left')
    grid[1].set_xlabel('time since the first window [s] (dotted: start of a held-out part)')
    grid[0].set_title(f'Held-out blocks of the thermal history ({kind}): each family\'s best '
                      'candidate fitted on the rest', fontsize=9)
    return fig


def side_by_side(cal, windows):
    """Figure: raw, compensated and ArduPilot-style cubic, 30-s drift per axis vs time."""
    tm = 0.5 * (windows.t0 + windows.t1)
    t_rel = tm - tm.min()
    a_c, g_c = stream_windows(cal, windows)
    fig, grid = _subplots(2, 3, figsize=(12, 6), sharex=True)
    for row, (sig, comp, idx) in enumerate((('accel', a_c, cal.accel_input),
                                            ('gyro', g_c, cal.gyro_input))):
        y = getattr(windows, sig)
        feats = Features(windows, idx)
        ref = np.full(3, ARDUPILOT_TREF)
        rows = np.ones(len(windows), bool)
        coef, _ = fit_spec(feats, ARDUPILOT_SPEC, y, rows, ref)
        cubic = y - predict(feats, ARDUPILOT_SPEC, coef, ref)
        for i in range(3):
            ax = grid[row, i]
            for name, v, style in (('raw', y, dict(color='0.6', lw=2)),
                                   ('ArduPilot-style cubic', cubic, dict(color='k', lw=1)),
                                   ('compensated (this calibration)', comp,
                                    dict(color=COLORS[i], lw=1.2))):
                mids, _ = _blocks(t_rel, v[:, i:i + 1], rows)
                blk = np.floor(t_rel / BLOCK_S).astype(int)
                _, inv = np.unique(blk, return_inverse=True)
                means = np.bincount(inv, v[:, i]) / np.bincount(inv)
                ax.plot(mids, means - means.mean(), label=name, **style)
            ax.set_title(f'{sig} {"xyz"[i]}', fontsize=9)
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_ylabel(f'30-s mean - mean [{SCALE[sig][1]}]')
    grid[0, 0].legend(fontsize=7)
    for ax in grid[1]:
        ax.set_xlabel('time [s]')
    return fig
