"""Block statistics of the stationary detector (``stationary``) and its still/moving decisions.

Pure pieces with no detector state: the bounded history ``Ring``, the block table
``Blocks``, the block mean and variance (``mean_var``), and the bridging of isolated false
alarms, on the whole log (``bridge``) and as far as the blocks seen so far decide it
(``decided``), which is what makes the detector's holds independent of how the stream is cut.
"""

import numpy as np

#: isolated false alarms: runs this short and this marginal between still blocks are still
BRIDGE_BLOCKS = 2
BRIDGE_SCORE = 4.0


class Ring:
    """The last ``maxlen`` rows appended (like ``deque(maxlen=...)``), in one numpy array.

    ``values`` is not in insertion order once the ring has wrapped: only order-free
    statistics (quantiles, medians) are taken of it.
    """

    def __init__(self, maxlen, width=None):
        self.maxlen = int(maxlen)
        self._shape = () if width is None else (int(width),)
        self._a = np.empty((0,) + self._shape)
        self._total = 0
        self._seen = 0

    def __len__(self):
        return min(self._total, self.maxlen)

    @property
    def total(self):
        """Rows appended since the last ``clear`` (kept or not)."""
        return self._seen

    def clear(self):
        """Forget every row."""
        self._total = 0
        self._seen = 0

    def extend(self, x):
        """Append rows ``x`` (dropping the oldest beyond ``maxlen``)."""
        x = np.asarray(x, float).reshape((-1,) + self._shape)
        self._seen += len(x)
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


class Blocks:
    """Block statistics as growing column arrays.

    ``fa``/``fg``: the (accel, gyro) noise floor the block was scored with (0 until scored).
    """

    names = ('t0', 't1', 'n', 'am', 'av', 'gm', 'gv', 'tm', 'tt', 'fa', 'fg')

    def __init__(self, k):
        self.k = k
        self.clear()

    def clear(self):
        """Empty every column."""
        self.t0 = np.zeros(0)
        self.t1 = np.zeros(0)
        self.n = np.zeros(0, int)
        self.am = np.zeros((0, 3))
        self.av = np.zeros((0, 3))
        self.gm = np.zeros((0, 3))
        self.gv = np.zeros((0, 3))
        self.tm = np.zeros((0, self.k))
        self.tt = np.zeros(0)  # mean time of samples, for temperature rates
        self.fa = np.zeros(0)
        self.fg = np.zeros(0)

    def __len__(self):
        return len(self.t0)

    def append(self, other):
        """Append the blocks of ``other`` (another Blocks)."""
        for name in self.names:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(other, name)]))

    def take(self, sl):
        """Return the blocks ``sl`` (slice, index array or mask) as a new Blocks."""
        out = Blocks(self.k)
        for name in self.names:
            setattr(out, name, getattr(self, name)[sl])
        return out


#: blocks up to this many samples are summed with one numpy add per sample row
SEQUENTIAL_SUM_N = 32


def mean_var(x):
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


def bridge(score):
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


def decided(score, final):
    """Return per block 1 (still), 0 (moving) or -1 (not decided yet).

    What ``bridge`` would decide on the whole log, as far as the blocks seen decide it.
    A score is final once the next block's jump test is in (or the log ended): the last
    block, if still by its score, is undecided. A moving run that ``bridge`` could bridge
    is undecided until the block after it is final (still: bridged) or the log ends (not
    bridged). The first block (the log's start, or a decided moving block or the start of
    the open hold) never begins a bridged run.
    """
    k = len(score)
    raw = score < 1.0
    state = raw.astype(np.int8)
    known = k if final else k - 1
    if not final and raw[-1]:
        state[-1] = -1
    d = np.diff(np.r_[0, (~raw).astype(np.int8), 0])
    rs, re = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    if len(rs):
        peak = np.maximum.reduceat(np.r_[score, 0.0], np.c_[rs, re].ravel())[::2]
        cand = (rs > 0) & (re - rs <= BRIDGE_BLOCKS) & (peak < BRIDGE_SCORE)
        bridged = cand & (re < known)
        label = np.where(bridged, 1, np.where(cand & ~bridged & (not final), -1, 0))
        state[~raw] = np.repeat(label.astype(np.int8), re - rs)
    return state
