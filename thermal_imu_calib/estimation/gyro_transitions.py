"""The pose changes of the gyroscope rotation fit, prepared once (``gyro_rotations``).

Each pose change between two holds is compensated with the static gyro model (thermal
bias, g-sensitivity with the accelerometer model's specific force), cut to its motion
(``_motion_extent``: still samples only add angle random walk), integrated by the
trapezoid rule into per-interval increments linear in the unknown scale, misalignment and
nonlinearity (``PreparedTransitions``), with the within-interval coning term, and runs of
increments whose composition is their sum to ``MERGE_COMMUTATOR`` are summed
(``_merge_commuting``). A pose change back to the same pose by whole turns is taken as
closed (``is_full_turn``). Units: rad, rad/s, s.
"""

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..rotations import cross, sum_sq


@dataclass
class PreparedTransitions:
    """Fixed per-transition arrays of the rotation fit (padded with zeros to one length).

    The rotation increment of sample interval k is linear in the unknowns:
    ``theta_k = Omega1 b_k + Omega2 o c2_k + Omega3 o c3_k`` (trapezoid rule).
    """

    b: np.ndarray          # (k, n, 3) integrated bias/g-sensitivity-free raw rate, rad
    c2: np.ndarray         # (k, n, 3) integrated W^2
    c3: np.ndarray         # (k, n, 3) integrated W^3
    u_from: np.ndarray     # (k, 3)
    u_to: np.ndarray       # (k, 3)
    sigma: np.ndarray      # (k,) rad, direction-residual standard deviation
    closed: np.ndarray     # (k,) bool
    index: List[int] = field(default_factory=list)   # positions in the input list
    cone: Optional[np.ndarray] = None                 # (k, n, 3) coning increments, rad


def _trapezoid(x, dt):
    return 0.5 * (x[1:] + x[:-1]) * dt[:, None]


#: consecutive increments are summed into one while the neglected second-order term of the
#: composition (1/2 sum_{i<j} theta_i x theta_j, Baker-Campbell-Hausdorff) stays below this
MERGE_COMMUTATOR = 1e-7      # rad
#: motion = smoothed bias-free rate above this many noise standard deviations
MOTION_SIGMAS = 8.0
#: still time kept around the detected motion of a transition, s
MOTION_MARGIN_S = 0.25
#: start and end of a pose change in the same pose: gravity directions within this (deg)
SAME_POSE_DEG = 5.0
#: a same-pose change is a full turn when its integrated angle is within this fraction of
#: n x 360 deg (n >= 1): covers the raw scale error of MEMS gyros (imucal's Ferraris
#: session: +3.4 % on x) and a hand-made turn that ends a few degrees off
FULL_TURN_TOLERANCE = 0.10


def is_full_turn(rate, dt, up_from, up_to):
    """Return True when a pose change is a whole number of turns back to the same pose.

    rate: (n, 3) bias-free angular rate (rad/s) over the samples; dt: (n - 1,) s; up_from,
    up_to: unit gravity directions of the holds before and after. The rotation angle is the
    norm of the integrated rate (exact for a turn about a fixed axis).
    """
    if float(np.dot(up_from, up_to)) < np.cos(np.radians(SAME_POSE_DEG)) or len(dt) == 0:
        return False
    angle = float(np.degrees(np.linalg.norm(np.sum(_trapezoid(rate, dt), axis=0))))
    turns = round(angle / 360.0)
    return turns >= 1 and abs(angle - 360.0 * turns) <= FULL_TURN_TOLERANCE * 360.0 * turns


def _group_starts(increments, window=64):
    """Return the first sample of every merged group of each (n_t, 3) increment array, rad.

    A group grows while the neglected second-order term of its composition,
    E = 1/2 sum_{l<j} theta_l x theta_j over the group, stays within ``MERGE_COMMUTATOR``;
    the sample that would exceed it starts the next group. All transitions advance together
    by ``window`` samples per step, and the running sums are sequential cumulative sums
    seeded with the group's sums so far: they repeat, in the same order, the additions of a
    sample-by-sample loop (test_gyro_rotations_fast keeps it as the reference), so the groups are
    identical to it bit for bit.
    """
    k = len(increments)
    lens = np.array([len(x) for x in increments], int)
    pad = np.zeros((k, (max(lens) if k else 0) + window, 3))
    for j, x in enumerate(increments):
        pad[j, :len(x)] = x
    lim2 = MERGE_COMMUTATOR ** 2
    starts = [[0] for _ in range(k)]
    pos = np.ones(k, int)                  # next sample to append
    s = pad[:, 0].copy()                   # group sum before it
    e = np.zeros((k, 3))                   # group commutator before it
    offs = np.arange(window)
    a, b = [1, 2, 0], [2, 0, 1]            # (S x theta)_i = S_a theta_b - S_b theta_a
    act = np.flatnonzero(pos < lens)
    while len(act):
        idx = pos[act, None] + offs
        th = pad[act[:, None], idx]                                        # (m, w, 3)
        ss = np.cumsum(np.concatenate([s[act, None], th], axis=1), axis=1)
        sp = ss[:, :-1]
        c = 0.5 * (sp[..., a] * th[..., b] - sp[..., b] * th[..., a])
        ee = np.cumsum(np.concatenate([e[act, None], c], axis=1), axis=1)[:, 1:]
        n2 = ee[..., 0] * ee[..., 0] + ee[..., 1] * ee[..., 1] + ee[..., 2] * ee[..., 2]
        over = (n2 > lim2) & (idx < lens[act, None])
        hit = over.any(axis=1)
        first = np.argmax(over, axis=1)
        for j, f in zip(act[hit], first[hit]):
            starts[j].append(int(pos[j] + f))
        rows = np.arange(len(act))
        s[act] = np.where(hit[:, None], th[rows, first], ss[:, -1])
        e[act] = np.where(hit[:, None], 0.0, ee[:, -1])
        pos[act] = np.where(hit, pos[act] + first + 1, pos[act] + window)
        act = act[pos[act] < lens[act]]
    return [np.array(x) for x in starts]


def _merge_commuting(parts):
    """Sum runs of increments whose composition is their sum to 1e-7 rad, per transition.

    parts: one (b, c2, c3, cone) tuple of (n_t, 3) arrays per transition; the groups come
    from b (``_group_starts``, all transitions at once) and apply to all four.
    """
    return [tuple(np.add.reduceat(x, starts, axis=0) for x in p)
            for p, starts in zip(parts, _group_starts([p[0] for p in parts]))]


def _motion_extent(t, d, noise):
    """Return the sample slice of a transition that holds its motion (plus a margin).

    Outside it the unit is still (the detector guard), so its true rotation is zero and
    integrating it would only add angle random walk. ``noise``: per-sample rate std.
    """
    n = len(t)
    if noise is None or n < 8:
        return slice(0, n)
    dt = float(np.median(np.diff(t)))
    k = max(3, int(round(0.1 / max(dt, 1e-6))))
    mag = np.sqrt(sum_sq(d))                   # np.linalg.norm(d, axis=1), bit for bit
    smooth = np.convolve(mag, np.ones(k) / k, mode='same')
    moving = np.flatnonzero(smooth > MOTION_SIGMAS * float(np.mean(noise)) / np.sqrt(k)
                            + float(np.mean(noise)) * np.sqrt(2.0 / np.pi))
    if len(moving) == 0:
        return slice(0, n)
    lo = np.searchsorted(t, t[moving[0]] - MOTION_MARGIN_S)
    hi = np.searchsorted(t, t[moving[-1]] + MOTION_MARGIN_S, side='right')
    return slice(int(lo), int(max(hi, lo + 2)))


def prepare_transitions(transitions, hold_up, hold_sigma, static, accel_model, accel_input,
                        gyro_input, t0g, gyro_noise=None):
    """Precompute the static-compensated, integrated raw rates of each usable transition.

    hold_up: dict hold id -> unit up (3,); hold_sigma: dict hold id -> direction std (rad).
    static: StaticGyroFit; accel_model corrects the transition's specific force (g-sensitivity
    during motion). Transitions between unknown holds are skipped.
    """
    rows = []
    for i, tr in enumerate(transitions):
        if tr.hold_from not in hold_up or tr.hold_to not in hold_up or len(tr.t) < 3:
            continue
        temps = np.asarray(tr.temps, float)
        ta = np.broadcast_to(temps[list(accel_input)] if temps.size else accel_model.t0,
                             (len(tr.t), 3))
        xg = temps[list(gyro_input)] if temps.size else np.asarray(t0g, float)
        a = accel_model.correct(tr.accel, ta)
        dxg = xg - t0g
        c = np.zeros(3)
        for row in static.offset[::-1]:
            c = c * dxg + row
        w = tr.gyro - c
        d = w - static.beta - a @ static.g.T
        keep = _motion_extent(tr.t, d, gyro_noise)
        tt, d, w = tr.t[keep], d[keep], w[keep]
        dt = np.diff(tt)
        closed = bool(tr.closed) or is_full_turn(d, dt, hold_up[tr.hold_from],
                                                 hold_up[tr.hold_to])
        # within-interval coning of a linearly varying rate (Bortz): dt^2/12 w_a x w_b,
        # evaluated with the prior scale (its Omega1 dependence is second order)
        cone = cross(d[:-1], d[1:]) * (dt ** 2 / 12.0)[:, None]
        rows.append([i, tr, _trapezoid(d, dt), _trapezoid(w * w, dt), _trapezoid(w ** 3, dt),
                     cone, dt, closed])
    for r, merged in zip(rows, _merge_commuting([tuple(r[2:6]) for r in rows])):
        r[2:6] = merged
    k = len(rows)
    n = max([len(r[2]) for r in rows], default=1)
    b = np.zeros((k, n, 3))
    c2 = np.zeros((k, n, 3))
    c3 = np.zeros((k, n, 3))
    c0 = np.zeros((k, n, 3))
    uf, ut, sg, cl, idx = [], [], [], [], []
    for j, (i, tr, bb, cc2, cc3, cc, dt, closed) in enumerate(rows):
        b[j, :len(bb)], c2[j, :len(bb)], c3[j, :len(bb)], c0[j, :len(bb)] = bb, cc2, cc3, cc
        uf.append(hold_up[tr.hold_from])
        ut.append(hold_up[tr.hold_to])
        gn = 0.0 if gyro_noise is None else \
            float(np.mean(gyro_noise)) * np.sqrt(np.sum(dt ** 2))
        sg.append(np.sqrt(hold_sigma[tr.hold_from] ** 2 + hold_sigma[tr.hold_to] ** 2
                          + gn ** 2 + 1e-12))
        cl.append(closed)
        idx.append(i)
    return PreparedTransitions(b, c2, c3, np.array(uf).reshape(k, 3),
                               np.array(ut).reshape(k, 3), np.array(sg), np.array(cl, bool),
                               idx, c0)
