"""Gyroscope calibration without a turntable: static bias and g-sensitivity, then rotations.

Static part (stationary windows; raw means y_w in rad/s, corrected specific force a_w)::

    y_w = beta + cw(X_w) + G a_w + Omega1^-1 w_earth(hold)          (raw domain)

so that the seed 002 model ``w = Omega0 + Omega1 W + ... + C a`` (models.whole_unit) gets
``Omega0 = -Omega1 beta`` and ``C = -Omega1 G``. The earth rate in the sensor frame is
``W_e (sin(lat) u + cos(lat) (cos(psi) e1 + sin(psi) e2))`` with u the hold's up direction
(from the corrected accelerometer) and e1, e2 spanning its horizontal plane:

* latitude given: the vertical component is removed exactly; the heading psi of each hold
  is unknown, so the horizontal component (fixed magnitude) is a per-hold nuisance angle;
* latitude unknown: the horizontal magnitude becomes one more nuisance (0..W_e), and the
  vertical component ``W_e sin(lat) u`` is indistinguishable from an isotropic
  g-sensitivity (both are proportional to u): it stays in the diagonal of C (at most
  7.4e-6 rad/s per m/s^2), which the notes say.

Rotation part (imu_tk, Tedaldi et al. 2014): between consecutive holds i -> j the
compensated gyro is integrated (quaternions, all transitions at once by a pairwise tree
product) and the gravity direction measured before is carried over and compared with
the one measured after: ``r = u_j - dR' u_i``. Transitions flagged ``closed`` (full turns,
start and end orientation identical, as the Ferraris protocol) add ``rotvec(dR) = 0``.
Unknowns: Omega1 (3x3 scale/misalignment relative to the accelerometer frame) and the
per-axis nonlinearity Omega2, Omega3; observability as in ``whole_unit_fit``. The earth
rate during a 2-4 s pose change (< 3e-4 rad) is neglected.

The rotation part needs raw samples between holds. :class:`MotionCollector` wraps the
stationary detector and keeps only those: a ring of the last ``lookback_s`` seconds, and
from the end of each hold a *tape* of gyro + accel samples that freezes as soon as the
detector sees the next still period (so a long hold costs nothing) and is abandoned when
a pose change lasts longer than ``max_transition_s``. Memory: 7 float64 per sample
(56 bytes): at most ``rate x (lookback_s + max_transition_s)`` samples in flight plus the
kept transitions (each at most ``rate x max_transition_s`` samples, at most
``max_transitions`` of them): 200 Hz, 20 s + 30 s, 100 transitions of ~4 s -> ~0.6 MB in
flight, ~4.5 MB kept.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional
import zipfile

import numpy as np

from ..models.whole_unit import WholeUnitGyroModel
from .outliers import robust_scale
from .segments import Windows
from .stationary import DetectorConfig, StationaryDetector
from .whole_unit_fit import (CONVENTION, decide_determined, DETERMINED_RATIO, fit_free, Layout,
                             Priors)

EARTH_RATE = 7.2921150e-5    # rad/s, WGS84
BYTES_PER_SAMPLE = 56        # t, gyro xyz, accel xyz as float64


# ------------------------------------------------------------------------ quaternions
def quat_from_rotvec(v):
    """Return (..., 4) unit quaternions (w, x, y, z) for rotation vectors (..., 3), rad."""
    v = np.asarray(v, float)
    th = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * th
    small = th < 1e-8
    s = np.where(small, 0.5 - th * th / 48.0, np.sin(half) / np.where(small, 1.0, th))
    return np.concatenate([np.cos(half), s * v], axis=-1)


def quat_mul(p, q):
    """Return the Hamilton product p q of (..., 4) quaternions."""
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def quat_rotate_inverse(q, v):
    """Return R(q)' v: vectors (..., 3) expressed in the rotated frame."""
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    vq = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return quat_mul(quat_mul(qc, vq), q)[..., 1:]


def quat_to_rotvec(q):
    """Return rotation vectors (..., 3) of unit quaternions (..., 4) (angle <= pi)."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return scale * q[..., 1:]


def integrate_batch(increments):
    """Return the ordered products of rotation-vector increments, one per row.

    increments: (k, n, 3) body-frame rotation vectors (zero-padded rows are identities);
    returns (k, 4) quaternions of dR = exp(inc_0) exp(inc_1) ... exp(inc_{n-1}).
    """
    q = quat_from_rotvec(increments)
    n = q.shape[1]
    size = 1 << max(int(np.ceil(np.log2(max(n, 1)))), 0)
    if size > n:
        pad = np.zeros((q.shape[0], size - n, 4))
        pad[..., 0] = 1.0
        q = np.concatenate([q, pad], axis=1)
    while q.shape[1] > 1:
        q = quat_mul(q[:, 0::2], q[:, 1::2])
    return q[:, 0] / np.linalg.norm(q[:, 0], axis=-1, keepdims=True)


def rate_increments(t, omega):
    """Return (n-1, 3) rotation increments of rates omega (n, 3) at times t (trapezoid)."""
    dt = np.diff(np.asarray(t, float))
    return 0.5 * (omega[1:] + omega[:-1]) * dt[:, None]


def integrate_rotation(t, omega):
    """Return the rotation vector (3,) of dR for body rates omega (n, 3) rad/s at times t s."""
    inc = rate_increments(t, np.asarray(omega, float))
    return quat_to_rotvec(integrate_batch(inc[None]))[0]


# ------------------------------------------------------------------------ collector
@dataclass
class Transition:
    """Raw samples of one pose change between two consecutive holds."""

    hold_from: int
    hold_to: int
    t: np.ndarray            # (n,) s, from the end of hold_from to the start of hold_to
    gyro: np.ndarray         # (n, 3) raw rad/s
    accel: np.ndarray        # (n, 3) raw m/s^2
    temps: np.ndarray        # (k,) mean thermal inputs over the transition
    #: start and end orientation are the same (full turns, e.g. a Ferraris 360 deg rotation)
    closed: bool = False

    @property
    def duration(self):
        """Return the length in seconds."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0


class _Tape:
    """Growing sample columns (t, gyro, accel, temps)."""

    def __init__(self, k):
        self.k = k
        self.parts = []

    def append(self, t, g, a, tm):
        if len(t):
            self.parts.append((t, g, a, tm))

    def cols(self):
        if not self.parts:
            return (np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, self.k)))
        if len(self.parts) > 1:
            self.parts = [tuple(np.concatenate(c) for c in zip(*self.parts))]
        return self.parts[0]

    def select(self, lo, hi=np.inf):
        t, g, a, tm = self.cols()
        m = (t >= lo) & (t <= hi)
        return t[m], g[m], a[m], tm[m]

    def end(self):
        t = self.cols()[0]
        return t[-1] if len(t) else -np.inf

    def start(self):
        t = self.cols()[0]
        return t[0] if len(t) else np.inf

    def trim_before(self, lo):
        t, g, a, tm = self.cols()
        m = t >= lo
        self.parts = [(t[m], g[m], a[m], tm[m])]

    def __len__(self):
        return len(self.cols()[0])


class MotionCollector:
    """Stationary detector plus the raw samples of the pose changes between holds.

    Feed chunks with ``update`` (same arguments as ``StationaryDetector.update``); closed
    holds come back as Windows, pose changes accumulate in ``transitions``. See the module
    docstring for the memory bound.
    """

    def __init__(self, config=None, n_inputs=0, max_transition_s=30.0, lookback_s=None,
                 max_transitions=500):
        self.config = config or DetectorConfig()
        self.det = StationaryDetector(self.config, n_inputs)
        self.k = n_inputs
        # with derived detector settings: set once the detector has derived them
        self.lookback_s = None if lookback_s is None else float(lookback_s)
        self.max_transition_s = float(max_transition_s)
        self.max_transitions = int(max_transitions)
        self.transitions: List[Transition] = []
        self.dropped = {'too_long': 0, 'incomplete': 0, 'over_limit': 0}
        self._ring = _Tape(n_inputs)
        self._tape = None              # samples since the end of the previous hold
        self._prev = None              # (hold id, t1) of the previous hold
        self._frozen = False
        self._dt = None

    def memory_bytes(self):
        """Return the bytes held in sample buffers now (ring, tape, kept transitions)."""
        n = len(self._ring) + (len(self._tape) if self._tape is not None else 0)
        n += sum(len(tr.t) for tr in self.transitions)
        return n * (BYTES_PER_SAMPLE + 8 * self.k)

    def update(self, t, accel, gyro, temps=None):
        """Add samples (s, m/s^2, rad/s, (n, k) inputs); return the holds closed now."""
        t = np.asarray(t, float)
        accel = np.asarray(accel, float)
        gyro = np.asarray(gyro, float)
        temps = np.zeros((len(t), self.k)) if temps is None else \
            np.asarray(temps, float).reshape(len(t), self.k)
        if len(t) > 1 and self._dt is None:
            self._dt = float(np.median(np.diff(t)))
        self._ring.append(t, gyro, accel, temps)
        if len(t) and self.lookback_s is not None:
            self._ring.trim_before(t[-1] - self.lookback_s - (t[-1] - t[0]))
        if self._tape is not None and not self._frozen:
            self._tape.append(t, gyro, accel, temps)
        closed = self.det.update(t, accel, gyro, temps)
        self._on_holds(closed)
        self._after_chunk()
        return closed

    def finish(self):
        """Flush the detector (end of the log); return the last holds."""
        closed = self.det.finish()
        self._on_holds(closed)
        self._tape = None
        return closed

    def status(self):
        """Return the detector's status dict (still now, open-hold seconds, noise floor)."""
        return self.det.status()

    def pop_transitions(self):
        """Return the pose changes kept so far and forget them (a caller that stores them).

        They no longer count in ``memory_bytes`` nor towards ``max_transitions``.
        """
        out, self.transitions = self.transitions, []
        return out

    def _on_holds(self, windows):
        if not len(windows):
            return
        for h in windows.hold_ids:
            m = windows.hold == h
            t0, t1 = float(windows.t0[m].min()), float(windows.t1[m].max())
            if self._prev is not None and self._tape is not None:
                self._make(self._prev[0], int(h), self._prev[1], t0)
            self._prev = (int(h), t1)
            self._tape = _Tape(self.k)
            self._tape.append(*self._ring.select(t1))
            self._frozen = False

    def _segment(self, lo, hi):
        parts = [self._tape.select(lo, hi)]
        end = parts[0][0][-1] if len(parts[0][0]) else lo - 1.0
        if end < hi:
            parts.append(self._ring.select(np.nextafter(end, np.inf), hi))
        return tuple(np.concatenate(c) for c in zip(*parts))

    def _make(self, h_from, h_to, lo, hi):
        t, g, a, tm = self._segment(lo, hi)
        dt = self._dt or 0.0
        ok = len(t) >= 3 and t[0] <= lo + 2 * dt + 1e-9 and t[-1] >= hi - 2 * dt - 1e-9
        if ok and dt > 0:
            ok = float(np.max(np.diff(t))) < 5 * dt
        if not ok:
            self.dropped['incomplete'] += 1
            return
        if hi - lo > self.max_transition_s:
            self.dropped['too_long'] += 1
            return
        if len(self.transitions) >= self.max_transitions:
            self.dropped['over_limit'] += 1
            return
        self.transitions.append(Transition(h_from, h_to, t, g, a,
                                           tm.mean(0) if len(tm) else np.zeros(self.k)))

    def _after_chunk(self):
        if self.lookback_s is None and self.det.config is not None:
            c = self.det.config
            self.lookback_s = c.min_hold_s + 2 * c.guard_s + 6 * c.block_s + 2.0
        if self._tape is None:
            return
        st = self.det.status()
        c = self.det.config
        margin = c.guard_s + 2 * c.block_s + 1.0
        if st['stationary'] and st['hold_seconds'] >= margin:
            self._frozen = True
        elif self._frozen and not st['stationary']:
            self._frozen = False
            end = self._tape.end()
            self._tape.append(*self._ring.select(np.nextafter(end, np.inf)))
        if not self._frozen and len(self._tape) and self._prev is not None:
            if self._tape.end() - self._prev[1] > self.max_transition_s + self.lookback_s:
                self.dropped['too_long'] += 1
                self._tape = None
                self._prev = None


def offset_holds(transitions, offset):
    """Return copies of pose changes with ``offset`` added to both hold ids (merging logs)."""
    return [dataclasses.replace(t, hold_from=t.hold_from + offset, hold_to=t.hold_to + offset)
            for t in transitions]


#: ``format`` entry of a transitions file (``save_transitions``)
TRANSITIONS_FORMAT = 'thermal_imu_calib/transitions/1'


def save_transitions(file, transitions):
    """Write pose changes to an ``.npz`` file (path or binary file object).

    One file holds any number of them: per transition the hold ids, ``closed``, the
    thermal inputs (k,) and the sample count; the samples (t s, gyro rad/s, accel m/s^2)
    concatenated.
    """
    trs = list(transitions)
    k = len(np.ravel(trs[0].temps)) if trs else 0
    cat = [np.concatenate([getattr(tr, name) for tr in trs]) if trs else np.zeros(shape)
           for name, shape in (('t', 0), ('gyro', (0, 3)), ('accel', (0, 3)))]
    np.savez(file, format=np.array(TRANSITIONS_FORMAT),
             hold_from=np.array([tr.hold_from for tr in trs], np.int64),
             hold_to=np.array([tr.hold_to for tr in trs], np.int64),
             closed=np.array([tr.closed for tr in trs], bool),
             length=np.array([len(tr.t) for tr in trs], np.int64),
             temps=np.array([np.ravel(tr.temps) for tr in trs], float).reshape(len(trs), k),
             t=cat[0], gyro=cat[1], accel=cat[2])


def load_transitions(file):
    """Read pose changes written by ``save_transitions``; returns a list of Transition.

    Raises ValueError naming what is wrong when the file is not such a file.
    """
    try:
        with np.load(file, allow_pickle=False) as z:
            data = {name: z[name] for name in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f'{file}: not a readable transitions file (not an .npz archive, or '
                         f'damaged: {e.__class__.__name__}); delete it or write it again with '
                         'save_transitions') from None
    missing = {'hold_from', 'hold_to', 'closed', 'length', 'temps', 't', 'gyro',
               'accel'} - set(data)
    if str(data.get('format', '')) != TRANSITIONS_FORMAT or missing:
        raise ValueError(f'{file}: not a transitions file (format '
                         f'{str(data.get("format", "missing"))!r}, expected '
                         f'{TRANSITIONS_FORMAT!r}, missing {sorted(missing) or "nothing"}); '
                         'delete it or write it again with save_transitions')
    ends = np.cumsum(data['length'])
    if len(ends) and ends[-1] != len(data['t']):
        raise ValueError(f'{file}: the sample counts ({int(ends[-1])}) do not match the '
                         f'samples stored ({len(data["t"])}); the file is damaged, delete it')
    out = []
    for i, (lo, hi) in enumerate(zip(ends - data['length'], ends)):
        out.append(Transition(int(data['hold_from'][i]), int(data['hold_to'][i]),
                              data['t'][lo:hi], data['gyro'][lo:hi], data['accel'][lo:hi],
                              data['temps'][i], closed=bool(data['closed'][i])))
    return out


def collect_motion(chunks, config=None, n_inputs=0, **kwargs):
    """Run a MotionCollector over AlignedChunk's; return (Windows, transitions, collector)."""
    col = MotionCollector(config, n_inputs, **kwargs)
    parts = []
    for ch in chunks:
        parts.append(col.update(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps))
    parts.append(col.finish())
    w = Windows.concat(parts) if any(len(p) for p in parts) else Windows.empty(n_inputs)
    return w, col.transitions, col


# ------------------------------------------------------------------------ static fit
def _hold_frames(windows, acc):
    """Return (hold ids, index per window, (h, 3) up, e1, e2) from corrected accel means."""
    ids, inv = np.unique(windows.hold, return_inverse=True)
    up = np.zeros((len(ids), 3))
    np.add.at(up, inv, acc * windows.n[:, None])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    ref = np.eye(3)[np.argmin(np.abs(up), axis=1)]
    e1 = np.cross(up, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(up, e1)
    return ids, inv, up, e1, e2


@dataclass
class StaticGyroFit:
    """Raw-domain static solution: y = beta + cw(X) + G a + Omega1^-1 w_earth."""

    beta: np.ndarray
    offset: np.ndarray                # (no + 1, 3), row 0 = 0 (convention)
    g: np.ndarray                     # (3, 3)
    std: dict
    estimated: dict
    fixed: dict
    ratios: dict
    heading: np.ndarray               # (h,) rad nuisance per hold
    horizontal_fraction: float        # |horizontal earth rate| / W_e used
    residual_rms: float               # rad/s, window means
    outlier_holds: list
    notes: list


def _normal_solve(a, b):
    """Least squares by normal equations with column scaling (small, well-posed systems)."""
    if a.shape[1] == 0:
        return np.zeros(0)
    cs = np.sqrt(np.sum(a * a, axis=0))
    cs[cs == 0] = 1.0
    an = a / cs
    try:
        sol = np.linalg.solve(an.T @ an, an.T @ b)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(an, b, rcond=None)[0]
    return sol / cs


def fit_gyro_static(windows, axis_inputs, acc, t0, latitude=None, omega1=None, priors=None,
                    order=2, ratio=DETERMINED_RATIO, robust=True, k_robust=3.0):
    """Estimate the gyro thermal bias polynomial and g-sensitivity from stationary windows.

    windows: Windows (gyro means rad/s); axis_inputs: (m, 3) thermal inputs or None;
    acc: (m, 3) corrected specific force per window (m/s^2); t0: (3,) input reference;
    latitude: degrees or None; omega1: current 3x3 scale/misalignment (identity if None).

    The model is linear in (beta, cw, G) for fixed headings, and each heading (and the
    horizontal magnitude without latitude) has a closed form for fixed linear parameters,
    so the solver alternates the two (with iteratively reweighted soft-L1 then Cauchy
    weights when ``robust``); observability is decided as in ``whole_unit_fit`` from the
    full Jacobian, headings included as nuisances.
    """
    priors = priors or Priors()
    om1 = np.eye(3) if omega1 is None else np.asarray(omega1, float)
    om1_inv = np.linalg.inv(om1)
    has_x = axis_inputs is not None
    no = order if has_x else 0
    y = np.asarray(windows.gyro, float)
    m = len(y)
    sig = np.sqrt(np.maximum(windows.gyro_var, 1e-30) / windows.n[:, None])
    dx = (np.asarray(axis_inputs, float) - t0) if has_x else np.zeros((m, 3))
    ids, inv, up, e1, e2 = _hold_frames(windows, acc)
    nh = len(ids)
    lat_known = latitude is not None
    s_lat = np.sin(np.radians(latitude)) if lat_known else 0.0
    c_lat = np.cos(np.radians(latitude)) if lat_known else 1.0

    lay = Layout()
    lay.add('beta', (3,), 0.0, priors.gyro_bias)
    lay.add('cw0', (3,), 0.0, 0.0, CONVENTION + ': cw0 = 0, the bias is carried by Omega0 '
            '(exactly redundant)')
    for j in range(1, no + 1):
        lay.add(f'cw{j}', (3,), 0.0, priors.gyro_offset_tc[j - 1])
    lay.add('G', (3, 3), 0.0, priors.g_sensitivity)
    n_lin = lay.size
    lay.add('psi', (nh,), 0.0, np.pi)
    if not lat_known:
        lay.add('mh', (1,), 0.5, 0.5)
    nuis = np.zeros(lay.size, bool)
    nuis[n_lin:] = True

    # linear design per window: (m, 3, n_lin)
    x = np.zeros((m, 3, n_lin))
    x[:, :, lay.slices['beta']] = np.eye(3)
    for j in range(1, no + 1):
        x[:, :, lay.slices[f'cw{j}']] = np.einsum('ij,ni->nij', np.eye(3), dx ** j)
    x[:, :, lay.slices['G']] = np.einsum('ij,nk->nijk', np.eye(3), acc).reshape(m, 3, 9)

    def earth(psi, mh):
        hdir = np.cos(psi)[inv, None] * e1[inv] + np.sin(psi)[inv, None] * e2[inv]
        return EARTH_RATE * (s_lat * up[inv] + mh * hdir) @ om1_inv.T, hdir

    def full_jac(theta, psi, mh):
        """Whitened Jacobian (3m, size) of r = (y - pred) / sigma."""
        jac = np.zeros((m, 3, lay.size))
        jac[:, :, :n_lin] = x
        dpsi = EARTH_RATE * mh * (-np.sin(psi)[inv, None] * e1[inv]
                                  + np.cos(psi)[inv, None] * e2[inv]) @ om1_inv.T
        jac[np.arange(m), :, n_lin + inv] = dpsi
        if not lat_known:
            _, hdir = earth(psi, mh)
            jac[:, :, lay.slices['mh'].start] = EARTH_RATE * hdir @ om1_inv.T
        return (-jac / sig[:, :, None]).reshape(3 * m, lay.size)

    def solve(free_lin, theta0, with_prior, weights_kind):
        """Alternate linear LS and closed-form headings; return (theta, psi, mh, r, w)."""
        idx = np.flatnonzero(free_lin)
        x_free, x_fixed = x[:, :, idx], x[:, :, ~free_lin]  # loop invariants
        theta = theta0.copy()
        psi = np.zeros(nh)
        mh = c_lat if lat_known else 0.5
        wts = np.ones((m, 3))
        stages = ['linear'] if weights_kind == 'linear' else ['linear', 'soft_l1', 'cauchy']
        c = np.inf
        for stage in stages:
            if stage != 'linear':
                r_all = ((y - np.einsum('nik,k->ni', x, theta) - earth(psi, mh)[0])
                         / sig).ravel()
                c = k_robust * max(robust_scale(r_all), 1.0)
            for _ in range(60):
                we, hdir = earth(psi, mh)
                yy = y - we - np.einsum('nik,k->ni', x_fixed, theta[~free_lin])
                r = (yy - np.einsum('nik,k->ni', x_free, theta[idx])) / sig
                if stage == 'soft_l1':
                    wts = 1.0 / np.sqrt(1.0 + (r / c) ** 2)
                elif stage == 'cauchy':
                    wts = 1.0 / (1.0 + (r / c) ** 2)
                sw = np.sqrt(wts) / sig
                a = (x_free * sw[:, :, None]).reshape(3 * m, len(idx))
                b = (yy * sw).ravel()
                if with_prior:
                    sd = lay.std[idx]
                    a = np.vstack([a, np.diag(1.0 / sd)])
                    b = np.r_[b, lay.mean[idx] / sd]
                new = _normal_solve(a, b)
                step = np.max(np.abs(new - theta[idx]) / lay.std[idx]) if len(idx) else 0.0
                theta[idx] = new
                # headings (and horizontal magnitude) in closed form, rate domain
                rr = (y - np.einsum('nik,k->ni', x, theta)) @ om1.T \
                    - EARTH_RATE * s_lat * up[inv]
                ww = np.mean(wts / sig ** 2, axis=1)
                dh = np.zeros((nh, 3))
                np.add.at(dh, inv, rr * ww[:, None])
                psi_new = np.arctan2(np.sum(dh * e2, 1), np.sum(dh * e1, 1))
                if not lat_known:
                    hd = np.cos(psi_new)[:, None] * e1 + np.sin(psi_new)[:, None] * e2
                    wsum = np.zeros(nh)
                    np.add.at(wsum, inv, ww)
                    mh = float(np.clip(np.sum(dh * hd) / (EARTH_RATE * wsum.sum()), 0.0, 1.0))
                dpsi = float(np.max(np.abs(np.angle(np.exp(1j * (psi_new - psi))))))
                psi = psi_new
                if step < 1e-6 and dpsi < 1e-4:
                    break
        r = (y - np.einsum('nik,k->ni', x, theta) - earth(psi, mh)[0]) / sig
        return theta, psi, mh, r, wts, c

    lin_cand = lay.candidates[:n_lin]
    theta1, psi1, mh1, r1, _, _ = solve(lin_cand, lay.mean[:n_lin].copy(), True, 'linear')
    s = max(robust_scale(r1), 1.0)
    chains = [[lay.slices[f'cw{j}'].start + i for j in range(1, no + 1)] for i in range(3)]
    free, ratios = decide_determined(lay, full_jac(theta1, psi1, mh1), s, ratio,
                                     chains=chains, nuisance=nuis)
    theta0 = lay.mean[:n_lin].copy()
    theta0[free[:n_lin]] = theta1[free[:n_lin]]
    theta, psi, mh, r, wts, c = solve(free[:n_lin], theta0, False,
                                      'robust' if robust else 'linear')
    scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
    p = np.r_[theta, psi, [] if lat_known else [mh]]
    idx = np.flatnonzero(free | nuis)
    jf = full_jac(theta, psi, mh)[:, idx] * np.sqrt(wts).ravel()[:, None]
    try:
        cov = np.linalg.pinv(jf.T @ jf) * max(scale, 1.0) ** 2
        sd = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sd = np.full(len(idx), np.nan)
    std = lay.posterior_std(free, idx, sd)
    offset = np.stack([lay.get(p, f'cw{j}') for j in range(no + 1)])
    rw = r * sig
    holds_bad = []
    if robust:
        hold_r = np.array([np.median(np.abs(r[windows.hold == h])) for h in ids])
        holds_bad = [int(h) for h, v in zip(ids, hold_r) if v > 4 * max(scale, 1.0)]
    notes = []
    labels = [lay.label(i) for i in range(lay.size) if not free[i] and not nuis[i]
              and lay.reason[i] and not lay.reason[i].startswith(CONVENTION)]
    if labels:
        notes.append(f'gyroscope {", ".join(labels)} not determined by the static holds: '
                     'fixed at the prior (g-sensitivity needs holds in at least three '
                     'non-coplanar directions; thermal terms a temperature span)')
    if lat_known:
        notes.append(f'gyroscope: earth rate removed at latitude {latitude:g} deg (vertical '
                     'component exactly; horizontal component with an unknown heading per '
                     'hold as a nuisance)')
    else:
        notes.append('gyroscope: no latitude given: the horizontal earth rate is a per-hold '
                     'nuisance of unknown magnitude (<= 7.3e-5 rad/s) and the vertical '
                     'component stays in the diagonal of C (<= 7.4e-6 rad/s per m/s^2); pass '
                     '--latitude to remove it')
    if holds_bad:
        notes.append(f'gyroscope: holds {holds_bad} disagree with the others (down-weighted)')
    est = lay.masks(free)
    fixed = lay.reasons(free)
    for k in ('psi', 'mh'):
        est.pop(k, None)
        fixed.pop(k, None)
    return StaticGyroFit(
        lay.get(p, 'beta'), offset, lay.get(p, 'G'),
        {n: lay.get(std, n) for n in lay.names if n not in ('psi', 'mh')}, est, fixed,
        {lay.label(i): v for i, v in ratios.items() if not nuis[i]},
        psi, float(mh), float(np.sqrt(np.mean(rw ** 2))), holds_bad, notes)


# ------------------------------------------------------------------------ rotation fit
@dataclass
class RotationFit:
    """Omega1 (and Omega2, Omega3) from rotations between holds."""

    omega1: np.ndarray
    omega2: np.ndarray
    omega3: np.ndarray
    std: dict
    estimated: dict
    fixed: dict
    ratios: dict
    used: int
    error_before_deg: np.ndarray     # per transition, with the prior Omega1
    error_after_deg: np.ndarray
    notes: list


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


def _merge_commuting(b, c2, c3, cone):
    """Sum runs of increments whose composition is their sum to 1e-7 rad (one pass)."""
    groups = [0]
    sx = sy = sz = ex = ey = ez = 0.0
    lim2 = MERGE_COMMUTATOR ** 2
    for i, (x, y, z) in enumerate(b.tolist()):
        # commutator added by appending theta_i to the group: 1/2 S x theta_i
        cx, cy, cz = 0.5 * (sy * z - sz * y), 0.5 * (sz * x - sx * z), 0.5 * (sx * y - sy * x)
        nx, ny, nz = ex + cx, ey + cy, ez + cz
        if i and nx * nx + ny * ny + nz * nz > lim2:
            groups.append(i)
            sx, sy, sz, ex, ey, ez = x, y, z, 0.0, 0.0, 0.0
        else:
            sx, sy, sz, ex, ey, ez = sx + x, sy + y, sz + z, nx, ny, nz
    starts = np.array(groups)
    return tuple(np.add.reduceat(x, starts, axis=0) for x in (b, c2, c3, cone))


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
    mag = np.linalg.norm(d, axis=1)
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
        # within-interval coning of a linearly varying rate (Bortz): dt^2/12 w_a x w_b,
        # evaluated with the prior scale (its Omega1 dependence is second order)
        cone = np.cross(d[:-1], d[1:]) * (dt ** 2 / 12.0)[:, None]
        bb, cc2, cc3, cc = _merge_commuting(_trapezoid(d, dt), _trapezoid(w * w, dt),
                                            _trapezoid(w ** 3, dt), cone)
        rows.append((i, tr, bb, cc2, cc3, cc, dt))
    k = len(rows)
    n = max([len(r[2]) for r in rows], default=1)
    b = np.zeros((k, n, 3))
    c2 = np.zeros((k, n, 3))
    c3 = np.zeros((k, n, 3))
    c0 = np.zeros((k, n, 3))
    uf, ut, sg, cl, idx = [], [], [], [], []
    for j, (i, tr, bb, cc2, cc3, cc, dt) in enumerate(rows):
        b[j, :len(bb)], c2[j, :len(bb)], c3[j, :len(bb)], c0[j, :len(bb)] = bb, cc2, cc3, cc
        uf.append(hold_up[tr.hold_from])
        ut.append(hold_up[tr.hold_to])
        gn = 0.0 if gyro_noise is None else \
            float(np.mean(gyro_noise)) * np.sqrt(np.sum(dt ** 2))
        sg.append(np.sqrt(hold_sigma[tr.hold_from] ** 2 + hold_sigma[tr.hold_to] ** 2
                          + gn ** 2 + 1e-12))
        cl.append(bool(tr.closed))
        idx.append(i)
    return PreparedTransitions(b, c2, c3, np.array(uf).reshape(k, 3),
                               np.array(ut).reshape(k, 3), np.array(sg), np.array(cl, bool),
                               idx, c0)


def prefix_products(q):
    """Return inclusive ordered prefix products q_0 ... q_i along axis 1 of (k, n, 4)."""
    q = q.copy()
    s = 1
    n = q.shape[1]
    while s < n:
        q[:, s:] = quat_mul(q[:, :-s], q[:, s:])
        s *= 2
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_matrix(q):
    """Return (..., 3, 3) rotation matrices of unit quaternions (..., 4) (w, x, y, z)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)],
        -2)


def transition_rotations(prep, omega1, omega2, omega3, prefixes=False):
    """Return (k, 4) quaternions dR of every prepared transition (and the prefixes)."""
    theta = prep.b @ np.asarray(omega1).T + omega2 * prep.c2 + omega3 * prep.c3
    if prep.cone is not None:
        theta = theta + prep.cone
    q = quat_from_rotvec(theta)
    if not prefixes:
        return integrate_batch(theta), None
    pre = prefix_products(q)
    return pre[:, -1], pre


def rotation_residuals(prep, omega1, omega2, omega3, want_jac=False):
    """Return (k, 3) residuals u_to - dR' u_from (rad; closure rotvec if closed) [, jac].

    The Jacobian (k, 3, 15) w.r.t. (Omega1 row-major, Omega2, Omega3) uses the
    right-perturbation dR -> dR exp(dphi), dphi = dR' sum_k P_k dtheta_k (P_k prefix
    products), with the small-increment approximation of the SO(3) Jacobian.
    """
    q, pre = transition_rotations(prep, omega1, omega2, omega3, want_jac)
    carried = quat_rotate_inverse(q, prep.u_from)
    r = prep.u_to - carried
    if np.any(prep.closed):
        r[prep.closed] = quat_to_rotvec(q[prep.closed])
    if not want_jac:
        return r
    pm = quat_to_matrix(pre)                                   # (k, n, 3, 3)
    d1 = np.einsum('knia,knb->kiab', pm, prep.b).reshape(-1, 3, 9)
    d2 = np.einsum('knia,kna->kia', pm, prep.c2)
    d3 = np.einsum('knia,kna->kia', pm, prep.c3)
    dphi_start = np.concatenate([d1, d2, d3], axis=2)         # (k, 3, 15)
    rot = quat_to_matrix(q)
    dphi = np.einsum('kji,kjp->kip', rot, dphi_start)          # end frame
    jac = np.cross(dphi, carried[:, :, None], axisa=1, axisb=1, axisc=1)
    if np.any(prep.closed):
        jac[prep.closed] = dphi[prep.closed]
    return r, jac


def direction_error_deg(prep, omega1, omega2=0.0, omega3=0.0):
    """Return (k,) angle between u_to and the carried u_from (deg); closure angle if closed."""
    q, _ = transition_rotations(prep, omega1, omega2, omega3)
    carried = quat_rotate_inverse(q, prep.u_from)
    c = np.clip(np.sum(carried * prep.u_to, axis=1), -1, 1)
    ang = np.degrees(np.arccos(c))
    if np.any(prep.closed):
        ang[prep.closed] = np.degrees(np.linalg.norm(quat_to_rotvec(q[prep.closed]), axis=1))
    return ang


def _subset(prep, rows):
    """Return the prepared transitions selected by a bool mask."""
    return PreparedTransitions(prep.b[rows], prep.c2[rows], prep.c3[rows], prep.u_from[rows],
                               prep.u_to[rows], prep.sigma[rows], prep.closed[rows],
                               [i for i, r in zip(prep.index, rows) if r],
                               None if prep.cone is None else prep.cone[rows])


def _select_rotation_terms(lay, free, p1, prep, solve_rows, k, tol=0.01):
    """Drop Omega3, then Omega2, unless leave-pose-changes-out validation supports them."""
    if k < 6:
        return free, {}
    folds = np.arange(k) % min(5, k)

    def cv_error(fr):
        err = 0.0
        for f in np.unique(folds):
            test = folds == f
            p = solve_rows(fr, p1, ~test)
            r = rotation_residuals(_subset(prep, test), lay.get(p, 'Omega1'),
                                   lay.get(p, 'Omega2'), lay.get(p, 'Omega3'))
            err += float(np.sum((r / prep.sigma[test, None]) ** 2))
        return err / k

    current = free.copy()
    best = cv_error(current)
    scores = {'all determined': best}
    for g in ('Omega3', 'Omega2'):
        i = np.arange(lay.slices[g].start, lay.slices[g].stop)
        i = i[current[i]]
        if not len(i):
            continue
        fr = current.copy()
        fr[i] = False
        e = cv_error(fr)
        scores[f'without {g}'] = e
        if e <= best * (1.0 + tol):
            current = fr
            best = min(best, e)
            for j in i:
                lay.reason[j] = ('determined, but leave-pose-changes-out validation does not '
                                 'support it: fixed at its prior')
        else:
            break
    return current, scores


def fit_gyro_rotations(prep, priors=None, omega1_prior=None, ratio=DETERMINED_RATIO,
                       robust=True, select=True):
    """Estimate Omega1 (and, when determined, Omega2/Omega3) from prepared transitions.

    ``select``: keep the nonlinear terms only when leave-pose-changes-out validation
    supports them (as the accelerometer's optional terms).
    """
    priors = priors or Priors()
    lay = Layout()
    std1 = np.full((3, 3), priors.gyro_misalignment)
    np.fill_diagonal(std1, priors.gyro_scale)
    lay.add('Omega1', (3, 3), np.eye(3) if omega1_prior is None else omega1_prior, std1)
    lay.add('Omega2', (3,), 0.0, priors.gyro_nonlin2)
    lay.add('Omega3', (3,), 0.0, priors.gyro_nonlin3)
    k = len(prep.sigma)
    before = direction_error_deg(prep, lay.get(lay.mean, 'Omega1')) if k else np.zeros(0)

    def residuals_of(pr):
        def resid(p, want_jac=False):
            out = rotation_residuals(pr, lay.get(p, 'Omega1'), lay.get(p, 'Omega2'),
                                     lay.get(p, 'Omega3'), want_jac)
            if not want_jac:
                return (out / pr.sigma[:, None]).ravel()
            r, j = out
            return ((r / pr.sigma[:, None]).ravel(),
                    (j / pr.sigma[:, None, None]).reshape(-1, lay.size))
        return resid

    resid = residuals_of(prep)

    def solve(free, base, with_prior, use_robust):
        return fit_free(resid, lay.std, base, free, with_prior, use_robust, max_nfev=100)

    def solve_rows(free, base, rows):
        """Plain least squares of the free parameters on a subset of transitions."""
        return fit_free(residuals_of(_subset(prep, rows)), lay.std, base, free, tight=False,
                        max_nfev=50)[0]

    if k < 2:
        free = np.zeros(lay.size, bool)
        for i in range(lay.size):
            lay.reason[i] = ('no rotations between holds were collected: fixed at the prior'
                             if k == 0 else 'one rotation cannot determine it: fixed at the '
                             'prior')
        ratios = {}
        p = lay.mean.copy()
        std = lay.std.copy()
        notes = ['gyroscope scale factor and misalignment (Omega1) not estimated: '
                 f'{k} usable pose changes between holds (need several, about different '
                 'axes)']
        after = before
    else:
        p1, _ = solve(lay.candidates, lay.mean, True, False)
        r1, j1 = resid(p1, True)
        s = max(robust_scale(r1), 1.0)
        free, ratios = decide_determined(lay, j1, s, ratio,
                                         chains=[[9 + i, 12 + i] for i in range(3)])
        cv = {}
        if select:
            free, cv = _select_rotation_terms(lay, free, p1, prep, solve_rows, k)
        p0 = lay.mean.copy()
        p0[free] = p1[free]
        p, res = solve(free, p0, False, robust)
        r, jf = resid(p, True)
        scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
        jf = jf[:, free]
        std = np.where(free, 0.0, lay.std)
        try:
            cov = np.linalg.pinv(jf.T @ jf) * max(scale, 1.0) ** 2
            std[free] = np.sqrt(np.maximum(np.diag(cov), 0))
        except np.linalg.LinAlgError:
            std[free] = np.nan
        after = direction_error_deg(prep, lay.get(p, 'Omega1'), lay.get(p, 'Omega2'),
                                    lay.get(p, 'Omega3'))
        notes = []
        by_cv = [lay.label(i) for i in range(lay.size) if not free[i]
                 and (lay.reason[i] or '').startswith('determined, but')]
        labels = [lay.label(i) for i in range(lay.size) if not free[i]
                  and lay.label(i) not in by_cv]
        if labels:
            notes.append(f'gyroscope {", ".join(labels)} not determined by the {k} pose '
                         'changes: fixed at the prior (scale needs rotations about each axis; '
                         'nonlinearity needs fast ones)')
        if by_cv:
            notes.append(f'gyroscope {", ".join(by_cv)}: determined, but held-out pose changes '
                         'do not support it (leave-pose-changes-out validation): fixed at the '
                         'prior')
    return RotationFit(lay.get(p, 'Omega1'), lay.get(p, 'Omega2'), lay.get(p, 'Omega3'),
                       {n: lay.get(std, n) for n in lay.names}, lay.masks(free),
                       lay.reasons(free), {lay.label(i): v for i, v in ratios.items()}, k,
                       before, after, notes)


# ------------------------------------------------------------------------ both
@dataclass
class GyroFit:
    """The whole-unit gyro model plus what was learnt on the way."""

    model: WholeUnitGyroModel
    static: StaticGyroFit
    rotation: Optional[RotationFit]
    notes: list
    stats: dict


def hold_directions(windows, acc):
    """Return dicts hold -> unit up (corrected accel) and hold -> direction std (rad)."""
    ids, inv, up, _, _ = _hold_frames(windows, acc)
    g = np.linalg.norm(acc, axis=1)
    var = np.zeros(len(ids))
    n = np.zeros(len(ids))
    np.add.at(var, inv, np.mean(windows.accel_var, axis=1) * windows.n)
    np.add.at(n, inv, windows.n)
    gm = np.zeros(len(ids))
    np.add.at(gm, inv, g * windows.n)
    gm /= n
    sig = np.sqrt(var / n / n) / gm
    return ({int(h): up[j] for j, h in enumerate(ids)},
            {int(h): float(sig[j]) for j, h in enumerate(ids)})


def fit_gyro(windows, axis_inputs, acc, t0, latitude=None, transitions=None, accel_model=None,
             accel_input=(0, 0, 0), gyro_input=(0, 0, 0), priors=None, order=2,
             input_unit='degC', robust=True):
    """Fit the seed 002 gyro model: static bias/g-sensitivity, then rotations, then static again.

    windows, axis_inputs (m, 3) or None, acc (m, 3) corrected accel per window (m/s^2),
    t0 (3,) input reference; transitions from MotionCollector (None: no rotation part).
    """
    priors = priors or Priors()
    st = fit_gyro_static(windows, axis_inputs, acc, t0, latitude, None, priors, order,
                         robust=robust)
    rot = None
    omega1, omega2, omega3 = np.eye(3), np.zeros(3), np.zeros(3)
    notes = list(st.notes)
    if transitions and accel_model is not None:
        up, sig = hold_directions(windows, acc)
        noise = np.sqrt(np.median(windows.gyro_var, axis=0))
        prep = prepare_transitions(transitions, up, sig, st, accel_model, accel_input,
                                   gyro_input, np.asarray(t0, float), noise)
        rot = fit_gyro_rotations(prep, priors, robust=robust)
        omega1, omega2, omega3 = rot.omega1, rot.omega2, rot.omega3
        notes += rot.notes
        if np.any(rot.estimated['Omega1']):
            st = fit_gyro_static(windows, axis_inputs, acc, t0, latitude, omega1, priors,
                                 order, robust=robust)
    else:
        rot = fit_gyro_rotations(prepare_transitions([], {}, {}, st, None, (), (), t0),
                                 priors)
        notes += rot.notes
    # raw-domain bias in cw0 (Omega0 = 0 by convention), C = -Omega1 G
    offset = st.offset.copy()
    offset[0] = st.beta
    c = -omega1 @ st.g
    std = dict(st.std)
    std['cw0'] = std.pop('beta')
    std['Omega0'] = np.zeros(3)
    std['C'] = std.pop('G')
    std.update(rot.std)
    est = dict(st.estimated)
    est['cw0'] = est.pop('beta')
    est['Omega0'] = np.zeros(3, bool)
    est['C'] = est.pop('G')
    est.update(rot.estimated)
    fixed = dict(st.fixed)
    fixed.pop('cw0', None)
    if 'beta' in fixed:
        fixed['cw0'] = fixed.pop('beta')
    if 'G' in fixed:
        fixed['C'] = fixed.pop('G')
    fixed['Omega0'] = (CONVENTION + ': Omega0 = 0, the bias is carried by cw0 (raw domain; '
                       'exactly redundant)')
    fixed.update(rot.fixed)
    model = WholeUnitGyroModel(t0, offset, None, np.zeros(3), omega1, omega2, omega3, c,
                               std=std, estimated=est, fixed=fixed, input_unit=input_unit,
                               convention='Omega1 full 3x3: gyro axes relative to the '
                                          'accelerometer frame')
    stats = {'gyro_static_residual_rms': {'value': st.residual_rms, 'unit': 'rad/s'},
             'gyro_outlier_holds': st.outlier_holds,
             'gyro_posterior_ratio': {**st.ratios, **(rot.ratios if rot else {})},
             'earth_rate_horizontal_fraction': st.horizontal_fraction,
             'rotations_used': rot.used if rot else 0}
    if rot is not None and rot.used:
        stats['rotation_direction_error_deg'] = {
            'before_rms': float(np.sqrt(np.mean(rot.error_before_deg ** 2))),
            'after_rms': float(np.sqrt(np.mean(rot.error_after_deg ** 2))),
            'note': 'angle between the gravity direction after a pose change and the one '
                    'before carried through the integrated gyro (prior vs fitted Omega1)'}
    return GyroFit(model, st, rot, notes, stats)
