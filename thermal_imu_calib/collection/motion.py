"""Pose changes between holds, collected while data streams (live or offline).

The rotation part of the gyro fit needs raw samples between holds.
:class:`MotionCollector` wraps the stationary detector and keeps only those: a
ring of the last ``lookback_s`` seconds, and from the end of each hold a *tape*
of gyro + accel samples that freezes as soon as the detector sees the next still
period (so a long hold costs nothing) and is abandoned when a pose change lasts
longer than ``max_transition_s``. Memory: 7 float64 per sample (56 bytes): at
most ``rate x (lookback_s + max_transition_s)`` samples in flight plus the kept
transitions (each at most ``rate x max_transition_s`` samples, at most
``max_transitions`` of them): 200 Hz, 20 s + 30 s, 100 transitions of ~4 s ->
~0.6 MB in flight, ~4.5 MB kept. ``save_transitions``/``load_transitions``
keep them in ``FILE.transitions.npz``.
"""

import dataclasses
from dataclasses import dataclass
from typing import List
import zipfile

import numpy as np

from .segments import Windows
from .stationary import DetectorConfig, StationaryDetector


BYTES_PER_SAMPLE = 56        # t, gyro xyz, accel xyz as float64


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
    """Growing sample columns (t, gyro, accel, temps), kept as a list of appended parts.

    Parts are concatenated only when the samples are needed (``cols``/``select``); while
    the stamps increase, trimming the front drops or slices whole parts (views, no copy).
    """

    #: parts are merged into one once there are more than this many (bounds the list)
    MAX_PARTS = 16

    def __init__(self, k):
        self.k = k
        self.parts = []
        self._n = 0
        self._sorted = True       # stamps non-decreasing over all parts

    def append(self, t, g, a, tm):
        if len(t):
            if self._sorted:
                self._sorted = bool((not self.parts or t[0] >= self.parts[-1][0][-1])
                                    and np.all(t[1:] >= t[:-1]))
            self.parts.append((t, g, a, tm))
            self._n += len(t)
            if len(self.parts) > self.MAX_PARTS:
                self.cols()

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
        return self.parts[-1][0][-1] if self.parts else -np.inf

    def start(self):
        return self.parts[0][0][0] if self.parts else np.inf

    def trim_before(self, lo):
        if not self._sorted:
            t, g, a, tm = self.cols()
            m = t >= lo
            self._n = int(np.count_nonzero(m))
            self.parts = [(t[m], g[m], a[m], tm[m])] if self._n else []
            return
        # non-decreasing stamps: the samples kept (t >= lo) are a suffix
        while self.parts and self.parts[0][0][-1] < lo:
            self._n -= len(self.parts.pop(0)[0])
        if self.parts:
            i = int(np.searchsorted(self.parts[0][0], lo, side='left'))
            if i:
                self.parts[0] = tuple(c[i:] for c in self.parts[0])
                self._n -= i

    def __len__(self):
        return self._n


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
        self._ring.append(t, gyro, accel, temps)
        if len(t) and self.lookback_s is not None:
            # the samples a hold closed later can end in: the detector scores the first
            # group of blocks only when it is complete
            self._ring.trim_before(min(t[0], self.det.unscored_since()) - self.lookback_s)
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
        # too long first: what _after_chunk drops early is counted the same
        if hi - lo > self.max_transition_s:
            self.dropped['too_long'] += 1
            return
        t, g, a, tm = self._segment(lo, hi)
        # the sample interval of the detector's derived rate (one figure for the whole log)
        dt = 1.0 / self.det.derived['rate_hz']
        ok = len(t) >= 3 and t[0] <= lo + 2 * dt + 1e-9 and t[-1] >= hi - 2 * dt - 1e-9
        if ok:
            ok = float(np.max(np.diff(t))) < 5 * dt
        if not ok:
            self.dropped['incomplete'] += 1
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
        if self._prev is not None and \
                self.det.open_since() - self._prev[1] > self.max_transition_s:
            # the next hold starts after the open blocks: the pose change is too long
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
