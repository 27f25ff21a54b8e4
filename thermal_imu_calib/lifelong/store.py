"""Bounded hold store: the recent raw windows plus compacted statistics, kept in a directory.

A *hold* arrives as the stationary windows the detector closed (``collection.segments.
Windows``; statistics, never raw samples). The newest holds are kept as they are
(``recent.jsonl``, JSON lines, appended with fsync). When there are more than
``max_recent_holds`` holds or ``max_recent_windows`` windows, the oldest holds are
compacted: each is put in an *orientation cluster* (gravity directions within
``cluster_deg`` of the cluster's first hold) and each of its windows in a *temperature bin*
(``bin_degc`` wide, first thermal input); per (cluster, bin) the sample-weighted sums of
the means, variances, temperatures and times are kept (``compacted.json``, written
atomically; the time sum ``tsum``, s x samples, gives a bin's mean time for the ageing trend,
``lifelong.ageing``; files written before it load with the bin's newest time instead).
Compacted statistics fade with age (weight x exp(-age / ``memory_days``)): a bias that ages
is followed, and a bin whose weight falls below ``min_weight`` samples is dropped.

Bounds (defaults): at most 300 raw holds / 20000 raw windows (~0.5 kB per window: ~10 MB),
at most ``max_clusters`` x (temperature span / ``bin_degc``) compacted bins (32 x 60 = 1920
rows, ~1 MB); the whole directory stays under ~12 MB and memory under a few MB.

For a fit the compacted bins become windows again: one pseudo-hold per cluster, one
window per bin, ``n`` = the faded weight. Holds
compacted into one cluster share one unknown orientation in the fit: the cluster width
bounds the error this adds (1 - cos(cluster_deg) of g: 1.5e-4 m/s^2 at 0.5 deg).
``cut(t)`` starts a new epoch (after a knock): everything before ``t`` is dropped.
``cut(t, keep=sensor)`` (a knock that moved one sensor only) drops it for the other sensor
alone: the older holds are compacted and kept for ``keep``'s fits (``fit_windows(sensor=
keep)``), at most ``MAX_KEPT`` such histories, those of the sensor that changed dropped.
``shift(t, accel, gyro)`` keeps everything, moved by the step a knock made.
"""

from dataclasses import dataclass, fields
import json
import os

import numpy as np

from ..collection.segments import Windows
from ..io.output import write_atomic

RECENT = 'recent.jsonl'
COMPACTED = 'compacted.json'
COUNTERS = 'counters.json'
#: hold ids of compacted clusters start here (raw hold ids are below)
CLUSTER_BASE = 1_000_000_000
DAY_S = 86400.0
#: most one-sensor histories kept across change alarms (``HoldStore.cut(t, keep=...)``)
MAX_KEPT = 4
#: hold ids of a kept history's clusters start here, one block per history
KEPT_BASE = 100_000


@dataclass
class StoreConfig:
    """Bounds and compaction of the hold store (degC, deg, days, samples)."""

    max_recent_holds: int = 300
    max_recent_windows: int = 20000
    #: compact down to this fraction of the bounds (not one hold at a time)
    compact_to: float = 0.75
    bin_degc: float = 1.0
    cluster_deg: float = 0.5
    max_clusters: int = 32
    #: time constant of the fading of compacted statistics (days); 0: never fade
    memory_days: float = 14.0
    min_weight: float = 10.0


class _Bins:
    """Sample-weighted sums per (cluster, temperature bin), as arrays (one row per bin)."""

    SUMS = ('w', 'accel', 'gyro', 'accel_var', 'gyro_var', 'temp', 'temp_rate', 'seconds',
            'tsum')

    def __init__(self, k):
        self.k = k
        self.cluster = np.zeros(0, int)
        self.bin = np.zeros(0, int)
        self.ref = np.zeros(0)            # time (s) the sums were last faded to
        self.t1 = np.zeros(0)             # newest window end (s)
        self.w = np.zeros(0)
        self.accel, self.gyro = np.zeros((0, 3)), np.zeros((0, 3))
        self.accel_var, self.gyro_var = np.zeros((0, 3)), np.zeros((0, 3))
        self.temp, self.temp_rate = np.zeros((0, k)), np.zeros((0, k))
        self.seconds = np.zeros(0)
        self.tsum = np.zeros(0)           # sample-weighted sum of window mid times (s)

    def __len__(self):
        return len(self.cluster)

    def fade(self, now, days):
        """Fade the sums to time ``now`` (s) with time constant ``days``."""
        if not len(self) or days <= 0:
            self.ref = np.maximum(self.ref, now) if len(self) else self.ref
            return
        f = np.exp(-np.clip(now - self.ref, 0, None) / (days * DAY_S))
        for name in self.SUMS:
            arr = getattr(self, name)
            setattr(self, name, arr * f.reshape((-1,) + (1,) * (arr.ndim - 1)))
        self.ref = np.maximum(self.ref, now)

    def add(self, cluster, win, bin_degc):
        """Add the windows of one hold (all in ``cluster``)."""
        b = (np.floor(win.temp[:, 0] / bin_degc).astype(int) if self.k
             else np.zeros(len(win), int))
        n = win.n.astype(float)
        for key in np.unique(b):
            m = b == key
            rows = np.flatnonzero((self.cluster == cluster) & (self.bin == key))
            if len(rows):
                i = int(rows[0])
            else:
                i = len(self)
                self._append(cluster, int(key), float(win.t1[m].max()))
            nm = n[m]
            self.w[i] += nm.sum()
            self.accel[i] += nm @ win.accel[m]
            self.gyro[i] += nm @ win.gyro[m]
            self.accel_var[i] += nm @ win.accel_var[m]
            self.gyro_var[i] += nm @ win.gyro_var[m]
            self.temp[i] += nm @ win.temp[m]
            self.temp_rate[i] += nm @ win.temp_rate[m]
            self.seconds[i] += float(np.sum(win.t1[m] - win.t0[m]))
            self.tsum[i] += nm @ (0.5 * (win.t0[m] + win.t1[m]))
            self.t1[i] = max(self.t1[i], float(win.t1[m].max()))

    def _append(self, cluster, key, t1):
        self.cluster = np.append(self.cluster, cluster)
        self.bin = np.append(self.bin, key)
        self.ref = np.append(self.ref, t1)
        self.t1 = np.append(self.t1, t1)
        for name in self.SUMS:
            arr = getattr(self, name)
            setattr(self, name, np.concatenate([arr, np.zeros((1,) + arr.shape[1:])]))

    def keep(self, mask):
        """Keep the rows of ``mask``."""
        for name in ('cluster', 'bin', 'ref', 't1') + self.SUMS:
            setattr(self, name, getattr(self, name)[mask])

    def windows(self):
        """Return the bins as Windows: one pseudo-hold per cluster, one window per bin."""
        if not len(self):
            return Windows.empty(self.k)
        w = self.w[:, None]
        n = np.maximum(np.round(self.w), 1).astype(int)
        secs = np.maximum(self.seconds, 1e-3)
        return Windows(CLUSTER_BASE + self.cluster, self.t1 - secs, self.t1.copy(), n,
                       self.accel / w, self.gyro / w, self.accel_var / w, self.gyro_var / w,
                       self.temp / w, self.temp_rate / w)

    def mean_times(self):
        """Return each bin's sample-weighted mean time (s)."""
        return self.tsum / np.maximum(self.w, 1e-300)

    def to_dict(self):
        """Return plain types for JSON."""
        return {name: getattr(self, name).tolist()
                for name in ('cluster', 'bin', 'ref', 't1') + self.SUMS}

    @staticmethod
    def from_dict(d, k):
        """Inverse of ``to_dict``."""
        b = _Bins(k)
        if not d.get('cluster'):
            return b
        for name in ('cluster', 'bin'):
            setattr(b, name, np.asarray(d[name], int))
        for name in ('ref', 't1', 'w', 'seconds'):
            setattr(b, name, np.asarray(d[name], float))
        # files written before the time sum: the bin's newest time stands for its mean
        b.tsum = np.asarray(d['tsum'], float) if 'tsum' in d else b.t1 * b.w
        for name in ('accel', 'gyro', 'accel_var', 'gyro_var'):
            setattr(b, name, np.asarray(d[name], float).reshape(-1, 3))
        for name in ('temp', 'temp_rate'):
            setattr(b, name, np.asarray(d[name], float).reshape(-1, k))
        return b


class HoldStore:
    """The holds of a lifelong collection, bounded, persisted in ``directory`` ('' : memory)."""

    def __init__(self, directory, k, config=None):
        self.dir = os.path.expanduser(directory) if directory else ''
        self.k = int(k)
        self.config = config or StoreConfig()
        self.recent = Windows.empty(self.k)
        self.bins = _Bins(self.k)
        self.clusters = []                # unit gravity-up directions (3,)
        self.next_hold = 0
        self.compacted_through = -1       # raw hold ids <= this are in the bins
        self.total_holds = 0              # holds ever added (this epoch and before)
        self.epoch_start = -np.inf        # s: holds before this were dropped (cut)
        #: [(sensor, _Bins)]: history before a one-sensor cut, still valid for that sensor
        self.kept = []
        self.notes = []
        if self.dir:
            os.makedirs(self.dir, exist_ok=True)
            self._load()

    # ------------------------------------------------------------------ persistence
    def _path(self, name):
        return os.path.join(self.dir, name)

    def _load(self):
        state = {}
        try:
            with open(self._path(COMPACTED)) as f:
                state = json.load(f)
        except FileNotFoundError:
            pass
        except (OSError, ValueError) as e:
            self.notes.append(f'{self._path(COMPACTED)} unreadable ({e}): compacted '
                              'statistics start afresh')
            os.replace(self._path(COMPACTED), self._path(COMPACTED) + '.unreadable')
        if state:
            if int(state.get('k', self.k)) != self.k:
                raise ValueError(f'{self.dir} holds a collection of {state.get("k")} thermal '
                                 f'inputs, this node has {self.k}: give another directory')
            self.bins = _Bins.from_dict(state.get('bins', {}), self.k)
            self.clusters = [np.asarray(c, float) for c in state.get('clusters', [])]
            self.next_hold = int(state.get('next_hold', 0))
            self.compacted_through = int(state.get('compacted_through', -1))
            self.total_holds = int(state.get('total_holds', 0))
            self.epoch_start = float(state.get('epoch_start', -np.inf))
            self.kept = [(str(e['sensor']), _Bins.from_dict(e['bins'], self.k))
                         for e in state.get('kept', [])]
        try:
            with open(self._path(COUNTERS)) as f:
                counters = json.load(f)
            self.total_holds = max(self.total_holds, int(counters.get('total_holds', 0)))
            self.next_hold = max(self.next_hold, int(counters.get('next_hold', 0)))
        except (OSError, ValueError):
            pass
        try:
            with open(self._path(RECENT), 'rb') as f:
                text = f.read().decode('utf-8', 'replace')
        except FileNotFoundError:
            text = ''
        win = Windows.from_jsonl(text, self.k)
        if len(win) and win.n_inputs != self.k:
            raise ValueError(f'{self._path(RECENT)} has {win.n_inputs} thermal inputs, this '
                             f'node {self.k}: give another directory')
        keep = (win.hold > self.compacted_through) & (win.t0 >= self.epoch_start)
        self.recent = win.select(keep) if len(win) else win
        if len(self.recent):
            self.next_hold = max(self.next_hold, int(self.recent.hold.max()) + 1)
        self._write_recent()            # drops a torn last line and compacted holds

    def _state(self):
        return {'k': self.k, 'bins': self.bins.to_dict(),
                'clusters': [c.tolist() for c in self.clusters], 'next_hold': self.next_hold,
                'compacted_through': self.compacted_through, 'total_holds': self.total_holds,
                'epoch_start': None if not np.isfinite(self.epoch_start)
                else self.epoch_start,
                'kept': [{'sensor': w, 'bins': b.to_dict()} for w, b in self.kept]}

    def _write_state(self):
        if self.dir:
            state = self._state()
            if state['epoch_start'] is None:
                state.pop('epoch_start')
            if not state['kept']:
                state.pop('kept')
            write_atomic(self._path(COMPACTED), json.dumps(state, separators=(',', ':')))

    def _write_recent(self):
        if self.dir:
            write_atomic(self._path(RECENT), self.recent.to_jsonl())

    def disk_bytes(self):
        """Return the bytes the store's files take."""
        if not self.dir:
            return 0
        return sum(os.path.getsize(self._path(n)) for n in (RECENT, COMPACTED, COUNTERS)
                   if os.path.exists(self._path(n)))

    # ------------------------------------------------------------------ adding
    def add(self, windows):
        """Add the windows of closed holds (any hold ids); return the new hold ids."""
        if not len(windows):
            return []
        if windows.n_inputs != self.k:
            raise ValueError(f'windows with {windows.n_inputs} thermal inputs, store has '
                             f'{self.k}')
        win = windows.select(np.ones(len(windows), bool))
        first = {}                       # detector id -> order of appearance
        for h in win.hold:
            first.setdefault(int(h), len(first))
        win.hold = np.array([self.next_hold + first[int(h)] for h in win.hold], int)
        self.next_hold += len(first)
        self.total_holds += len(first)
        if self.dir:
            with open(self._path(RECENT), 'a') as f:
                f.write(win.to_jsonl())
                f.flush()
                os.fsync(f.fileno())
        if self.dir:
            write_atomic(self._path(COUNTERS), json.dumps(
                {'total_holds': self.total_holds, 'next_hold': self.next_hold}))
        self.recent = Windows.concat([self.recent, win])
        if self.recent.n_inputs != self.k:      # concat of empty parts loses k
            self.recent = Windows.empty(self.k)
        self._bound()
        return list(range(self.next_hold - len(first), self.next_hold))

    def _bound(self):
        c = self.config
        ids = self.recent.hold_ids
        if len(ids) <= c.max_recent_holds and len(self.recent) <= c.max_recent_windows:
            return
        per_hold = np.array([np.sum(self.recent.hold == h) for h in ids])
        # oldest first until both bounds hold at compact_to of them
        left_w = np.cumsum(per_hold[::-1])[::-1]        # windows from hold i to the newest
        left_h = len(ids) - np.arange(len(ids))
        ok = (left_h <= c.compact_to * c.max_recent_holds) & \
             (left_w <= c.compact_to * c.max_recent_windows)
        first_kept = int(np.argmax(ok)) if ok.any() else len(ids) - 1
        self.compact(ids[:first_kept])

    def compact(self, hold_ids):
        """Move these raw holds into the compacted bins (persisted: state, then recent)."""
        if not len(hold_ids):
            return
        self._absorb(hold_ids)
        self._write_state()
        self._write_recent()

    def _absorb(self, hold_ids):
        """Move these raw holds into the compacted bins in memory (not yet persisted)."""
        if not len(hold_ids):
            return
        now = float(self.recent.t1.max())
        self.bins.fade(now, self.config.memory_days)
        for h in hold_ids:
            m = self.recent.hold == h
            win = self.recent.select(m)
            self.bins.add(self._cluster(win), win, self.config.bin_degc)
        self.bins.keep(self.bins.w >= self.config.min_weight)
        self.compacted_through = max(self.compacted_through, int(np.max(hold_ids)))
        self.recent = self.recent.select(~np.isin(self.recent.hold, hold_ids))

    def _cluster(self, win):
        mean = np.average(win.accel, axis=0, weights=win.n)
        u = mean / np.linalg.norm(mean)
        if self.clusters:
            c = np.array(self.clusters)
            ang = np.degrees(np.arccos(np.clip(c @ u, -1, 1)))
            j = int(np.argmin(ang))
            if ang[j] <= self.config.cluster_deg or len(self.clusters) >= \
                    self.config.max_clusters:
                return j
        self.clusters.append(u)
        return len(self.clusters) - 1

    def cut(self, t, keep=None):
        """Start a new epoch at ``t`` (s): drop the compacted bins and older raw holds.

        ``keep`` ('accel' or 'gyro'): the change touched the other sensor only, so the
        older holds stay valid for ``keep``: they are compacted and kept for its fits
        (``fit_windows(sensor=keep)``), with the histories kept for it before (the oldest
        dropped beyond ``MAX_KEPT``); histories kept for the other sensor are dropped.
        None: everything before ``t`` is dropped, kept histories too.
        """
        old = self._holds_before(t)
        if keep is None:
            self.kept = []
        else:
            self._absorb(old)            # persisted once, below
            self.kept = [(w, b) for w, b in self.kept if w == keep]
            if len(self.bins):
                self.kept = (self.kept + [(keep, self.bins)])[-MAX_KEPT:]
        self.bins = _Bins(self.k)
        self.clusters = []
        self.epoch_start = float(t)
        if len(old):
            self.compacted_through = max(self.compacted_through, int(np.max(old)))
        self.recent = self.recent.select(self.recent.t0 >= t) if len(self.recent) \
            else self.recent
        self._write_state()
        self._write_recent()

    def shift(self, t, accel, gyro, drop=()):
        """Move everything before ``t`` (s) by a step of the biases, instead of dropping it.

        ``accel`` (3,) m/s^2 and ``gyro`` (3,) rad/s are added to the means of the raw
        holds that began before ``t``, the compacted bins and the kept histories (a knock
        steps the offsets, not the thermal sensitivity; ``LifelongConfig.alarm_cut``
        'shift', ``knock_step``); ``drop``: raw hold ids removed (holds that cannot be
        placed before or after ``t``). Persisted: state, then recent.
        """
        a, g = np.asarray(accel, float).reshape(3), np.asarray(gyro, float).reshape(3)
        for bins in [self.bins] + [b for _, b in self.kept]:
            bins.accel = bins.accel + bins.w[:, None] * a
            bins.gyro = bins.gyro + bins.w[:, None] * g
        if len(self.recent) and len(drop):
            self.recent = self.recent.select(~np.isin(self.recent.hold, list(drop)))
        if len(self.recent):
            old = np.isin(self.recent.hold, self._holds_before(t))[:, None]
            self.recent.accel = self.recent.accel + old * a
            self.recent.gyro = self.recent.gyro + old * g
        self._write_state()
        self._write_recent()

    def _holds_before(self, t):
        """Return the ids of the raw holds that began before ``t`` (s)."""
        if not len(self.recent):
            return np.zeros(0, int)
        ids, starts = self.recent.hold_starts()
        return ids[starts < t]

    # ------------------------------------------------------------------ reading
    def windows(self, now=None, exclude=()):
        """Return all the store's windows for a fit (compacted bins faded to ``now``).

        ``exclude``: raw hold ids left out (the held-out holds of the swap gate). Hold ids
        are renumbered 0, 1, ... in order of appearance, compacted clusters (the oldest
        data) first, then the raw holds, oldest first, as a log gives them (small ids in
        time order; the estimators take hold ids in any order).
        """
        return self.fit_windows(now, exclude)[0]

    def has_kept(self, sensor):
        """Return True when history from before a one-sensor cut is kept for ``sensor``."""
        return any(w == sensor and len(b) for w, b in self.kept)

    def _compacted(self, bins, now, base=0):
        """Return (windows, mean times) of a copy of ``bins`` faded to ``now``; ids + base."""
        bins = _Bins.from_dict(bins.to_dict(), self.k)
        if now is not None:
            bins.fade(float(now), self.config.memory_days)
            bins.keep(bins.w >= self.config.min_weight)
        comp = bins.windows()
        if not len(comp):
            return comp, np.zeros(0)
        order = np.lexsort((bins.bin, bins.cluster))
        comp = comp.select(order)
        comp.hold = comp.hold + base
        return comp, bins.mean_times()[order]

    def fit_windows(self, now=None, exclude=(), sensor=None):
        """Return (``windows(now, exclude)``, each window's mean time (s)).

        A raw window's mean time is its middle; a compacted bin's the sample-weighted mean
        of its windows' (its own ``t0``/``t1`` stay the newest window's, as before).
        ``sensor``: also the history kept for that sensor across one-sensor cuts (oldest
        first, before this epoch's), for that sensor's fit only.
        """
        kept = [b for w, b in self.kept if w == sensor] if sensor is not None else []
        parts = [self._compacted(b, now, KEPT_BASE * (i + 1)) for i, b in enumerate(kept)]
        parts.append(self._compacted(self.bins, now))
        raw = self.recent.select(~np.isin(self.recent.hold, list(exclude))) \
            if len(self.recent) else self.recent
        out = Windows.concat([w for w, _ in parts if len(w)] + [raw])
        if not len(out):
            return Windows.empty(self.k), np.zeros(0)
        times = np.concatenate([t for _, t in parts] + [0.5 * (raw.t0 + raw.t1)])
        first = {}
        for h in out.hold:
            first.setdefault(int(h), len(first))
        out.hold = np.array([first[int(h)] for h in out.hold], int)
        return out, times

    def newest_holds(self, count):
        """Return the ids of the newest ``count`` raw holds, oldest first."""
        ids = self.recent.hold_ids if len(self.recent) else np.zeros(0, int)
        return ids[-count:] if count > 0 else ids[:0]

    def holds(self, ids):
        """Return the raw windows of these hold ids."""
        return self.recent.select(np.isin(self.recent.hold, list(ids))) if len(self.recent) \
            else self.recent

    def temperature_span(self):
        """Return (lo, hi) degC of the first input over raw and compacted data, or None."""
        if not self.k:
            return None
        t = [self.recent.temp[:, 0]] if len(self.recent) else []
        if len(self.bins):
            t.append(self.bins.temp[:, 0] / self.bins.w)
        if not t:
            return None
        t = np.concatenate(t)
        return float(t.min()), float(t.max())

    def summary(self):
        """Return counts and sizes (for diagnostics and the bench)."""
        return {'holds_total': self.total_holds,
                'raw_holds': int(len(self.recent.hold_ids)) if len(self.recent) else 0,
                'raw_windows': len(self.recent), 'compacted_bins': len(self.bins),
                'clusters': len(self.clusters), 'disk_bytes': self.disk_bytes(),
                'kept_bins': int(sum(len(b) for _, b in self.kept)),
                'temperature_span': self.temperature_span()}


def store_fields():
    """Return the StoreConfig field names (for parameters)."""
    return [f.name for f in fields(StoreConfig)]
