"""Outliers (seed 002 section 3.2): spike rejection in sample streams and robust fitting.

Spikes
    :class:`SpikeFilter` is a streaming Hampel filter. Sample x_t of a channel is a spike
    when ``|x_t - median(window_t)| > threshold * sigma_t``, where ``window_t`` is the
    centred window of ``2 h + 1`` samples and ``sigma_t`` is the largest of

    * the window's local noise: 1.4826 x the median absolute deviation of its first
      differences / sqrt(2) (insensitive to a linear trend: motion, vibration),
    * the channel's white-noise floor: the smallest, over completed blocks of
      ``block`` samples, of 1.4826 x median(|x_t - x_{t-1}|) / sqrt(2),
    * the output resolution: the smallest non-zero |x_t - x_{t-1}| seen so far (one LSB of
      a quantised sensor, whose local MAD is often exactly 0),
    * ``min_sigma`` (per channel, in the signal's unit).

    No sample is flagged before the first block is complete (the noise is not known yet).
    A smooth ramp is never a spike (the centred median follows it); an isolated wild
    sample is. Two spikes closer than ``2 h + 1`` samples inflate the local spread and may
    both pass (the window trades that against the output lag). Flagged samples are replaced by the
    window median (``mode='replace'``) or only flagged (``'flag'``). Everything is
    vectorised per chunk and the result does not depend on how the stream is chunked:
    blocks and windows are counted in samples since the start. The output lags the input
    by ``h`` samples (``delay``); :meth:`SpikeFilter.flush` releases the tail.
    Memory: ``2 h`` samples of every channel and passthrough column, plus one block of
    absolute differences (``block`` x channels floats).

Robust fitting
    :func:`robust_least_squares` runs ``scipy.optimize.least_squares`` three times: plain
    least squares, then a soft-L1 and a Cauchy loss whose scale is ``k`` robust standard
    deviations (MAD) of the previous residuals. A bumped hold then has bounded (soft-L1)
    and finally vanishing (Cauchy) influence on the parameters. Each stage starts its own
    trust region at its starting point (``_from_zero``).
"""

from dataclasses import dataclass, field
from typing import List

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

MAD_TO_SIGMA = 1.4826


@dataclass
class SpikeOutput:
    """Samples released by the filter: cleaned values, the spike mask and passthrough columns."""

    values: np.ndarray              # (m, c) cleaned (or original with mode='flag')
    spikes: np.ndarray              # (m, c) bool
    extra: List[np.ndarray] = field(default_factory=list)

    def __len__(self):
        return int(self.values.shape[0])


class SpikeFilter:
    """Streaming, chunk-invariant Hampel spike gate with a per-channel rejection counter."""

    def __init__(self, channels=6, half_window=3, threshold=8.0, min_sigma=None, block=512,
                 mode='replace'):
        if half_window < 1:
            raise ValueError(f'half_window must be >= 1 (got {half_window})')
        if not threshold > 0:
            raise ValueError(f'threshold must be > 0 (got {threshold})')
        if mode not in ('replace', 'flag'):
            raise ValueError(f"mode must be 'replace' or 'flag', not {mode!r}")
        self.c = int(channels)
        self.h = int(half_window)
        self.threshold = float(threshold)
        self.min_sigma = np.zeros(self.c) if min_sigma is None else \
            np.broadcast_to(np.asarray(min_sigma, float), (self.c,)).copy()
        self.block = int(block)
        self.mode = mode
        self._x = np.zeros((0, self.c))       # unreleased raw samples (<= 2h)
        self._extra = None
        self._floor_buf = np.zeros((0, self.c))
        self._emitted = 0                     # samples released so far
        self._seen = 0                        # samples pushed so far
        self._last = None                     # previous raw sample (for differences)
        self._lsb = np.full(self.c, np.inf)   # smallest non-zero |diff| so far
        self._blk = []                        # |diff| rows of the block in progress
        self._blk_n = 0
        self._floor = np.full(self.c, np.inf)  # min over completed blocks
        #: per-channel count of rejected samples
        self.rejected = np.zeros(self.c, np.int64)

    @property
    def delay(self):
        """Return the output lag in samples."""
        return self.h

    @property
    def samples(self):
        """Return the number of samples released so far."""
        return self._emitted

    def noise_floor(self):
        """Return the current per-channel sigma floor (signal units)."""
        f = np.fmax(np.where(np.isfinite(self._floor), self._floor, 0.0),
                    np.where(np.isfinite(self._lsb), self._lsb, 0.0))
        return np.maximum(f, self.min_sigma)

    def counts(self):
        """Return a plain dict for diagnostics: samples, rejected per channel, rate."""
        n = max(self._emitted, 1)
        return {'samples': int(self._emitted), 'rejected': self.rejected.tolist(),
                'rejected_total': int(self.rejected.sum()),
                'rejected_fraction': float(self.rejected.sum() / (n * self.c))}

    # ----------------------------------------------------------------- stream
    def _floors(self, x):
        """Per-row sigma floors (n, c) for new raw rows x, updating the running statistics."""
        n = x.shape[0]
        prev = x[:1] if self._last is None else self._last[None]
        with np.errstate(over='ignore', invalid='ignore'):   # corrupt values: inf/nan, below
            d = np.abs(np.diff(np.concatenate([prev, x]), axis=0))
        if self._last is None:
            d[0] = np.nan                      # no difference for the very first sample
        self._last = x[-1].copy()
        # resolution: cumulative min of non-zero differences (chunk-invariant)
        dz = np.where((d > 0) & np.isfinite(d), d, np.inf)
        lsb = np.minimum.accumulate(np.vstack([self._lsb[None], dz]), axis=0)[1:]
        self._lsb = lsb[-1].copy()
        # block noise: completed blocks by absolute sample index
        floor_rows = np.empty((n, self.c))
        i = 0
        while i < n:
            take = min(self.block - self._blk_n, n - i)
            floor_rows[i:i + take] = self._floor
            self._blk.append(d[i:i + take])
            self._blk_n += take
            i += take
            if self._blk_n == self.block:
                blk = np.concatenate(self._blk)
                with np.errstate(all='ignore'):
                    est = MAD_TO_SIGMA * np.nanmedian(blk, axis=0) / np.sqrt(2.0)
                self._floor = np.fmin(self._floor, np.where(np.isfinite(est), est, np.inf))
                self._blk, self._blk_n = [], 0
        # rows before the first completed block keep an infinite floor: no flags while
        # the noise is still unknown (the first ``block`` samples)
        floor = np.fmax(floor_rows, np.where(np.isfinite(lsb), lsb, 0.0))
        return np.maximum(floor, self.min_sigma)

    def push(self, x, extra=None):
        """Add (n, c) samples (and passthrough arrays with n rows); return the released rows."""
        x = np.asarray(x, float).reshape(-1, self.c)
        extra = [np.asarray(e) for e in (extra or [])]
        for e in extra:
            if e.shape[0] != x.shape[0]:
                raise ValueError(f'passthrough array has {e.shape[0]} rows, samples {x.shape[0]}')
        floors = self._floors(x) if len(x) else np.zeros((0, self.c))
        self._seen += x.shape[0]
        if self._extra is None:
            self._extra = [e[:0] for e in extra]
        buf = np.concatenate([self._x, x])
        fbuf = np.concatenate([self._floor_buf, floors])
        ebuf = [np.concatenate([a, b]) for a, b in zip(self._extra, extra)]
        return self._release(buf, fbuf, ebuf, final=False)

    def flush(self):
        """Release the last ``delay`` samples (end of the stream)."""
        if self._extra is None:
            return SpikeOutput(np.zeros((0, self.c)), np.zeros((0, self.c), bool), [])
        return self._release(self._x, self._floor_buf, self._extra, final=True)

    def _release(self, buf, fbuf, ebuf, final):
        h, w = self.h, 2 * self.h + 1
        n = buf.shape[0]
        start = self._emitted - (self._seen - n)      # buffer index of the next release
        end = n if final else n - h                   # exclusive
        if end <= start or n == 0:
            self._keep(buf, fbuf, ebuf, start)
            return SpikeOutput(np.zeros((0, self.c)), np.zeros((0, self.c), bool),
                               [e[:0] for e in ebuf])
        idx = np.arange(start, end)
        if n >= w:
            win = sliding_window_view(buf, w, axis=0)          # (n - 2h, c, w)
            lo = np.clip(idx - h, 0, n - w)                    # shifted windows at the ends
            win = win[lo]
        else:
            win = np.broadcast_to(buf.T[None], (len(idx), self.c, n))
        floor = fbuf[idx]
        # values near the float limit (a corrupt message) overflow to inf or nan here; the
        # result is the same with or without the warning numpy would print (non-finite
        # values and sigmas never flag a spike), so it is not printed
        with np.errstate(over='ignore', invalid='ignore'):
            med = np.median(win, axis=-1)
            dw = np.diff(win, axis=-1)
            mad = np.median(np.abs(dw - np.median(dw, axis=-1)[..., None]), axis=-1)
            sigma = np.maximum(MAD_TO_SIGMA * mad / np.sqrt(2.0), floor)
            vals = buf[idx]
            spikes = np.abs(vals - med) > self.threshold * sigma
        spikes &= np.isfinite(vals) & np.isfinite(floor)
        self.rejected += spikes.sum(axis=0)
        out = np.where(spikes, med, vals) if self.mode == 'replace' else vals.copy()
        self._emitted += len(idx)
        self._keep(buf, fbuf, ebuf, end)
        return SpikeOutput(out, spikes, [e[idx] for e in ebuf])

    def _keep(self, buf, fbuf, ebuf, released_to):
        """Keep h rows of left context plus everything not yet released."""
        keep_from = max(0, min(released_to, buf.shape[0]) - self.h)
        self._x = buf[keep_from:]
        self._floor_buf = fbuf[keep_from:]
        self._extra = [e[keep_from:] for e in ebuf]


def despike(x, **kwargs):
    """Run a :class:`SpikeFilter` over a whole (n, c) array; return (cleaned, spikes, filter)."""
    x = np.asarray(x, float)
    x2 = x.reshape(x.shape[0], -1)
    f = SpikeFilter(channels=x2.shape[1], **kwargs)
    a = f.push(x2)
    b = f.flush()
    vals = np.concatenate([a.values, b.values]).reshape(x.shape)
    mask = np.concatenate([a.spikes, b.spikes]).reshape(x.shape)
    return vals, mask, f


class ImuSpikeFilter:
    """Spike gate for IMU column chunks: accel and gyro (6 channels), stamps passed through.

    ``push(chunk)`` takes an ``io.columns.ImuColumns`` or an ``AlignedChunk`` (whose
    temperatures, ages and ``extra`` passthrough, e.g. raw CDR buffers and log times, are
    delayed with the samples) and returns the same type, ``delay`` samples late; ``flush()``
    returns the tail. ``counts()`` reports the rejections per channel.
    """

    def __init__(self, accel_min_sigma=0.0, gyro_min_sigma=0.0, **kwargs):
        ms = np.r_[np.broadcast_to(accel_min_sigma, 3), np.broadcast_to(gyro_min_sigma, 3)]
        self.filter = SpikeFilter(channels=6, min_sigma=ms, **kwargs)
        self._frame = ''
        self._aligned = None
        self._keys = None            # extra keys of aligned chunks, and which were lists

    @property
    def delay(self):
        """Return the output lag in samples."""
        return self.filter.delay

    def counts(self):
        """Return the rejection counters (accel x,y,z then gyro x,y,z)."""
        return self.filter.counts()

    def push(self, chunk):
        """Filter one chunk; returns the released part as the input's type."""
        from ..io.columns import AlignedChunk
        aligned = isinstance(chunk, AlignedChunk)
        self._aligned = aligned
        imu = chunk.imu if aligned else chunk
        self._frame = imu.frame_id or self._frame
        extra = [imu.stamp_ns]
        if aligned:
            extra += [chunk.temps, chunk.temp_age]
            if self._keys is None:
                self._keys = [(k, isinstance(v, list)) for k, v in sorted(chunk.extra.items())]
            for k, is_list in self._keys:
                v = chunk.extra[k]
                if is_list:
                    arr = np.empty(len(v), object)
                    arr[:] = v
                    v = arr
                extra.append(np.asarray(v))
        out = self.filter.push(np.hstack([imu.accel, imu.gyro]), extra)
        return self._wrap(out)

    def flush(self):
        """Release the tail at the end of the stream."""
        return self._wrap(self.filter.flush())

    def _wrap(self, out):
        from ..io.columns import AlignedChunk, ImuColumns
        stamps = out.extra[0] if out.extra else np.zeros(0, np.int64)
        imu = ImuColumns(np.asarray(stamps, np.int64), out.values[:, :3].copy(),
                         out.values[:, 3:].copy(), self._frame)
        if self._aligned:
            extra = {}
            for (k, is_list), v in zip(self._keys or [], out.extra[3:]):
                extra[k] = list(v) if is_list else v
            return AlignedChunk(imu, out.extra[1], out.extra[2], extra)
        return imu


# ---------------------------------------------------------------------- robust fitting
def robust_scale(r):
    """Return the MAD-based standard deviation of residuals r (0 for fewer than 2)."""
    r = np.asarray(r, float).ravel()
    r = r[np.isfinite(r)]
    if r.size < 2:
        return 0.0
    return float(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r))))


@dataclass
class RobustResult:
    """A robust least-squares solution with the scale used and which residuals lost weight."""

    x: np.ndarray
    jac: np.ndarray
    fun: np.ndarray                 # unweighted (whitened) residuals at x
    scale: float                    # robust std of the residuals (their unit)
    f_scale: float                  # soft threshold of the final loss
    outliers: np.ndarray            # bool per residual, |r| > f_scale
    cost: float
    nfev: int
    success: bool
    message: str = ''


def _from_zero(fun, x, jac, kwargs):
    """Run ``least_squares`` in the offset d = x' - x from its start x; return x' in ``x``.

    scipy's trust-region methods size their first trust region by |x0| (1 only when
    x0 = 0): a stage that starts where the previous one ended, near zero, would start with
    a radius of ~1e-14 and stop at once ('ftol') without moving. Each stage starts at d = 0.
    """
    kwargs = dict(kwargs)
    if 'bounds' in kwargs:
        lo, hi = kwargs['bounds']
        kwargs['bounds'] = (np.asarray(lo, float) - x, np.asarray(hi, float) - x)
    from scipy.optimize import least_squares   # not at import: 0.3 s of a node's start
    res = least_squares(lambda d: fun(x + d), np.zeros_like(x),
                        jac=(lambda d: jac(x + d)) if callable(jac) else jac, **kwargs)
    res.x = x + res.x
    return res


def robust_least_squares(fun, x0, jac='2-point', k=3.0, min_scale=1.0, final_loss='cauchy',
                         stages=('linear', 'soft_l1', 'final'), **kwargs):
    """Least squares that one bad group of residuals cannot drag (see the module docstring).

    ``fun`` returns whitened residuals (unit ~ 1 sigma when the model fits). The loss scale
    of each robust stage is ``k * max(robust_scale(previous residuals), min_scale)``.
    ``kwargs`` go to every ``scipy.optimize.least_squares`` call (x_scale, bounds, ...).
    """
    x = np.asarray(x0, float)
    res = None
    f_scale = np.inf
    for stage in stages:
        if stage == 'linear':
            res = _from_zero(fun, x, jac, dict(kwargs, loss='linear'))
        else:
            s = robust_scale(res.fun) if res is not None else robust_scale(fun(x))
            f_scale = k * max(s, min_scale)
            loss = 'soft_l1' if stage == 'soft_l1' else final_loss
            res = _from_zero(fun, x, jac, dict(kwargs, loss=loss, f_scale=f_scale))
        x = res.x
    r = np.asarray(res.fun, float)
    return RobustResult(res.x, res.jac, r, robust_scale(r), float(f_scale),
                        np.abs(r) > f_scale, float(res.cost), int(res.nfev),
                        bool(res.success), str(res.message))


def group_outliers(residuals, groups, scale, limit=4.0):
    """Return the group ids whose median |residual| exceeds ``limit`` x ``scale``."""
    residuals = np.asarray(residuals, float)
    groups = np.asarray(groups)
    bad = []
    for g in np.unique(groups):
        m = np.median(np.abs(residuals[groups == g]))
        if scale > 0 and m > limit * scale:
            bad.append(g.item() if hasattr(g, 'item') else g)
    return bad


__all__ = ['SpikeFilter', 'SpikeOutput', 'ImuSpikeFilter', 'despike', 'robust_scale',
           'robust_least_squares', 'RobustResult', 'group_outliers']
