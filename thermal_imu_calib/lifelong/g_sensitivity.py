"""The gyro's g-sensitivity learned from the stops off the mounting pose (slopes), held out.

A fit of one mounting pose cannot see the gyro's g-sensitivity C (rad/s per m/s^2, seed
002 eq. 3): the specific force is the same in every hold, so C f is part of the bias. On a
slope the specific force turns by the slope's angle and the gyro reads C (f - f_level)
more; on simulated robot months the slope stops' gyro error was 2-4x the level stops'
(docs/lifelong.md). The lifelong fit leaves those stops out (``pose.main_pose_mask``), but
the store keeps them, so:

* **pairs**: each hold off the mounting pose with the mean of the main-pose holds within
  ``PAIR_S`` of it: the difference of the mean gyro error (the calibration's corrected
  gyro less the earth rate's vertical part, ``gate.hold_errors``'s ``gyro_vec``) and of
  the corrected specific force. The level holds near in time carry the same thermal
  misfit and ageing, which the difference removes; the horizontal earth rate (the heading
  is not known) stays in it as noise;
* **C**: the least-squares fit of those gyro differences on the force differences in the
  two directions perpendicular to the level gravity (along it a slope of a few degrees
  moves f by 1 - cos of the angle: nothing to fit), zero along it, so a level hold reads
  as before;
* **held out**: fitted on the older pairs, the newest ``HELDOUT_FRACTION`` scored with and
  without it (``selection.paired.paired_test``, one-sided at its ``ALPHA``); used only when
  it passes, and then fitted on every pair;
* **the model**: an ``offset_polynomial`` gyro becomes the seed 002 gyro form with the same
  offset polynomial, unit scale and the coupling (``WholeUnitGyroModel``); a gyro of another
  family is left as it is (the note says so).

On by default (``LifelongConfig.gyro_g_sensitivity``; docs/lifelong.md, (c'')). No ROS
import.
"""

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
from scipy.special import ndtri

from ..models.whole_unit import WholeUnitGyroModel
from ..selection.paired import ALPHA, hold_positions, MIN_HELDOUT, paired_test
from . import gate

#: main-pose holds within this of a hold off the pose are its level reference (s)
PAIR_S = 6 * 3600.0
#: share of the pairs (the newest) the coupling is judged on before it is used
HELDOUT_FRACTION = 1.0 / 3.0
#: fewest pairs the held-out fit is made on (two force directions per gyro axis)
MIN_TRAIN = 6


@dataclass
class Coupling:
    """What the g-sensitivity stage found: the fitted C (or why not) and its held-out test."""

    used: bool
    text: str
    c: Optional[np.ndarray] = None      # (3, 3) gyro error per specific force, rad/s/(m/s^2)
    pairs: int = 0
    z: float = float('nan')
    heldout: int = 0
    rms_without: float = float('nan')   # rad/s, held-out pairs
    rms_with: float = float('nan')


def hold_pose(windows, in_pose, ids):
    """Return (h,) whether each hold of ``ids`` has a window in the main pose (``in_pose``)."""
    pos = hold_positions(ids, windows.hold)
    return np.bincount(pos, weights=np.asarray(in_pose, float), minlength=len(ids)) > 0


def pairs(err, main, pair_s=PAIR_S):
    """Return (gyro differences (m, 3), force differences (m, 3), t (m,), level force (3,)).

    ``err``: ``gate.hold_errors`` of one calibration; ``main`` (h,): the holds in the main
    pose. A hold off the pose pairs with the mean of the main-pose holds within ``pair_s``
    (s) of its end; one without any is dropped.
    """
    t, g, a = err['t'], err['gyro_vec'], err['accel_vec']
    lv, off = np.flatnonzero(main), np.flatnonzero(~main)
    f_level = np.median(a[lv], 0) if len(lv) else np.array([0.0, 0.0, 1.0])
    if not len(lv) or not len(off):
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), f_level
    near = (np.abs(t[off][:, None] - t[lv][None, :]) <= pair_s).astype(float)
    cnt = near.sum(1)
    ok = cnt > 0
    near, cnt, off = near[ok], cnt[ok], off[ok]
    dg = g[off] - near @ g[lv] / cnt[:, None]
    da = a[off] - near @ a[lv] / cnt[:, None]
    return dg, da, t[off], f_level


def _across(up):
    """Return (2, 3): two unit vectors perpendicular to ``up`` and to each other."""
    u = np.asarray(up, float) / np.linalg.norm(up)
    seed = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, seed)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)])


def fit(dg, da, up):
    """Return C (3, 3) with dg ~ C da, fitted across ``up`` and zero along it (rad/s/(m/s^2))."""
    e = _across(up)
    b, *_ = np.linalg.lstsq(da @ e.T, dg, rcond=None)    # (2, 3)
    return b.T @ e


def learn(cal, windows, in_pose, gravity, latitude=None):
    """Return the ``Coupling`` the holds off the main pose support for ``cal``'s gyro.

    ``windows``: every hold's windows (main pose and off it), ``in_pose`` (n,) the windows
    of the main pose (``pose.main_pose_mask``).
    """
    if cal is None or cal.gyro is None or not len(windows):
        return Coupling(False, 'g-sensitivity: no gyro model or no holds')
    err = gate.hold_errors(cal, windows, gravity, latitude)
    main = hold_pose(windows, in_pose, err['ids'])
    dg, da, t, f_level = pairs(err, main)
    m = len(t)
    n_held = max(MIN_HELDOUT, int(round(m * HELDOUT_FRACTION)))
    if m - n_held < MIN_TRAIN:
        return Coupling(False, f'g-sensitivity not fitted: {m} holds off the mounting pose '
                               f'with a level hold within {PAIR_S / 3600:g} h, '
                               f'{MIN_TRAIN + MIN_HELDOUT} needed', pairs=m)
    order = np.argsort(t, kind='stable')
    train, held = order[:m - n_held], order[m - n_held:]
    c_train = fit(dg[train], da[train], f_level)
    r_ref = np.linalg.norm(dg[held], axis=1)
    r_cand = np.linalg.norm(dg[held] - da[held] @ c_train.T, axis=1)
    z, n = paired_test(r_ref, r_cand)
    before = float(np.sqrt(np.mean(r_ref ** 2)))
    after = float(np.sqrt(np.mean(r_cand ** 2)))
    used = bool(np.isfinite(z) and z > -ndtri(ALPHA))
    figures = (f'{n} newest of {m} holds off the mounting pose, fitted on the older: gyro '
               f'{before * 1e3:.3f} -> {after * 1e3:.3f} mrad/s, paired z {z:.2f}')
    if not used:
        return Coupling(False, f'g-sensitivity not used ({figures}; limit '
                               f'{-ndtri(ALPHA):.2f})', pairs=m, z=z, heldout=n,
                        rms_without=before, rms_with=after)
    c = fit(dg, da, f_level)
    return Coupling(True, f'g-sensitivity used ({figures}); fitted on all {m}', c=c,
                    pairs=m, z=z, heldout=n, rms_without=before, rms_with=after)


def attach(cal, coupling):
    """Return (calibration, note): ``cal`` with the coupling in its gyro model, if it can.

    Only an ``offset_polynomial`` gyro takes it: it becomes a ``WholeUnitGyroModel`` with
    the same offset polynomial (and stds), unit scale and coupling -C, so the corrected
    rate is the old one less C times the corrected specific force (C is zero along the
    level gravity: a level hold reads as before).
    """
    if not coupling.used:
        return cal, coupling.text
    g = cal.gyro
    if g is None or g.kind != 'offset_polynomial':
        return cal, (coupling.text + f'; not applied: the gyro model is '
                     f'{getattr(g, "kind", "absent")}, only an offset polynomial takes it')
    std = {} if g.coeff_std is None else {f'cw{j}': s for j, s in enumerate(g.coeff_std)}
    if std:
        std['Omega0'] = np.zeros(3)
    model = WholeUnitGyroModel(
        g.t0, g.coeffs, None, np.zeros(3), np.eye(3), None, None, -coupling.c, std=std,
        estimated={'C': np.abs(coupling.c) > 0}, input_unit=g.input_unit,
        fixed={'Omega1': 'lifelong: unit scale (one mounting pose)',
               'C': 'lifelong: zero along the level gravity (slopes do not move it)'},
        convention='lifelong: offset polynomial + g-sensitivity from the stops off the '
                   'mounting pose')
    fitted = dict(cal.fit or {})
    fitted['g_sensitivity'] = {'pairs': coupling.pairs, 'heldout': coupling.heldout,
                               'z': coupling.z, 'rms_without_rad_s': coupling.rms_without,
                               'rms_with_rad_s': coupling.rms_with}
    return replace(cal, gyro=model, fit=fitted), coupling.text
