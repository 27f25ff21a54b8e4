"""Streaming stationary detection whose settings are derived from the log itself.

Nothing needs tuning: from the first ``DERIVE_SAMPLES`` samples the detector measures the
sample rate and the quantisation step (LSB) of each sensor and derives its block length,
hold, guard and window lengths and variance factors (``detector_config.DetectorConfig``).
The variance thresholds are those factors times the noise floor: the ``noise_quantile`` of
the block variances seen before, corrected for the chi-square bias, never below the
quantisation noise LSB^2/12, so a navigation-grade triad and a hobby MEMS chip run the same
code; the floor keeps adapting as the log goes on.

A block is *moving* when any of these holds:

* its accel or gyro variance (summed over axes) is above the threshold, or the gyro
  variance is above ``rotation_dps`` squared (hand tremor below that is tolerated);
* its mean gyro differs from the gyro bias (the median of the last quiet blocks, so thermal
  bias drift is followed) by more than ``rotation_dps``: a rotation about gravity, which
  leaves the accelerometer unchanged, is seen here;
* its mean accel differs from a neighbour's by more than ``mean_sigmas`` standard errors
  *and* by more than gravity turned at ``rotation_dps`` over one block (a slow tilt).

Thermal drift inside a hold moves the means by far less than either bound, so only motion
splits a hold. Runs of still blocks become *holds* (``holds.make_hold``: guards trimmed,
short ones dropped, each cut into windows of ``window_s``, ``segments.Windows``).
``holds`` keeps one record per hold (start, duration, stillness score). Memory stays small
for hours of data, and the same class runs offline (CLI) and live (node).

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
"""

import numpy as np

from .blocks import Blocks, bridge, decided, mean_var, Ring
from .detector_config import (chi2_ppf, DERIVED, DetectorConfig,  # noqa: F401  (re-exported)
                              DetectorSettingsError, format_settings, quantisation_step)
from .holds import format_holds, make_hold, tilt_deg  # noqa: F401  (re-exported)
from .segments import Windows

#: samples used to measure the rate and the quantisation step before detection starts
DERIVE_SAMPLES = 200
#: blocks per group: a block is scored with the noise floor and gyro bias frozen at the
#: start of its group (from the groups before); the first group with its own statistics
GROUP_BLOCKS = 200
#: ... the floor is taken again once the blocks seen grew by 1/FLOOR_REFRESH
FLOOR_REFRESH = 8
#: quiet-block gyro means kept for the bias reference
BIAS_BLOCKS = 2000
#: block variances kept for the noise floor
FLOOR_BLOCKS = 200_000


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

    def _make_hold(self, b, score, edge=(False, False)):
        """Return the Windows of a still run (None: too short), its record kept in ``holds``."""
        made = make_hold(b, score, self._next_hold, self.config, self.derived['rate_hz'],
                         'guard_s' not in self.derived['given'], self.k, edge)
        if made is None:
            return None
        windows, record = made
        self._next_hold += 1
        self.holds.append(record)
        return windows


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


def detect(chunks, config=None, n_inputs=0):
    """Run the detector over an iterable of AlignedChunk and return all windows."""
    det = StationaryDetector(config, n_inputs)
    parts = []
    for ch in chunks:
        parts.append(det.update(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps))
    parts.append(det.finish())
    return Windows.concat(parts) if any(len(p) for p in parts) else Windows.empty(n_inputs)
