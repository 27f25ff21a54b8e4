"""Streaming stationary detection whose settings are derived from the log itself.

Nothing needs tuning: from the first ``DERIVE_SAMPLES`` samples the detector measures the
sample rate and the quantisation step (LSB) of each sensor, and derives

* the *block*: ``block_n`` samples (about ``BLOCK_TARGET_S``, at least ``MIN_BLOCK_N``), so
  a 1 Hz chamber log and a 2 kHz IMU both get blocks with a defined variance;
* minimum hold, guard and window lengths from the block length (a 1 s hold at >= 50 Hz;
  the guard grows to GUARD_FRACTION of a long still run, at most GUARD_MAX_S);
* variance thresholds from the chi-square spread of a block variance with that many
  samples, relative to the noise floor (the ``noise_quantile`` of the block variances seen
  before, corrected for the chi-square bias, never below the quantisation noise LSB^2/12),
  so a navigation-grade triad and a hobby MEMS chip run the same code; the floor keeps
  adapting as the log goes on.

A block is *moving* when any of these holds:

* its accel or gyro variance (summed over axes) is above the threshold, or the gyro
  variance is above ``rotation_dps`` squared (hand tremor below that is tolerated);
* its mean gyro differs from the gyro bias (the median of the last quiet blocks, so thermal
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

The output is a function of the sample stream only, never of how it was cut into chunks
(the node gets live batches of any size, the CLI 20,000 messages re-cut by the aligner):
the settings come from exactly the first ``DERIVE_SAMPLES`` samples; blocks are counted
from the first sample; blocks are scored in groups of ``GROUP_BLOCKS``, each with the noise
floor and gyro bias (and |g| for the tilt bound) frozen when its group began, from every
block before it, so nothing a later chunk brings changes a score (the first group waits
until it is complete, or the log ends, and is scored with its own statistics); and a hold
is emitted only when its end is decided (``blocks.decided``: the last block's jump test is
in and a gap after it is too long or too strong to be bridged, or bridged). The floor's
quantile over up to FLOOR_BLOCKS variances is taken again at a group start once the blocks
seen grew by 1/FLOOR_REFRESH, the bias at every group start.

Cohesive: one streaming algorithm (derive, score blocks, bridge, make holds and windows)
whose state is shared by every step; split, its parts would pass that state around.
"""

import dataclasses
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.special import gammaincinv

from .blocks import Blocks, bridge, decided, mean_var, Ring
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
#: blocks per group: a block is scored with the noise floor and gyro bias frozen at the
#: start of its group (from the groups before); the first group with its own statistics
GROUP_BLOCKS = 200
#: ... the floor is taken again once the blocks seen grew by 1/FLOOR_REFRESH
FLOOR_REFRESH = 8
#: a derived guard is this fraction of the still run, between guard_s and GUARD_MAX_S
GUARD_FRACTION = 0.02
#: ... and at the end of a hold, before a pose change, this fraction
GUARD_TAIL_FRACTION = 0.05
GUARD_MAX_S = 1.0
#: a guard block is kept when the chi-square statistic of its mean against the hold's core
#: is below this many times its degrees of freedom (``_settled``: mean square error)
EDGE_Z2_PER_DOF = 2.0
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


class StationaryDetector:
    """Feed aligned chunks with ``update``; collect closed holds as Windows tables.

    The result is a function of the sample stream only: cutting it into other chunks
    gives the same holds, windows and records, bit for bit (see the module doc).
    """

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
        self._var_a = Ring(FLOOR_BLOCKS)
        self._var_g = Ring(FLOOR_BLOCKS)
        self._quiet = Ring(BIAS_BLOCKS, 4)   # quiet blocks' mean gyro (3) and |mean accel|
        self._lsb_var = (0.0, 0.0)
        self._chi_bias = 1.0        # chi-square quantile bias of the floor (see _floor_of)
        self._floor = None          # (blocks in the rings, floor): noise_floor() cache
        self._frozen = None         # (floor, gyro bias, |g|) scoring the current group
        self._floor_at = 0          # blocks in the rings when the frozen floor was taken
        self._quiet_at = 0          # ... quiet blocks when the frozen bias was taken
        self._g0 = None             # median |mean accel| of the first group (no quiet block)
        self._made = 0              # blocks made since the start (global index of the next)
        self._scored = 0            # blocks scored since the start
        self._pool0 = 0             # global index of the first open block
        self._open = Blocks(n_inputs)
        self._score = np.zeros(0)   # motion scores of the scored open blocks
        self._last_t = -np.inf      # newest stamp fed
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
        if len(t):
            self._last_t = max(self._last_t, float(np.max(t)))
        if self.config is None:
            self._pending.append((t, accel, gyro, temps))
            self._pending_n += len(t)
            if self._pending_n < DERIVE_SAMPLES:
                return Windows.empty(self.k)
            t, accel, gyro, temps = (np.concatenate(c) for c in zip(*self._pending))
            self._pending = []
            # exactly the first DERIVE_SAMPLES samples, however the stream was cut
            self._derive(t[:DERIVE_SAMPLES], accel[:DERIVE_SAMPLES], gyro[:DERIVE_SAMPLES])
        if self._carry is not None:
            t, accel, gyro, temps = (np.concatenate([c, x]) for c, x in
                                     zip(self._carry, (t, accel, gyro, temps)))
            self._carry = None
        full = len(t) // self.block_n * self.block_n
        self._carry = (t[full:], accel[full:], gyro[full:], temps[full:])
        if full:
            self._add_blocks(t[:full], accel[:full], gyro[:full], temps[:full])
        self._score_new(final=False)
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
        self._score_new(final=True)
        return self._classify(final=True)

    def noise_floor(self):
        """Return (accel, gyro) per-sample variance floors summed over axes, or None.

        Over every block scored so far (the last FLOOR_BLOCKS); the blocks themselves are
        scored with the floor frozen at their group's start (``_score_new``).
        """
        if self.config is None:
            return None
        seen = self._var_a.total
        if self._floor is None or self._floor[0] != seen:
            # cached until new blocks are scored (the node calls this on every batch)
            self._floor = (seen, self._floor_of(self._var_a.values(), self._var_g.values()))
        return self._floor[1]

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
        """Return a dict for progress reporting: still now, open-hold seconds, noise floor.

        Provisional (the last block's score and a trailing gap may still change); during
        the first group, before any block is scored, from the blocks seen so far (no floor
        reported yet).
        """
        ob = self._open
        score = self._score
        if not len(score) and len(ob):
            score = self._provisional_scores()
        still = bridge(score) if len(score) else np.zeros(0, bool)
        run = 0.0
        if len(still) and still[-1]:
            moving = np.flatnonzero(~still)
            i = int(moving[-1]) + 1 if len(moving) else 0
            run = float(ob.t1[len(still) - 1] - ob.t0[i])
        # the floor scoring the current group (noise_floor() takes a quantile over all blocks)
        nf = self._frozen[0] if self._frozen is not None else None
        return {'stationary': bool(len(still) and still[-1]), 'hold_seconds': run,
                'noise_floor': None if nf is None else {'accel_var': nf[0], 'gyro_var': nf[1]},
                'samples': self.samples}

    def unscored_since(self):
        """Return the first stamp of the samples not yet scored (inf: none is waiting).

        A hold closed later ends no earlier than a few blocks and the guard before it
        (``MotionCollector`` keeps its raw samples from there).
        """
        if self._pending:
            return float(self._pending[0][0][0])
        if self._made > self._scored:
            return float(self._open.t0[self._scored - self._pool0])
        if self._carry is not None and len(self._carry[0]):
            return float(self._carry[0][0])
        return np.inf

    def open_since(self):
        """Return the stamp no hold closed later can start before (the open blocks' start)."""
        if len(self._open):
            return float(self._open.t0[0])
        s = self.unscored_since()
        return s if np.isfinite(s) else self._last_t

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
        dof = 3 * (self.block_n - 1)
        self._chi_bias = float(chi2_ppf(self.config.noise_quantile, dof) / dof)
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
        blk = Blocks(self.k)
        tt = t.reshape(m, n)
        blk.t0, blk.t1, blk.tt = tt[:, 0], tt[:, -1], tt.mean(1)
        blk.n = np.full(m, n)
        blk.am, blk.av = mean_var(accel.reshape(m, n, 3))
        blk.gm, blk.gv = mean_var(gyro.reshape(m, n, 3))
        blk.tm = temps.reshape(m, n, self.k).mean(1)
        blk.fa, blk.fg = np.zeros(m), np.zeros(m)
        self._open.append(blk)
        self._made += m

    def _floor_of(self, va, vg):
        """Return the (accel, gyro) noise floor of block variances (summed over axes), or None.

        The ``noise_quantile`` of the variances corrected for the chi-square bias of that
        quantile, never below the quantisation noise nor the configured minimum.
        """
        if len(va) < 4:
            return None
        c = self.config
        q = c.noise_quantile
        return (max(float(np.quantile(va, q)), self._chi_bias * self._lsb_var[0],
                    c.min_accel_var),
                max(float(np.quantile(vg, q)), self._chi_bias * self._lsb_var[1],
                    c.min_gyro_var))

    def _thresholds(self, floor):
        c = self.config
        return (c.accel_factor * floor[0],
                max(c.gyro_factor * floor[1], np.radians(c.rotation_dps) ** 2))

    def _reference(self, quiet, fallback):
        """Return (gyro bias (3,), |g|) from quiet-block rows (gyro mean, |accel mean|)."""
        if len(quiet):
            med = _column_median(quiet)
            return med[:3], float(med[3])
        return np.zeros(3), fallback

    def _score_new(self, final):
        """Score the blocks made since the last call, group by group (``GROUP_BLOCKS``).

        A block of group j > 0 is scored with the noise floor and gyro bias frozen when
        group j began (from groups < j); the first group waits until it is complete (or the
        log ends) and is scored with its own statistics. So a block's score depends on the
        samples only, never on where the stream was cut.
        """
        b = self._open
        while self._scored < self._made:
            lo = self._scored - self._pool0
            if self._scored == 0:
                if self._made < GROUP_BLOCKS and not final:
                    return
                m = min(self._made, GROUP_BLOCKS)
                va, vg = b.av[:m].sum(1), b.gv[:m].sum(1)
                self._var_a.extend(va)
                self._var_g.extend(vg)
                floor = self._floor_of(self._var_a.values(), self._var_g.values())
                self._floor_at = self._var_a.total
                self._g0 = float(np.median(np.linalg.norm(b.am[:m], axis=1)))
                if floor is not None:
                    thr_a, thr_g = self._thresholds(floor)
                    quiet = (va < thr_a) & (vg < thr_g)
                    self._quiet.extend(_quiet_rows(b, slice(0, m), quiet))
                self._frozen = (floor,) + self._reference(self._quiet.values(), self._g0)
                self._quiet_at = self._quiet.total
                self._score_blocks(0, m)
            else:
                if self._scored % GROUP_BLOCKS == 0:
                    self._refresh()
                m = min(self._made - self._scored, GROUP_BLOCKS - self._scored % GROUP_BLOCKS)
                quiet = self._score_blocks(lo, lo + m)
                self._var_a.extend(b.av[lo:lo + m].sum(1))
                self._var_g.extend(b.gv[lo:lo + m].sum(1))
                if quiet is not None:
                    sl = slice(lo, lo + m)
                    self._quiet.extend(_quiet_rows(b, sl, quiet))
            self._scored += m

    def _refresh(self):
        """Freeze the statistics for the group that begins (from all blocks before it).

        The gyro bias follows every group; the floor, a quantile over up to FLOOR_BLOCKS
        variances, is taken again once the blocks seen grew by 1/FLOOR_REFRESH (or a group).
        """
        floor, bias, g = self._frozen
        seen = self._var_a.total
        if floor is None or seen - self._floor_at >= max(
                GROUP_BLOCKS, min(seen, FLOOR_BLOCKS) // FLOOR_REFRESH):
            floor = self._floor_of(self._var_a.values(), self._var_g.values())
            self._floor_at = seen
        if self._quiet.total != self._quiet_at:       # else the same median
            bias, g = self._reference(self._quiet.values(), self._g0)
            self._quiet_at = self._quiet.total
        self._frozen = (floor, bias, g)

    def _score_blocks(self, lo, hi):
        """Score open blocks ``lo:hi`` with the frozen statistics; return their quiet mask.

        Motion score (< 1: still, see the module doc); the jump test of block ``lo - 1``
        against block ``lo`` is folded into both (block ``lo - 1``'s score is final now).
        """
        b = self._open
        floor, bias, g = self._frozen
        if floor is None:
            self._score = np.concatenate([self._score, np.full(hi - lo, np.inf)])
            return None
        score, quiet = self._scores_of(b, lo, hi, floor, bias, g)
        b.fa[lo:hi], b.fg[lo:hi] = floor
        start = len(self._score)
        self._score = np.concatenate([self._score, score[1:]])
        if lo > 0:
            self._score[start - 1] = max(self._score[start - 1], score[0])
        return quiet

    def _scores_of(self, b, lo, hi, floor, bias, g):
        """Return (scores of blocks ``lo - 1:hi``, quiet mask of blocks ``lo:hi``).

        For the given statistics; the first score is block ``lo - 1``'s jump to block
        ``lo`` only (0 when lo = 0).
        """
        c = self.config
        thr_a, thr_g = self._thresholds(floor)
        w_rot = np.radians(c.rotation_dps)
        sl = slice(lo, hi)
        va, vg = b.av[sl].sum(1), b.gv[sl].sum(1)
        quiet = (va < thr_a) & (vg < thr_g)
        rot = np.sum((b.gm[sl] - bias) ** 2, 1) / w_rot ** 2
        score = np.empty(hi - lo + 1)
        score[0] = 0.0
        np.maximum(np.maximum(va / thr_a, vg / thr_g), rot, out=score[1:])
        # mean continuity between neighbours: a jump marks both blocks as moving
        j0 = max(lo - 1, 0)
        if hi - j0 >= 2:
            n = np.maximum(b.n[j0:hi], 1)
            da = np.sum(np.diff(b.am[j0:hi], axis=0) ** 2, axis=1)
            dtb = np.diff(b.tt[j0:hi])
            se = c.mean_sigmas ** 2 * thr_a * (1.0 / n[1:] + 1.0 / n[:-1])
            jump = da / np.maximum(se, (g * w_rot * dtb) ** 2)
            jump[dtb > 3.0 * self.block_n / self.derived['rate_hz']] = np.inf   # a gap
            off = 1 - (lo - j0)         # score index of block j0
            idx = off + np.arange(len(jump))
            score[idx] = np.maximum(score[idx], jump)
            score[idx + 1] = np.maximum(score[idx + 1], jump)
        return score, quiet

    def _provisional_scores(self):
        """Scores of the first group's blocks seen so far, from their own statistics."""
        b = self._open
        va, vg = b.av.sum(1), b.gv.sum(1)
        floor = self._floor_of(va, vg)
        if floor is None:
            return np.full(len(b), np.inf)
        thr_a, thr_g = self._thresholds(floor)
        quiet = (va < thr_a) & (vg < thr_g)
        bias, g = self._reference(_quiet_rows(b, slice(None), quiet),
                                  float(np.median(np.linalg.norm(b.am, axis=1))))
        return self._scores_of(b, 0, len(b), floor, bias, g)[0][1:]

    def _classify(self, final):
        """Emit the holds whose end is decided; drop the blocks nothing can use any more."""
        b = self._open
        k = len(self._score)
        if k == 0:
            return Windows.empty(self.k)
        state = decided(self._score, final)
        unknown = np.flatnonzero(state < 0)
        u = int(unknown[0]) if len(unknown) else k
        edges = np.diff(np.r_[0, (state[:u] == 1).astype(int), 0])
        run_starts = np.flatnonzero(edges == 1)
        run_ends = np.flatnonzero(edges == -1)
        out = []
        for s, e in zip(run_starts, run_ends):
            if e == u and not final:
                break                     # the open hold: its end is not decided yet
            # no guard where the log starts or ends: no pose change borders the run there
            edge = (self._pool0 + s == 0, final and e == k)
            out.append(self._make_hold(b.take(slice(s, e)), self._score[s:e], edge))
        if final:
            consumed = len(b)
        elif len(run_ends) and run_ends[-1] == u:
            consumed = int(run_starts[-1])
        else:
            consumed = max(u - 1, 0)      # keep the last decided block for the jump test
        if consumed:
            self._open = b.take(slice(consumed, None))
            self._score = self._score[consumed:]
            self._pool0 += consumed
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
        floor the run's last block was scored with, or what the scatter of the core's block
        means implies when that is larger (noise that is not white at the block scale: a
        ringing mount, bias wander).
        """
        nf = (float(b.fa[-1]), float(b.fg[-1]))
        inner = np.flatnonzero(keep)
        if len(inner) == 0 or len(inner) == len(keep):
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


def _column_median(x):
    """Return ``np.median(x, 0)`` of an (n, c) array (the same floats, one partition)."""
    y = np.array(x.T, order='C')
    k = len(x) // 2
    if len(x) % 2:
        y.partition(k, axis=1)
        return y[:, k]
    y.partition([k - 1, k], axis=1)
    return (y[:, k - 1] + y[:, k]) / 2


def _quiet_rows(b, sl, quiet):
    """Return the rows (mean gyro xyz, |mean accel|) of the quiet blocks of ``b[sl]``."""
    am = b.am[sl][quiet]
    return np.concatenate([b.gm[sl][quiet], np.sqrt(np.sum(am * am, 1))[:, None]], 1)


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
