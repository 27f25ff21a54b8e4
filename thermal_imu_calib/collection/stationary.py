"""Streaming stationary detection whose settings are derived from the log itself.

Nothing needs tuning: from the first ``DERIVE_SAMPLES`` samples the detector measures the
sample rate and the quantisation step (LSB) of each sensor, and derives

* the *block*: ``block_n`` samples (about ``BLOCK_TARGET_S``, at least ``MIN_BLOCK_N``), so
  a 1 Hz chamber log and a 2 kHz IMU both get blocks with a defined variance;
* minimum hold, guard and window lengths from the block length (a 1 s hold at >= 50 Hz;
  the guard grows to GUARD_FRACTION of a long still run, at most GUARD_MAX_S);
* variance thresholds from the chi-square spread of a block variance with that many
  samples, relative to the noise floor (the ``noise_quantile`` of all block variances seen
  so far, corrected for the chi-square bias, never below the quantisation noise LSB^2/12),
  so a navigation-grade triad and a hobby MEMS chip run the same code; the floor keeps
  adapting as the log goes on.

A block is *moving* when any of these holds:

* its accel or gyro variance (summed over axes) is above the threshold, or the gyro
  variance is above ``rotation_dps`` squared (hand tremor below that is tolerated);
* its mean gyro differs from the gyro bias (the median of recent quiet blocks, so thermal
  bias drift is followed) by more than ``rotation_dps``: a rotation about gravity, which
  leaves the accelerometer unchanged, is seen here;
* its mean accel differs from a neighbour's by more than ``mean_sigmas`` standard errors
  *and* by more than gravity turned at ``rotation_dps`` over one block (a slow tilt).

Thermal drift inside a hold moves the means by far less than either bound, so only motion
splits a hold. Runs of still blocks become *holds*; ``guard_s`` is trimmed from both ends
(not where the log itself starts or ends; a derived guard only as far as its blocks' means
differ from the rest of the hold, ``_settled``), guards and holds measured in samples at the
derived rate (jittered stamps change nothing), shorter ones than ``min_hold_s`` are
dropped, and each hold is cut into windows of ``window_s`` (estimation.segments.Windows).
``holds`` keeps one record per hold (start, duration, stillness score). Memory stays small
for hours of data, and the same class runs offline (CLI) and live (node). Settings given
explicitly (not None / 0) are kept.

Cohesive: one streaming algorithm (derive, score blocks, bridge, make holds and windows)
whose state is shared by every step; split, its parts would pass that state around.
"""

import dataclasses
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.special import gammaincinv

from .segments import face_of, Windows

#: samples used to measure the rate and the quantisation step before detection starts
DERIVE_SAMPLES = 200
#: target block duration (s) and fewest samples per block
BLOCK_TARGET_S = 0.1
MIN_BLOCK_N = 5
#: a still block's variance stays below its chi-square quantile (1 - BLOCK_FALSE_ALARM)
#: times VARIANCE_MARGIN (non-white noise, tremor) times the noise floor
BLOCK_FALSE_ALARM = 1e-3
VARIANCE_MARGIN = 3.0
#: until this many blocks were seen, the open blocks are re-scored on every update
MATURE_BLOCKS = 200
#: a derived guard is this fraction of the still run, between guard_s and GUARD_MAX_S
GUARD_FRACTION = 0.02
#: ... and at the end of a hold, before a pose change, this fraction
GUARD_TAIL_FRACTION = 0.05
GUARD_MAX_S = 1.0
#: a guard block is kept when the chi-square statistic of its mean against the hold's core
#: is below this many times its degrees of freedom (``_settled``: mean square error)
EDGE_Z2_PER_DOF = 2.0
#: isolated false alarms: runs this short and this marginal between still blocks are still
BRIDGE_BLOCKS = 2
BRIDGE_SCORE = 4.0
#: quiet-block gyro means kept for the bias reference
BIAS_BLOCKS = 2000
#: block variances kept for the noise floor
FLOOR_BLOCKS = 200_000
DERIVED = ('block_s', 'window_s', 'min_hold_s', 'guard_s', 'accel_factor', 'gyro_factor')


class DetectorSettingsError(ValueError):
    """The settings derived from the IMU's sample rate are out of range (implausible stamps)."""


@dataclass
class DetectorConfig:
    """Stationary detector settings (seconds, dimensionless factors); None or 0: derived."""

    block_s: Optional[float] = None
    window_s: Optional[float] = None
    min_hold_s: Optional[float] = None
    guard_s: Optional[float] = None
    accel_factor: Optional[float] = None
    gyro_factor: Optional[float] = None
    mean_sigmas: float = 6.0
    noise_quantile: float = 0.05
    #: rotation rate (deg/s) below which the unit counts as held (hand tremor, slow drift)
    rotation_dps: float = 3.0
    #: absolute floors for the noise estimate (quantised sensors can read exactly constant)
    min_accel_var: float = 1e-10
    min_gyro_var: float = 1e-12

    def validate(self):
        """Raise ValueError with the offending field when a setting is out of range."""
        checks = [('block_s', 0.001, 60), ('window_s', 0.01, 3600), ('min_hold_s', 0.05, 36000),
                  ('guard_s', 0.0, 600), ('accel_factor', 1.0, 1e4), ('gyro_factor', 1.0, 1e4),
                  ('mean_sigmas', 1.0, 1000), ('noise_quantile', 0.001, 0.9),
                  ('rotation_dps', 0.001, 100)]
        for name, lo, hi in checks:
            v = getattr(self, name)
            if v is None or (name in DERIVED and v == 0 and name != 'guard_s'):
                continue
            if not lo <= v <= hi:
                raise ValueError(f'detector {name}={v} is outside [{lo}, {hi}]')
        if self.window_s and self.block_s and self.window_s < self.block_s:
            raise ValueError(f'window_s ({self.window_s}) must be >= block_s ({self.block_s})')

    def derive(self, rate_hz, accel_lsb=0.0, gyro_lsb=0.0):
        """Return (resolved DetectorConfig, block_n) for a log at ``rate_hz``."""
        given = {k: v for k, v in vars(self).items() if v is not None and
                 not (k in DERIVED and k != 'guard_s' and v == 0)}
        if 'block_s' in given:
            block_n = max(3, int(round(given['block_s'] * rate_hz)))
        else:
            block_n = max(MIN_BLOCK_N, int(round(BLOCK_TARGET_S * rate_hz)))
        block_s = block_n / rate_hz
        dof = 3 * (block_n - 1)
        factor = VARIANCE_MARGIN * float(chi2_ppf(1 - BLOCK_FALSE_ALARM, dof)
                                         / chi2_ppf(self.noise_quantile, dof))
        auto = {'block_s': block_s, 'min_hold_s': max(0.5, 5 * block_s),
                'guard_s': max(0.2, 2 * block_s), 'window_s': max(5.0, 2 * block_s),
                'accel_factor': factor, 'gyro_factor': factor}
        auto.update({k: v for k, v in given.items() if k in DERIVED})
        auto['window_s'] = max(auto['window_s'], block_s)
        return dataclasses.replace(self, **auto), block_n


def chi2_ppf(p, dof):
    """Return the chi-square quantile at ``p`` with ``dof`` degrees of freedom.

    What ``scipy.stats.chi2.ppf`` computes (``2 gammaincinv(dof/2, p)``, the same float),
    without importing scipy.stats (about 0.3 s of start-up).
    """
    return 2 * gammaincinv(dof / 2, p)


def quantisation_step(x):
    """Return the LSB of each column (0 when the values are not on a regular grid)."""
    x = np.asarray(x, float)
    out = np.zeros(x.shape[1])
    for i in range(x.shape[1]):
        d = np.abs(np.diff(x[:, i]))
        d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(x[:, i]))))]
        if len(d) < 3:
            continue
        q = float(np.min(d))
        ratio = d / q
        if np.median(np.abs(ratio - np.round(ratio))) < 0.02:
            out[i] = q
    return out


class _Ring:
    """The last ``maxlen`` rows appended (like ``deque(maxlen=...)``), in one numpy array.

    ``values`` is not in insertion order once the ring has wrapped: only order-free
    statistics (quantiles, medians) are taken of it.
    """

    def __init__(self, maxlen, width=None):
        self.maxlen = int(maxlen)
        self._shape = () if width is None else (int(width),)
        self._a = np.empty((0,) + self._shape)
        self._total = 0

    def __len__(self):
        return min(self._total, self.maxlen)

    def clear(self):
        self._total = 0

    def extend(self, x):
        x = np.asarray(x, float).reshape((-1,) + self._shape)
        if len(x) >= self.maxlen:
            x = x[len(x) - self.maxlen:]
        n = len(x)
        if not n:
            return
        size = len(self)
        if size + n > len(self._a) and len(self._a) < self.maxlen:
            grown = np.empty((min(self.maxlen, max(2 * len(self._a), size + n, 1024)),)
                             + self._shape)
            grown[:size] = self._a[:size]
            self._a = grown
        pos = self._total % self.maxlen if self._total >= self.maxlen else self._total
        first = min(n, self.maxlen - pos)
        self._a[pos:pos + first] = x[:first]
        if first < n:
            self._a[:n - first] = x[first:]
        self._total += n

    def values(self):
        """Return the rows kept (a view; order unspecified once wrapped)."""
        return self._a[:len(self)]


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
        self.requested = config or DetectorConfig()
        self.requested.validate()
        self.config = None          # resolved settings, once the rate is known
        self.block_n = None
        self.derived = None         # what was measured and derived (summary, fit.detector)
        self.k = n_inputs
        self._pending = []          # samples before the settings are derived
        self._pending_n = 0
        self._carry = None          # rows of the last, unfinished block
        self._var_a = _Ring(FLOOR_BLOCKS)
        self._var_g = _Ring(FLOOR_BLOCKS)
        self._bias = _Ring(BIAS_BLOCKS, 3)
        self._lsb_var = (0.0, 0.0)
        self._floor = None          # (blocks seen, (accel, gyro) floor), see noise_floor
        self._n_blocks = 0
        self._open = _Blocks(n_inputs)
        self._log_t0 = None         # start of the first block (no guard at the log start)
        self._score = np.zeros(0)   # motion score of the open blocks (cached)
        self._next_hold = 0
        self.holds = []             # one record per emitted hold
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
        if self.config is None:
            self._pending.append((t, accel, gyro, temps))
            self._pending_n += len(t)
            if self._pending_n < DERIVE_SAMPLES:
                return Windows.empty(self.k)
            t, accel, gyro, temps = (np.concatenate(c) for c in zip(*self._pending))
            self._pending = []
            self._derive(t, accel, gyro)
        if self._carry is not None:
            t, accel, gyro, temps = (np.concatenate([c, x]) for c, x in
                                     zip(self._carry, (t, accel, gyro, temps)))
            self._carry = None
        full = len(t) // self.block_n * self.block_n
        self._carry = (t[full:], accel[full:], gyro[full:], temps[full:])
        if full:
            self._add_blocks(t[:full], accel[:full], gyro[:full], temps[:full])
        return self._classify(final=False)

    def finish(self):
        """Flush: the unfinished block and the open hold are closed (end of a log)."""
        if self.config is None:
            if self._pending_n < 2:
                return Windows.empty(self.k)
            t, a, g, tm = (np.concatenate(c) for c in zip(*self._pending))
            self._pending = []
            self._derive(t, a, g)
            self._carry = (t, a, g, tm)
        if self._carry is not None and len(self._carry[0]) >= max(3, self.block_n // 2):
            t, a, g, tm = self._carry
            self._add_blocks(t, a, g, tm, n=len(t))
        self._carry = None
        return self._classify(final=True)

    def noise_floor(self):
        """Return (accel, gyro) per-sample variance floors summed over axes, or None."""
        if len(self._var_a) < 4 or self.config is None:
            return None
        if self._floor is not None and self._floor[0] == len(self._var_a) == self._n_blocks:
            return self._floor[1]
        q = self.config.noise_quantile
        dof = 3 * (self.block_n - 1)
        bias = float(chi2_ppf(q, dof) / dof)
        fa = max(float(np.quantile(self._var_a.values(), q)), bias * self._lsb_var[0],
                 self.config.min_accel_var)
        fg = max(float(np.quantile(self._var_g.values(), q)), bias * self._lsb_var[1],
                 self.config.min_gyro_var)
        # cached until new blocks arrive (the node calls this on every message batch)
        self._floor = (len(self._var_a), (fa, fg))
        self._n_blocks = len(self._var_a)
        return fa, fg

    def settings(self):
        """Return the derived settings and measurements as a plain dict (or None)."""
        if self.derived is None:
            return None
        out = dict(self.derived)
        nf = self.noise_floor()
        if nf is not None:
            out['accel_noise_std'] = float(np.sqrt(nf[0] / 3))
            out['gyro_noise_std'] = float(np.sqrt(nf[1] / 3))
        return out

    def status(self):
        """Return a dict for progress reporting: still now, open-hold seconds, noise floor."""
        ob = self._open
        still = _bridge(self._score) if len(ob) else np.zeros(0, bool)
        run = 0.0
        if len(still) and still[-1]:
            moving = np.flatnonzero(~still)
            i = int(moving[-1]) + 1 if len(moving) else 0
            run = float(ob.t1[-1] - ob.t0[i])
        nf = self.noise_floor()
        return {'stationary': bool(len(still) and still[-1]), 'hold_seconds': run,
                'noise_floor': None if nf is None else {'accel_var': nf[0], 'gyro_var': nf[1]},
                'samples': self.samples}

    # ---------------------------------------------------------------- internal
    def _derive(self, t, accel, gyro):
        dt = np.diff(t)
        dt = dt[dt > 0]
        rate = 1.0 / float(np.median(dt)) if len(dt) else 1.0
        qa, qg = quantisation_step(accel), quantisation_step(gyro)
        self.config, self.block_n = self.requested.derive(rate, float(qa.max()),
                                                          float(qg.max()))
        try:
            self.config.validate()
        except ValueError as e:
            raise DetectorSettingsError(
                f'{e}: derived from a sample rate of {rate:.3g} Hz (median spacing of the first '
                f'{len(t)} IMU header stamps); check that the stamps are the sample times '
                '(seconds and nanoseconds)') from None
        self._lsb_var = (float(np.sum(qa ** 2)) / 12.0, float(np.sum(qg ** 2)) / 12.0)
        c = self.config
        self.derived = {'rate_hz': rate, 'block_samples': self.block_n,
                        'accel_lsb': float(qa.max()), 'gyro_lsb': float(qg.max()),
                        **{k: float(getattr(c, k)) for k in DERIVED},
                        'mean_sigmas': c.mean_sigmas, 'rotation_dps': c.rotation_dps,
                        'noise_quantile': c.noise_quantile,
                        'given': sorted(k for k in DERIVED
                                        if getattr(self.requested, k) not in (None, 0)
                                        or (k == 'guard_s' and self.requested.guard_s == 0))}

    def _add_blocks(self, t, accel, gyro, temps, n=None):
        n = n or self.block_n
        m = len(t) // n
        blk = _Blocks(self.k)
        tt = t.reshape(m, n)
        blk.t0, blk.t1, blk.tt = tt[:, 0], tt[:, -1], tt.mean(1)
        blk.n = np.full(m, n)
        blk.am, blk.av = _mean_var(accel.reshape(m, n, 3))
        blk.gm, blk.gv = _mean_var(gyro.reshape(m, n, 3))
        blk.tm = temps.reshape(m, n, self.k).mean(1)
        self._floor = None
        self._var_a.extend(blk.av.sum(1))
        self._var_g.extend(blk.gv.sum(1))
        if self._log_t0 is None:
            self._log_t0 = blk.t0[0]
        self._open.append(blk)

    def _scores(self, b, start):
        """Motion scores (< 1: still) of blocks ``start:`` of ``b`` (see the module doc).

        The jump test of block ``start - 1`` (cached) against the first new one is folded in.
        """
        nf = self.noise_floor()
        if nf is None:
            self._score[start:] = np.inf
            return
        c = self.config
        fa, fg = nf
        w_rot = np.radians(c.rotation_dps)
        thr_a, thr_g = c.accel_factor * fa, max(c.gyro_factor * fg, w_rot ** 2)
        sl = slice(start, None)
        va, vg = b.av[sl].sum(1), b.gv[sl].sum(1)
        quiet = (va < thr_a) & (vg < thr_g)
        self._bias.extend(b.gm[sl][quiet])
        bias = np.median(self._bias.values(), 0) if len(self._bias) else np.zeros(3)
        rot = np.sum((b.gm[sl] - bias) ** 2, 1) / w_rot ** 2
        self._score[sl] = np.maximum.reduce([va / thr_a, vg / thr_g, rot])
        # mean continuity between neighbours: a jump marks both blocks as moving
        lo = max(start - 1, 0)
        if len(b) - lo < 2:
            return
        n = np.maximum(b.n[lo:], 1)
        da = np.sum(np.diff(b.am[lo:], axis=0) ** 2, axis=1)
        g = float(np.median(np.linalg.norm(b.am[lo:], axis=1)))
        dtb = np.diff(b.tt[lo:])
        se = c.mean_sigmas ** 2 * thr_a * (1.0 / n[1:] + 1.0 / n[:-1])
        jump = da / np.maximum(se, (g * w_rot * dtb) ** 2)
        jump[dtb > 3.0 * self.block_n / self.derived['rate_hz']] = np.inf   # a gap
        idx = lo + np.arange(len(jump))
        self._score[idx] = np.maximum(self._score[idx], jump)
        self._score[idx + 1] = np.maximum(self._score[idx + 1], jump)

    def _classify(self, final):
        b = self._open
        if len(b) == 0:
            return Windows.empty(self.k)
        if len(self._var_a) < MATURE_BLOCKS:
            # the noise floor is still settling: score the whole open pool again
            self._score = np.zeros(0)
            self._bias.clear()
        if len(self._score) < len(b):
            start = len(self._score)
            self._score = np.r_[self._score, np.zeros(len(b) - start)]
            self._scores(b, start)
        still = _bridge(self._score)
        edges = np.diff(np.r_[0, still.astype(int), 0])
        run_starts = np.flatnonzero(edges == 1)
        run_ends = np.flatnonzero(edges == -1)
        out = []
        consumed = 0
        for s, e in zip(run_starts, run_ends):
            if not (e < len(b) or final):
                break
            # no guard where the log starts or ends: no pose change borders the run there
            edge = (s == 0 and b.t0[0] == self._log_t0, final and e == len(b))
            out.append(self._make_hold(b.take(slice(s, e)), self._score[s:e], edge))
            consumed = e
        if final:
            consumed = len(b)
        elif not (len(run_starts) and run_ends[-1] == len(b)):
            consumed = max(consumed, len(b) - 1)   # keep the last block for continuity
        else:
            consumed = max(consumed, run_starts[-1])
        if consumed:
            self._open = b.take(slice(consumed, None))
            self._score = self._score[consumed:]
        parts = [w for w in out if w is not None]
        return Windows.concat(parts) if parts else Windows.empty(self.k)

    def _settled(self, b, keep):
        """Return ``keep`` with the guards undone as far as their blocks agree with the hold.

        ``keep`` marks the blocks inside the derived guards, which are now an upper bound:
        going outwards from the kept core, each guard block is kept until the first one whose
        mean accel or gyro differs from the core's, so a guard removes only what the data
        show to differ (the settling of a placed unit, the start of a turn) and nothing
        beyond it.  Keeping samples whose mean is off by ``d`` (per axis) lowers the hold
        mean's error when ``d^2`` is below the noise variance they remove; with ``d``
        estimated from the block, that is ``z^2 < 2 dof`` for the chi-square statistic of the
        block-minus-core difference (``EDGE_Z2_PER_DOF``).  The per-sample noise is the
        floor, or what the scatter of the core's block means implies when that is larger
        (noise that is not white at the block scale: a ringing mount, bias wander).
        """
        nf = self.noise_floor()
        inner = np.flatnonzero(keep)
        if nf is None or len(inner) == 0 or len(inner) == len(keep):
            return keep
        core = slice(inner[0], inner[-1] + 1)
        n = b.n.astype(float)
        out = keep.copy()
        for j in range(core.start - 1, -1, -1):
            if not self._agrees(b, n, slice(j, j + 1), core, nf):
                break
            out[j] = True
        for j in range(core.stop, len(keep)):
            if not self._agrees(b, n, slice(j, j + 1), core, nf):
                break
            out[j] = True
        return out

    @staticmethod
    def _agrees(b, n, zone, core, nf):
        """Return True when the mean accel and gyro of blocks ``zone`` agree with ``core``'s."""
        m = core.stop - core.start
        n_zone, n_core = float(n[zone].sum()), float(n[core].sum())
        for mean, floor in ((b.am, nf[0]), (b.gm, nf[1])):
            ref = np.average(mean[core], 0, n[core])
            var = floor / 3.0
            if m >= 2:
                var = max(var, float(np.sum((mean[core] - ref) ** 2 * n[core, None]))
                          / (3.0 * (m - 1)))
            d = np.average(mean[zone], 0, n[zone]) - ref
            if np.sum(d ** 2) / (var * (1.0 / n_zone + 1.0 / n_core)) > EDGE_Z2_PER_DOF * 3:
                return False
        return True

    def _make_hold(self, b, score, edge=(False, False)):
        c = self.config
        if len(b) == 0:
            return None
        guard = lead = c.guard_s
        if 'guard_s' not in self.derived['given']:
            # derived guard: grows with the hold up to GUARD_MAX_S; at the end of a hold, where
            # a pose change begins slowly before the blocks see it (a hand starting to turn
            # the unit), by GUARD_TAIL_FRACTION of the run, at the start by GUARD_FRACTION
            run = b.t1[-1] - b.t0[0]
            lead = min(max(guard, GUARD_FRACTION * run), max(guard, GUARD_MAX_S))
            guard = min(max(guard, GUARD_TAIL_FRACTION * run), max(guard, GUARD_MAX_S))
        # guards and the minimum hold count samples (at the derived rate), not stamp
        # differences: with jittered stamps (a driver stamping on arrival) a 0.2 s guard
        # would drop two or three 0.1 s blocks by chance, and a run's first-to-last stamp
        # span is one sample interval short of the time it covers, so a run of exactly the
        # minimum hold failed it
        rate = self.derived['rate_hz']
        before = np.cumsum(b.n) - b.n
        after = int(np.sum(b.n)) - np.cumsum(b.n)
        keep = ((before >= (0 if edge[0] else round(lead * rate)))
                & (after >= (0 if edge[1] else round(guard * rate))))
        if 'guard_s' not in self.derived['given']:
            keep = self._settled(b, keep)
        b = b.take(keep)
        score = score[keep]
        if len(b) == 0 or np.sum(b.n) < round(c.min_hold_s * rate):
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
        mean_a = np.average(b.am, 0, b.n)
        self.holds.append({'hold': hold, 'start': float(b.t0[0]),
                           'duration': float(b.t1[-1] - b.t0[0]), 'face': face_of(mean_a),
                           'tilt_deg': tilt_deg(mean_a),
                           'stillness': float(np.clip(1.0 - np.quantile(score, 0.95), 0, 1))})
        return Windows(
            hold=np.full(m, hold, int),
            t0=b.t0[starts], t1=b.t1[np.r_[starts[1:], len(b)] - 1], n=n.astype(int),
            accel=wmean(b.am), gyro=wmean(b.gm),
            accel_var=wmean(b.av), gyro_var=wmean(b.gv), temp=temp, temp_rate=rate)


#: blocks up to this many samples are summed with one numpy add per sample row
SEQUENTIAL_SUM_N = 32


def _mean_var(x):
    """Return ``x.mean(1), x.var(1, ddof=1)`` of (m, n, c) blocks.

    numpy reduces the middle axis of a C-ordered (m, n, c) array one sample row after the
    other; for short blocks the same additions in the same order are done here with one
    vectorised add per row (several times faster, bit-identical: ``test_collection_fast``).
    """
    n = x.shape[1]
    if n > SEQUENTIAL_SUM_N:
        mean = np.add.reduce(x, axis=1) / n
        dev = x - mean[:, None, :]
        np.square(dev, out=dev)
        return mean, np.add.reduce(dev, axis=1) / (n - 1)
    total = x[:, 0].copy()
    for i in range(1, n):
        total += x[:, i]
    mean = total / n
    ss = np.square(x[:, 0] - mean)
    for i in range(1, n):
        d = x[:, i] - mean
        np.square(d, out=d)
        ss += d
    return mean, ss / (n - 1)


def _bridge(score):
    """Return still = score < 1, with short marginal runs between still blocks bridged.

    A run of at most ``BRIDGE_BLOCKS`` blocks scoring below ``BRIDGE_SCORE`` with still
    blocks on both sides is a false alarm of the block test (heavy-tailed or coarsely
    quantised noise; over an hour of blocks a few are expected), not motion.
    """
    still = score < 1.0
    edges = np.diff(np.r_[0, (~still).astype(int), 0])
    for s, e in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        if (s > 0 and e < len(score) and e - s <= BRIDGE_BLOCKS
                and np.max(score[s:e]) < BRIDGE_SCORE):
            still[s:e] = True
    return still


def tilt_deg(accel_mean):
    """Return the angle (deg) between the gravity-up direction and the nearest sensor axis."""
    u = np.abs(np.asarray(accel_mean, float))
    return float(np.degrees(np.arccos(np.clip(u.max() / np.linalg.norm(u), -1.0, 1.0))))


def detect(chunks, config=None, n_inputs=0):
    """Run the detector over an iterable of AlignedChunk and return all windows."""
    det = StationaryDetector(config, n_inputs)
    parts = []
    for ch in chunks:
        parts.append(det.update(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps))
    parts.append(det.finish())
    return Windows.concat(parts) if any(len(p) for p in parts) else Windows.empty(n_inputs)


def format_settings(settings):
    """Render derived detector settings (``StationaryDetector.settings``) in one line."""
    if not settings:
        return 'detector: no data'
    s = settings
    given = set(s.get('given', []))

    def mark(k):
        return '' if k in given else '*'

    pairs = (('accel', 'accel_lsb'), ('gyro', 'gyro_lsb'))
    lsb = ', '.join(f'{name} LSB {s[k]:.3g}' for name, k in pairs if s.get(k))
    noise = ''
    if 'accel_noise_std' in s:
        noise = (f', noise floor {s["accel_noise_std"]:.3g} m/s^2 / '
                 f'{s["gyro_noise_std"]:.3g} rad/s')
    return (f'detector ({s["rate_hz"]:.4g} Hz{", " + lsb if lsb else ""}{noise}): block '
            f'{s["block_samples"]} samples = {s["block_s"]:.3g} s{mark("block_s")}, min hold '
            f'{s["min_hold_s"]:.3g} s{mark("min_hold_s")}, guard {s["guard_s"]:.3g} s'
            f'{mark("guard_s")}, window {s["window_s"]:.3g} s{mark("window_s")}, variance '
            f'factors {s["accel_factor"]:.3g}{mark("accel_factor")}/{s["gyro_factor"]:.3g}'
            f'{mark("gyro_factor")}, rotation {s["rotation_dps"]:g} deg/s  (* derived)')


def format_holds(holds):
    """Render hold records (``StationaryDetector.holds``) as a table for people."""
    out = ['  hold   start [s]  duration [s]  face     tilt [deg]  stillness']
    for h in holds:
        out.append(f'  {h["hold"]:4d}  {h["start"]:10.2f}  {h["duration"]:12.2f}  '
                   f'{h["face"]:7s}  {h["tilt_deg"]:10.1f}  {h["stillness"]:9.2f}')
    return '\n'.join(out)
