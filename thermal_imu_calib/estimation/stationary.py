"""Streaming stationary detection with thresholds derived from the data's own noise.

Samples are reduced to fixed-duration *blocks* (``block_s``): mean and variance of accel
and gyro, mean temperature. A block is still when

* its accel and gyro variances (summed over axes) are below ``accel_factor`` /
  ``gyro_factor`` times the noise floor, the ``noise_quantile`` of all block variances
  seen so far (so the same code serves a navigation-grade triad and a hobby MEMS chip);
* its means differ from the previous block's by less than ``mean_sigmas`` standard errors
  (a slow rotation has a small variance but a moving mean).

Runs of still blocks become *holds*; ``guard_s`` is trimmed from both ends so motion
between poses never leaks in, holds shorter than ``min_hold_s`` are dropped, and each hold
is cut into windows of ``window_s`` (estimation.segments.Windows). The detector keeps only
block statistics of the open hold plus two floats per block for the noise floor, so memory
stays small for hours of data, and the same class runs offline (CLI) and live (node).
"""

from dataclasses import dataclass

import numpy as np

from .segments import Windows


@dataclass
class DetectorConfig:
    """Stationary detector settings (seconds, dimensionless factors)."""

    block_s: float = 0.5
    window_s: float = 5.0
    min_hold_s: float = 10.0
    guard_s: float = 1.0
    accel_factor: float = 4.0
    gyro_factor: float = 4.0
    mean_sigmas: float = 6.0
    noise_quantile: float = 0.05
    #: absolute floors for the noise estimate (quantised sensors can read exactly constant)
    min_accel_var: float = 1e-10
    min_gyro_var: float = 1e-12

    def validate(self):
        """Raise ValueError with the offending field when a setting is out of range."""
        checks = [('block_s', 0.01, 10), ('window_s', 0.05, 600), ('min_hold_s', 0.1, 36000),
                  ('guard_s', 0.0, 60), ('accel_factor', 1.0, 1000), ('gyro_factor', 1.0, 1000),
                  ('mean_sigmas', 1.0, 1000), ('noise_quantile', 0.001, 0.9)]
        for name, lo, hi in checks:
            v = getattr(self, name)
            if not lo <= v <= hi:
                raise ValueError(f'detector {name}={v} is outside [{lo}, {hi}]')
        if self.window_s < self.block_s:
            raise ValueError(f'window_s ({self.window_s}) must be >= block_s ({self.block_s})')


class _Blocks:
    """Block statistics as growing column arrays."""

    names = ('t0', 't1', 'n', 'am', 'av', 'gm', 'gv', 'tm', 'tt')

    def __init__(self, k):
        self.k = k
        self.clear()

    def clear(self):
        self.t0 = np.zeros(0)
        self.t1 = np.zeros(0)
        self.n = np.zeros(0, int)
        self.am = np.zeros((0, 3))
        self.av = np.zeros((0, 3))
        self.gm = np.zeros((0, 3))
        self.gv = np.zeros((0, 3))
        self.tm = np.zeros((0, self.k))
        self.tt = np.zeros(0)  # mean time of samples, for temperature rates

    def __len__(self):
        return len(self.t0)

    def append(self, other):
        for name in self.names:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(other, name)]))

    def take(self, sl):
        out = _Blocks(self.k)
        for name in self.names:
            setattr(out, name, getattr(self, name)[sl])
        return out


class StationaryDetector:
    """Feed aligned chunks with ``update``; collect closed holds as Windows tables."""

    def __init__(self, config=None, n_inputs=0):
        self.config = config or DetectorConfig()
        self.config.validate()
        self.k = n_inputs
        self._origin = None
        self._carry = None  # rows of the last, unfinished block
        self._var_a = []    # per-block summed variances, for the noise floor
        self._var_g = []
        self._open = _Blocks(n_inputs)  # unclassified / open-hold blocks
        self._prev_still_mean = None
        self._next_hold = 0
        self.samples = 0

    # ----------------------------------------------------------------- public
    def update(self, t, accel, gyro, temps=None):
        """Add samples (t in s, accel m/s^2, gyro rad/s, temps (n, k) degC).

        Returns a Windows table of the holds that closed with this data (possibly empty).
        """
        t = np.asarray(t, float)
        accel = np.asarray(accel, float)
        gyro = np.asarray(gyro, float)
        temps = np.zeros((len(t), self.k)) if temps is None else np.asarray(temps, float)
        temps = temps.reshape(len(t), self.k)
        self.samples += len(t)
        if self._carry is not None:
            ct, ca, cg, ctm = self._carry
            t, accel, gyro, temps = (np.concatenate([ct, t]), np.concatenate([ca, accel]),
                                     np.concatenate([cg, gyro]), np.concatenate([ctm, temps]))
            self._carry = None
        if len(t) == 0:
            return Windows.empty(self.k)
        if self._origin is None:
            self._origin = t[0]
        bid = np.floor((t - self._origin) / self.config.block_s).astype(np.int64)
        last = bid[-1]
        keep = bid == last
        self._carry = (t[keep], accel[keep], gyro[keep], temps[keep])
        done = ~keep
        if np.any(done):
            self._add_blocks(t[done], accel[done], gyro[done], temps[done], bid[done])
        return self._classify(final=False)

    def finish(self):
        """Flush: the unfinished block and the open hold are closed (end of a log)."""
        if self._carry is not None and len(self._carry[0]):
            t, a, g, tm = self._carry
            self._carry = None
            bid = np.zeros(len(t), np.int64)
            self._add_blocks(t, a, g, tm, bid)
        return self._classify(final=True)

    def noise_floor(self):
        """Return (accel, gyro) per-sample variance floors summed over axes, or None."""
        if len(self._var_a) < 4:
            return None
        q = self.config.noise_quantile
        fa = max(float(np.quantile(self._var_a, q)), self.config.min_accel_var)
        fg = max(float(np.quantile(self._var_g, q)), self.config.min_gyro_var)
        return fa, fg

    def status(self):
        """Return a dict for progress reporting: still now, open-hold seconds, noise floor."""
        ob = self._open
        still = self._still_mask(ob) if len(ob) else np.zeros(0, bool)
        run = 0.0
        if len(still) and still[-1]:
            i = len(still) - 1
            while i > 0 and still[i - 1]:
                i -= 1
            run = float(ob.t1[-1] - ob.t0[i])
        nf = self.noise_floor()
        return {'stationary': bool(len(still) and still[-1]), 'hold_seconds': run,
                'noise_floor': None if nf is None else {'accel_var': nf[0], 'gyro_var': nf[1]},
                'samples': self.samples}

    # ---------------------------------------------------------------- internal
    def _add_blocks(self, t, accel, gyro, temps, bid):
        starts = np.flatnonzero(np.r_[True, bid[1:] != bid[:-1]])
        n = np.diff(np.r_[starts, len(t)])
        blk = _Blocks(self.k)
        blk.t0 = t[starts]
        blk.t1 = t[np.r_[starts[1:], len(t)] - 1]
        blk.n = n
        idx = np.repeat(np.arange(len(starts)), n)

        def mean_var(x):
            m = np.add.reduceat(x, starts, axis=0) / n[:, None]
            v = np.add.reduceat((x - m[idx]) ** 2, starts, axis=0) / np.maximum(n - 1, 1)[:, None]
            return m, v

        blk.am, blk.av = mean_var(accel)
        blk.gm, blk.gv = mean_var(gyro)
        blk.tm = (np.add.reduceat(temps, starts, axis=0) / n[:, None] if self.k
                  else np.zeros((len(starts), 0)))
        blk.tt = np.add.reduceat(t, starts) / n
        ok = n >= 3
        blk = blk.take(ok)
        self._var_a.extend(blk.av.sum(1).tolist())
        self._var_g.extend(blk.gv.sum(1).tolist())
        self._open.append(blk)

    def _still_mask(self, b):
        nf = self.noise_floor()
        if nf is None:
            return np.zeros(len(b), bool)
        fa, fg = nf
        c = self.config
        va, vg = b.av.sum(1), b.gv.sum(1)
        still = (va < c.accel_factor * fa) & (vg < c.gyro_factor * fg)
        # mean continuity between neighbouring blocks: squared difference against its
        # standard error (2 sigma^2 / n per axis, summed)
        n = np.maximum(b.n, 1)
        da = np.sum(np.diff(b.am, axis=0) ** 2, axis=1)
        dg = np.sum(np.diff(b.gm, axis=0) ** 2, axis=1)
        se_a = c.accel_factor * fa * (1.0 / n[1:] + 1.0 / n[:-1])
        se_g = c.gyro_factor * fg * (1.0 / n[1:] + 1.0 / n[:-1])
        jump = (da > c.mean_sigmas ** 2 * se_a) | (dg > c.mean_sigmas ** 2 * se_g)
        # a jump breaks stillness on both sides of it
        still[1:] &= ~jump
        still[:-1] &= ~jump
        return still

    def _classify(self, final):
        b = self._open
        if len(b) == 0:
            return Windows.empty(self.k)
        still = self._still_mask(b)
        # runs of still blocks: [start, end)
        edges = np.diff(np.r_[0, still.astype(int), 0])
        run_starts = np.flatnonzero(edges == 1)
        run_ends = np.flatnonzero(edges == -1)
        out = []
        consumed = 0
        for s, e in zip(run_starts, run_ends):
            closed = e < len(b) or final
            if not closed:
                break
            out.append(self._make_hold(b.take(slice(s, e))))
            consumed = e
        if final:
            consumed = len(b)
        elif not (len(run_starts) and run_ends[-1] == len(b)):
            # nothing open: drop everything classified (keep the last block for continuity)
            consumed = max(consumed, len(b) - 1)
        else:
            consumed = max(consumed, run_starts[-1])
        if consumed:
            self._open = b.take(slice(consumed, None))
        parts = [w for w in out if w is not None]
        return Windows.concat(parts) if parts else Windows.empty(self.k)

    def _make_hold(self, b):
        c = self.config
        if len(b) == 0:
            return None
        t_lo = b.t0[0] + c.guard_s
        t_hi = b.t1[-1] - c.guard_s
        keep = (b.t0 >= t_lo) & (b.t1 <= t_hi)
        b = b.take(keep)
        if len(b) == 0 or b.t1[-1] - b.t0[0] < c.min_hold_s:
            return None
        hold = self._next_hold
        self._next_hold += 1
        per = max(1, int(round(c.window_s / c.block_s)))
        groups = np.arange(len(b)) // per
        if groups[-1] > 0 and np.sum(groups == groups[-1]) < (per + 1) // 2:
            groups[groups == groups[-1]] -= 1  # merge a short tail into the previous window
        starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
        n = np.add.reduceat(b.n, starts)
        w = b.n[:, None].astype(float)

        def wmean(x):
            return np.add.reduceat(x * w, starts, axis=0) / n[:, None]

        m = len(starts)
        temp = wmean(b.tm) if self.k else np.zeros((m, 0))
        rate = np.zeros((m, self.k))
        if self.k:
            ends = np.r_[starts[1:], len(b)]
            for j, (s, e) in enumerate(zip(starts, ends)):
                if e - s >= 2:
                    tt = b.tt[s:e] - b.tt[s:e].mean()
                    rate[j] = (tt @ (b.tm[s:e] - b.tm[s:e].mean(0))) / max(tt @ tt, 1e-12)
        return Windows(
            hold=np.full(m, hold, int),
            t0=b.t0[starts], t1=b.t1[np.r_[starts[1:], len(b)] - 1], n=n.astype(int),
            accel=wmean(b.am), gyro=wmean(b.gm),
            accel_var=wmean(b.av), gyro_var=wmean(b.gv), temp=temp, temp_rate=rate)


def detect(chunks, config=None, n_inputs=0):
    """Run the detector over an iterable of AlignedChunk and return all windows."""
    det = StationaryDetector(config, n_inputs)
    parts = []
    for ch in chunks:
        parts.append(det.update(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps))
    parts.append(det.finish())
    return Windows.concat(parts) if any(len(p) for p in parts) else Windows.empty(n_inputs)
