"""Resolve temperature inputs at IMU header stamps (shared by the CLI and the live node).

All times are header stamps (int64 ns); log/receive times play no part in the values.

What happens at gaps, exactly:

* Between two samples of one input whose stamps are at most ``max_gap_s`` apart, the value
  is linearly interpolated and its age is 0.
* Where the bracketing samples are further apart than ``max_gap_s``, or the IMU stamp lies
  before the first / after the last sample, the *nearest* sample (by stamp) is held and
  its age is the distance to it in seconds.  A stamp equal to a sample's gets that sample
  with age 0.
* With no sample at all the value is NaN and the age ``inf``.
* Non-finite temperature samples are dropped on ``add`` (a NaN reading is no reading);
  duplicate stamps keep the last value added; out-of-order samples are sorted in.

:meth:`TemperatureTrack.latest` is the causal variant for live use: the newest sample
stamped at or before the IMU stamp is held (age = distance), falling back to the oldest
sample when all are later.

:class:`StreamAligner` (offline, with look-ahead) emits an IMU row once every input has a
sample stamped at or after it, so the bracket is complete and the result equals
``interpolate`` over the whole log.  Two exceptions, to keep memory bounded: a row is also
released once the IMU stream has advanced more than ``max_wait_s`` past it while some input
stayed silent (a dropout longer than ``max_wait_s``, or a dead input: the nearest sample
*received so far* is held, so rows in the second half of such a dropout get the older
neighbour instead of the newer one), and at :meth:`StreamAligner.finish` every remaining
row is released the same way.  Rows leave in the order they came in; at most about
``max_wait_s`` of IMU data (plus one chunk) is held back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from .columns import AlignedChunk, ImuColumns, TemperatureColumns

NS = 1_000_000_000


class TemperatureTrack:
    """Bounded, stamp-sorted sample history of one temperature input."""

    def __init__(self, max_history_s: float = 60.0):
        """Keep samples up to ``max_history_s`` older than the newest (plus one bracket)."""
        if not max_history_s > 0:
            raise ValueError(f'max_history_s must be > 0 (got {max_history_s}); pass the '
                             'number of seconds of history to keep, or math.inf.')
        self.max_history_s = float(max_history_s)
        self._t = np.zeros(0, np.int64)
        self._v = np.zeros(0)

    def __len__(self):
        return int(self._t.size)

    @property
    def stamps_ns(self) -> np.ndarray:
        """Stamps of the retained samples (sorted, read-only view)."""
        return self._t

    @property
    def values(self) -> np.ndarray:
        """Values of the retained samples, degC."""
        return self._v

    @property
    def newest_ns(self) -> int | None:
        """Stamp of the newest retained sample, or None when empty."""
        return int(self._t[-1]) if self._t.size else None

    def add(self, stamp_ns, values) -> None:
        """Add one sample or arrays of samples (stamps in ns, values in degC)."""
        t = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
        v = np.atleast_1d(np.asarray(values, dtype=np.float64))
        if t.shape != v.shape or t.ndim != 1:
            raise ValueError(f'stamp_ns {t.shape} and values {v.shape} must be matching scalars '
                             'or 1-d arrays; pass one value per stamp.')
        keep = np.isfinite(v)
        t, v = t[keep], v[keep]
        if t.size == 0:
            return
        if (self._t.size == 0 or t[0] > self._t[-1]) and np.all(np.diff(t) > 0):
            self._t = np.concatenate([self._t, t])
            self._v = np.concatenate([self._v, v])
        else:
            allt = np.concatenate([self._t, t])
            allv = np.concatenate([self._v, v])
            order = np.argsort(allt, kind='stable')
            allt, allv = allt[order], allv[order]
            last = np.append(allt[1:] != allt[:-1], True)  # last of each equal-stamp run
            self._t, self._v = allt[last], allv[last]
        if math.isfinite(self.max_history_s):
            self.discard_before(int(self._t[-1]) - int(self.max_history_s * NS))

    def clear(self) -> None:
        """Forget every sample (the stamps jumped backwards: a new recording or clock)."""
        self._t = np.zeros(0, np.int64)
        self._v = np.zeros(0)

    def discard_before(self, stamp_ns: int) -> None:
        """Drop samples older than ``stamp_ns``, keeping the newest of them as a bracket."""
        i = int(np.searchsorted(self._t, stamp_ns, side='left')) - 1
        if i > 0:
            self._t, self._v = self._t[i:], self._v[i:]

    def interpolate(self, stamp_ns, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(values, age_s)`` at the given stamps (see the module doc for gaps)."""
        return self.apply(self.plan(stamp_ns, max_gap_s))

    def plan(self, stamp_ns, max_gap_s: float) -> tuple:
        """Return where ``stamp_ns`` fall among the retained stamps (for :meth:`apply`).

        The plan depends on the stamps only, so tracks with the same stamps (inputs
        published together) share one.
        """
        s = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
        n, t = s.size, self._t
        if t.size == 0:
            return (n,)
        hi = np.clip(np.searchsorted(t, s, side='left'), 1, max(t.size - 1, 1))
        lo = hi - 1
        if t.size == 1:
            hi = lo
        t0, t1 = t[lo], t[hi]
        d0 = (s - t0).astype(np.float64) / NS  # >= 0 inside, < 0 before the first sample
        d1 = (t1 - s).astype(np.float64) / NS  # >= 0 inside, < 0 after the last sample
        inside = (d0 >= 0) & (d1 >= 0)
        span = (t1 - t0).astype(np.float64) / NS
        interp = inside & (span <= max_gap_s) & (span > 0)
        if interp.all():  # the usual case: every stamp bracketed closely (same arithmetic)
            return n, lo, hi, d0 / span
        w = d0[interp] / span[interp]
        return (n, lo, hi, None, np.abs(d1) < np.abs(d0), np.minimum(np.abs(d0), np.abs(d1)),
                interp, w)

    def apply(self, plan) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(values, age_s)`` of this track at the stamps of ``plan``."""
        if len(plan) == 1:
            return np.full(plan[0], np.nan), np.full(plan[0], np.inf)
        v = self._v
        n, lo, hi, w_all = plan[:4]
        if w_all is not None:
            return v[lo] * (1.0 - w_all) + v[hi] * w_all, np.zeros(n)
        near_hi, age, interp, w = plan[4:]
        out = np.where(near_hi, v[hi], v[lo])
        age = age.copy()
        if np.any(interp):
            out[interp] = v[lo][interp] * (1.0 - w) + v[hi][interp] * w
            age[interp] = 0.0
        return out, age

    def latest(self, stamp_ns) -> tuple[np.ndarray, np.ndarray]:
        """Return the causal hold-last ``(values, age_s)`` at the given stamps."""
        s = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
        t = self._t
        if t.size == 0:
            return np.full(s.size, np.nan), np.full(s.size, np.inf)
        i = np.maximum(np.searchsorted(t, s, side='right') - 1, 0)
        return self._v[i].copy(), np.abs(s - t[i]).astype(np.float64) / NS


def fresh_rows(temp_age, max_gap_s):
    """Return the rows whose every input has a reading within ``max_gap_s`` (s) of the stamp.

    The collection rule of ``calibrate`` (``app.collect``), the simulations
    (``collection.feed``) and ``calibrator_node`` alike: an IMU sample far inside a
    temperature dropout, or before the first reading or after the last by more than
    ``max_gap_s``, is not collected (its temperature would be a guess). ``temp_age`` is
    ``AlignedChunk.temp_age`` (n, k); with k = 0 every row is fresh.
    """
    return (np.asarray(temp_age, float) <= max_gap_s).all(1)


class StreamAligner:
    """Offline look-ahead alignment of streamed IMU chunks with k temperature inputs.

    Feed chunks (``push`` for RawChunk-like objects from ``LogReader.stream``, or
    ``push_columns``) and collect the AlignedChunks returned; call ``finish`` at the end.
    ``AlignedChunk.extra`` carries ``imu_log_time_ns`` / ``imu_raw`` (when present) and any
    other row-aligned passthrough given to ``push_columns``, row for row.
    """

    def __init__(self, n_inputs: int | Sequence[str], max_gap_s: float = 5.0,
                 max_wait_s: float = 30.0):
        """Align ``n_inputs`` inputs (or the named topics, in this order)."""
        if isinstance(n_inputs, (int, np.integer)):
            self.names = None
            k = int(n_inputs)
        else:
            self.names = list(n_inputs)
            k = len(self.names)
        if k < 0 or not max_gap_s > 0 or not max_wait_s > 0:
            raise ValueError(f'need n_inputs >= 0, max_gap_s > 0 and max_wait_s > 0 (got {k}, '
                             f'{max_gap_s}, {max_wait_s}).')
        self.max_gap_s = float(max_gap_s)
        self.max_wait_s = float(max_wait_s)
        self.tracks = [TemperatureTrack(math.inf) for _ in range(k)]
        self._imu: list[ImuColumns] = []
        self._extra: list[dict] = []
        self._imu_max = None
        self._emitted_max = None

    @property
    def n_inputs(self) -> int:
        """Number of temperature inputs."""
        return len(self.tracks)

    @property
    def pending(self) -> int:
        """Number of IMU rows held back waiting for temperature."""
        return sum(len(c) for c in self._imu)

    def push(self, chunk) -> list[AlignedChunk]:
        """Feed a RawChunk-like object (``imu``, ``temps``, ``imu_log_time_ns``, ``imu_raw``)."""
        temps = chunk.temps
        if isinstance(temps, Mapping):
            if self.names is not None:
                missing = [n for n in self.names if n not in temps]
                if missing:
                    raise KeyError(f'chunk has no temperature input {missing[0]!r}; it has '
                                   f'{sorted(temps)}; build the aligner with those names.')
                temps = [temps[n] for n in self.names]
            else:
                temps = list(temps.values())
        extra = {}
        log_time = getattr(chunk, 'imu_log_time_ns', None)
        if log_time is not None:
            extra['imu_log_time_ns'] = np.asarray(log_time, dtype=np.int64)
        raw = getattr(chunk, 'imu_raw', None)
        if raw is not None:
            extra['imu_raw'] = list(raw)
        return self.push_columns(chunk.imu, temps, extra)

    def push_columns(self, imu: ImuColumns, temps: Sequence[TemperatureColumns],
                     extra: Mapping | None = None) -> list[AlignedChunk]:
        """Feed IMU rows, new temperature samples per input and row-aligned passthrough."""
        if len(temps) != self.n_inputs:
            raise ValueError(f'got {len(temps)} temperature inputs, the aligner was built for '
                             f'{self.n_inputs}; pass one TemperatureColumns per input.')
        for track, tc in zip(self.tracks, temps):
            track.add(tc.stamp_ns, tc.temperature)
        extra = dict(extra or {})
        for key, val in extra.items():
            if len(val) != len(imu):
                raise ValueError(f'extra[{key!r}] has {len(val)} rows for {len(imu)} IMU rows; '
                                 'passthrough data must be row-aligned.')
        if self._extra and set(extra) != set(self._extra[0]):
            raise ValueError(f'extra keys {sorted(extra)} differ from the pending rows\' '
                             f'{sorted(self._extra[0])}; pass the same passthrough every time.')
        if len(imu):
            self._imu.append(imu)
            self._extra.append(extra)
            top = int(imu.stamp_ns.max())
            self._imu_max = top if self._imu_max is None else max(self._imu_max, top)
        return self._release(final=False)

    def finish(self) -> list[AlignedChunk]:
        """Release every remaining row, holding the nearest known samples."""
        return self._release(final=True)

    def _release(self, final: bool) -> list[AlignedChunk]:
        if not self._imu:
            return []
        imu = ImuColumns.concat(self._imu) if len(self._imu) > 1 else self._imu[0]
        extra = _concat_extra(self._extra)
        if final or not self.tracks:
            count = len(imu)
        else:
            s = imu.stamp_ns
            covered = np.ones(len(imu), bool)
            for track in self.tracks:
                newest = track.newest_ns
                covered &= (s <= newest) if newest is not None else False
            stale = s < self._imu_max - int(self.max_wait_s * NS)
            ready = covered | stale
            count = len(imu) if ready.all() else int(np.argmin(ready))
        if count == 0:
            self._imu, self._extra = [imu], [extra]
            return []
        out_imu = imu.slice(slice(0, count))
        rest = imu.slice(slice(count, None))
        out_extra = {k: v[:count] for k, v in extra.items()}
        self._imu = [rest] if len(rest) else []
        self._extra = [{k: v[count:] for k, v in extra.items()}] if len(rest) else []
        aligned = self._resolve(out_imu, out_extra)
        top = int(out_imu.stamp_ns.max())
        self._emitted_max = top if self._emitted_max is None else max(self._emitted_max, top)
        keep_from = min(self._emitted_max, int(rest.stamp_ns.min()) if len(rest) else top)
        for track in self.tracks:
            track.discard_before(keep_from - int(self.max_gap_s * NS))
        return [aligned]

    def _resolve(self, imu: ImuColumns, extra: dict) -> AlignedChunk:
        n, k = len(imu), self.n_inputs
        temps = np.empty((n, k))
        ages = np.empty((n, k))
        plans = []   # (stamps, plan): inputs stamped alike share the search
        for j, track in enumerate(self.tracks):
            plan = next((p for st, p in plans if st is track.stamps_ns or (
                len(st) == len(track) and np.array_equal(st, track.stamps_ns))), None)
            if plan is None:
                plan = track.plan(imu.stamp_ns, self.max_gap_s)
                plans.append((track.stamps_ns, plan))
            temps[:, j], ages[:, j] = track.apply(plan)
        return AlignedChunk(imu, temps, ages, extra)


def _concat_extra(parts: list[dict]) -> dict:
    if len(parts) == 1:
        return parts[0]
    out = {}
    for key in parts[0]:
        vals = [p[key] for p in parts]
        if isinstance(vals[0], np.ndarray):
            out[key] = np.concatenate(vals)
        else:
            out[key] = [x for v in vals for x in v]
    return out
