"""The fast calibrate read/detect/collect path against simple reference implementations.

Each optimised piece (issue 13: detector histories in numpy rings, block statistics summed
row by row, the pose-change tape trimmed by parts, the all-bracketed interpolation, the
one-layout Imu decode, equal-size gathers, window views, zlib-ng's CRC, chi-square
quantiles from scipy.special) has its plain version here.  Every comparison is exact
(bit for bit): the unit pieces on random data, and ``collect_windows(motion=True)`` with
every reference swapped in against the shipped path on the simulated sessions of
``sim.scenarios`` and the real fixtures written as bags, at several chunk sizes.
"""

from collections import deque
import dataclasses
import os
import sys
import zlib

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
import pytest
from scipy.stats import chi2

from thermal_imu_calib import sim
from thermal_imu_calib.collection import blocks, motion, stationary
from thermal_imu_calib.io import align, cdr, mcap_read, packed
from thermal_imu_calib.io.columns import AlignedChunk, ImuColumns, TemperatureColumns
from thermal_imu_calib.app.collect import collect_windows

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'bench'))
import make_real_bags  # noqa: E402


# ------------------------------------------------------------------ reference versions
class RefRing:
    """``deque(maxlen)`` of rows: what the detector kept before the numpy ring."""

    def __init__(self, maxlen, width=None):
        self.d = deque(maxlen=maxlen)
        self.width = width
        self.total = 0

    def __len__(self):
        return len(self.d)

    def clear(self):
        self.d.clear()
        self.total = 0

    def extend(self, x):
        x = np.asarray(x, float)
        self.d.extend(x.tolist() if self.width is None else list(x))
        self.total += len(x)

    def values(self):
        if self.width is None:
            return np.asarray(self.d, float)
        return np.asarray(self.d, float).reshape(-1, self.width)


def ref_mean_var(x):
    return x.mean(1), x.var(1, ddof=1)


class RefTape:
    """The pose-change tape as it was: one concatenation and a mask on every trim."""

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

    def trim_before(self, lo):
        t, g, a, tm = self.cols()
        m = t >= lo
        self.parts = [(t[m], g[m], a[m], tm[m])]

    def __len__(self):
        return len(self.cols()[0])


def ref_interpolate(self, stamp_ns, max_gap_s):
    """TemperatureTrack.interpolate without the all-bracketed shortcut."""
    s = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
    n, t, v = s.size, self._t, self._v
    if t.size == 0:
        return np.full(n, np.nan), np.full(n, np.inf)
    hi = np.clip(np.searchsorted(t, s, side='left'), 1, max(t.size - 1, 1))
    lo = hi - 1
    if t.size == 1:
        hi = lo
    t0, t1 = t[lo], t[hi]
    d0 = (s - t0).astype(np.float64) / align.NS
    d1 = (t1 - s).astype(np.float64) / align.NS
    span = (t1 - t0).astype(np.float64) / align.NS
    interp = (d0 >= 0) & (d1 >= 0) & (span <= max_gap_s) & (span > 0)
    out = np.where(np.abs(d1) < np.abs(d0), v[hi], v[lo])
    age = np.minimum(np.abs(d0), np.abs(d1))
    w = d0[interp] / span[interp]
    out[interp] = v[lo][interp] * (1.0 - w) + v[hi][interp] * w
    age[interp] = 0.0
    return out, age


def ref_resolve(self, imu, extra):
    """StreamAligner._resolve as it was: each input interpolated on its own."""
    temps = np.empty((len(imu), self.n_inputs))
    ages = np.empty((len(imu), self.n_inputs))
    for j, track in enumerate(self.tracks):
        temps[:, j], ages[:, j] = ref_interpolate(track, imu.stamp_ns, self.max_gap_s)
    return AlignedChunk(imu, temps, ages, extra)


def ref_gather(buf, starts, lengths):
    """Concatenate the pieces with one bytes join."""
    raw = buf.tobytes()
    return np.frombuffer(b''.join(raw[a:a + n] for a, n in zip(np.asarray(starts).tolist(),
                                                               np.asarray(lengths).tolist())),
                         np.uint8)


def ref_take_rows(buf, width, starts):
    return sliding_window_view(buf, width)[starts]


def ref_decode_imu_packed(buf, starts, lengths):
    """The general (per layout group) decode of packed Imu payloads."""
    return cdr._imu_columns(len(lengths), cdr._packed_groups(buf, starts, lengths,
                                                             cdr._IMU_FIELDS, 'Imu'))


def ref_chi2_ppf(p, dof):
    return chi2.ppf(p, dof)


REFERENCES = [(stationary, 'Ring', RefRing), (stationary, 'mean_var', ref_mean_var),
              (stationary, 'chi2_ppf', ref_chi2_ppf), (motion, '_Tape', RefTape),
              (align.TemperatureTrack, 'interpolate', ref_interpolate),
              (align.StreamAligner, '_resolve', ref_resolve),
              (packed, 'gather', ref_gather), (mcap_read, 'crc32', zlib.crc32),
              (packed, 'windows', sliding_window_view), (packed, 'take_rows', ref_take_rows),
              (mcap_read, 'take_rows', ref_take_rows), (cdr, 'take_rows', ref_take_rows),
              (cdr, 'decode_imu_packed', ref_decode_imu_packed)]


def collect(path, reference, monkeypatch, chunk_size):
    with monkeypatch.context() as m:
        if reference:
            for owner, name, value in REFERENCES:
                m.setattr(owner, name, value)
        return collect_windows(path, motion=True, chunk_size=chunk_size, progress=False)


def assert_same(a, b, where=''):
    """Exact equality of nested results (arrays bit for bit, NaN equal to NaN)."""
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=True), where
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            if f.name != 'seconds':
                assert_same(getattr(a, f.name), getattr(b, f.name), f'{where}.{f.name}')
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            assert_same(a[k], b[k], f'{where}[{k}]')
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f'{where}[{i}]')
    elif hasattr(a, '__dict__'):
        assert_same(vars(a), vars(b), where)
    else:
        assert a == b or (a != a and b != b), (where, a, b)


# ------------------------------------------------------------------ whole path, exact
@pytest.fixture(scope='module')
def logs(tmp_path_factory):
    """The sim.scenarios sessions and the real fixtures, written as .mcap logs."""
    d = tmp_path_factory.mktemp('logs')
    make_real_bags.main(str(d))
    out = sorted(str(d / f) for f in os.listdir(d) if f.endswith('.mcap'))
    for name in ('hand-held', 'imutk-procedure', 'chamber-2hz'):
        path = str(d / f'{name}.mcap')
        sim.write_scenario(path, name, 1)
        out.append(path)
    return out


@pytest.mark.parametrize('chunk_size', [20000, 777])
def test_collect_windows_is_the_reference_bit_for_bit(logs, monkeypatch, chunk_size):
    holds = 0
    for path in logs:
        ref = collect(path, True, monkeypatch, chunk_size)
        fast = collect(path, False, monkeypatch, chunk_size)
        assert_same(ref, fast, os.path.basename(path))
        holds += len(fast.holds)
        assert fast.windows.accel.dtype == np.float64
    assert holds > 50   # the comparison is over real detections, not empty tables


def test_collect_windows_does_not_depend_on_the_chunk_size(logs, monkeypatch):
    # the reader's chunks, re-cut by the temperature aligner: the same collection
    for path in logs:
        want = collect(path, False, monkeypatch, 20000)
        got = collect(path, False, monkeypatch, 50)
        assert got.motion['dropped'] == want.motion['dropped']
        got.motion = want.motion = None              # peak_bytes depends on the chunks
        # the input gate keeps temperature stamps (to judge their interval) in the reader's
        # chunks, up to a limit checked per chunk: not part of the collection
        got.gate.temp_stamps = want.gate.temp_stamps = None
        assert_same(got, want, os.path.basename(path))


def test_the_references_are_really_swapped_in(logs, monkeypatch):
    # a broken reference must change the result, so the comparison above can fail
    def wrong(x):
        mean, var = ref_mean_var(x)
        return mean, var * (1 + 1e-12)
    with monkeypatch.context() as m:
        m.setattr(stationary, 'mean_var', wrong)
        bad = collect_windows(logs[0], motion=True, progress=False)
    good = collect_windows(logs[0], motion=True, progress=False)
    assert not np.array_equal(bad.windows.accel_var, good.windows.accel_var)


# ------------------------------------------------------------------ pieces, exact
def test_ring_keeps_what_a_bounded_deque_keeps():
    rng = np.random.default_rng(1)
    for maxlen, width in ((7, None), (50, None), (11, 3)):
        ring, ref = blocks.Ring(maxlen, width), RefRing(maxlen, width)
        for step in range(60):
            n = int(rng.integers(0, 2 * maxlen + 3))
            x = rng.normal(size=(n,) if width is None else (n, width))
            ring.extend(x)
            ref.extend(x)
            if step % 17 == 16:
                ring.clear()
                ref.clear()
            assert len(ring) == len(ref) and ring.total == ref.total
            got, want = ring.values(), ref.values()
            assert got.shape == want.shape
            assert np.array_equal(np.sort(got, axis=0), np.sort(want, axis=0))
            if len(ref):
                assert np.quantile(got, 0.05) == np.quantile(want, 0.05)
                assert np.array_equal(np.median(got, 0), np.median(want, 0))


@pytest.mark.parametrize('n', [3, 5, 8, 9, 10, 16, 20, 32, 33, 40, 200])
def test_block_mean_and_variance_are_numpys(n):
    rng = np.random.default_rng(n)
    for m in (1, 7, 300):
        x = rng.normal(size=(m, n, 3)) * 1e-3 + np.array([0.1, -0.2, 9.81])
        mean, var = blocks.mean_var(x)
        rmean, rvar = ref_mean_var(x)
        assert np.array_equal(mean, rmean) and np.array_equal(var, rvar), (n, m)


def test_chi2_quantile_is_scipy_stats():
    for dof in (6, 12, 27, 297, 2997):
        for p in (0.999, 0.05, 0.01, 0.5):
            assert stationary.chi2_ppf(p, dof) == chi2.ppf(p, dof)


def test_tape_trims_like_the_reference_sorted_or_not():
    rng = np.random.default_rng(2)
    for shuffle in (False, True):
        tape, ref = motion._Tape(2), RefTape(2)
        t0 = 0.0
        for _ in range(40):
            n = int(rng.integers(0, 30))
            t = t0 + np.cumsum(rng.uniform(0.005, 0.015, n))
            if shuffle and n > 2:
                t = rng.permutation(t)
            t0 = float(t.max()) if n else t0
            cols = (t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                    rng.normal(size=(n, 2)))
            tape.append(*cols)
            ref.append(*cols)
            lo = t0 - rng.uniform(0.0, 0.5)
            tape.trim_before(lo)
            ref.trim_before(lo)
            assert len(tape) == len(ref)
            assert tape.end() == ref.end()
            for a, b in zip(tape.select(lo + 0.1, t0 - 0.05), ref.select(lo + 0.1, t0 - 0.05)):
                assert np.array_equal(a, b)


def test_inputs_stamped_alike_share_one_plan_with_the_same_result():
    rng = np.random.default_rng(6)
    st = np.cumsum(rng.integers(50_000_000, 150_000_000, 300)).astype(np.int64)
    tc = [TemperatureColumns(st, 20 + rng.normal(size=300), 'a'),
          TemperatureColumns(st.copy(), 30 + rng.normal(size=300), 'b'),
          TemperatureColumns(st[::2], 40 + rng.normal(size=150), 'c')]
    imu_st = np.sort(rng.integers(st[0] - 10**9, st[-1] + 10**9, 4000))
    imu = ImuColumns(imu_st, np.zeros((4000, 3)), np.zeros((4000, 3)))
    fast = align.StreamAligner(3)
    got = fast.push_columns(imu, tc) + fast.finish()
    ref = align.StreamAligner(3)
    ref._resolve = ref_resolve.__get__(ref)
    want = ref.push_columns(imu, tc) + ref.finish()
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert np.array_equal(a.temps, b.temps) and np.array_equal(a.temp_age, b.temp_age)


def test_interpolation_shortcut_is_the_general_formula():
    rng = np.random.default_rng(3)
    track = align.TemperatureTrack(np.inf)
    st = np.cumsum(rng.integers(50_000_000, 150_000_000, 400)).astype(np.int64)
    track.add(st, 20.0 + np.cumsum(rng.normal(size=400)) * 0.01)
    inside = rng.integers(st[0], st[-1], 5000)
    got = track.interpolate(inside, 5.0)
    assert np.all(got[1] == 0.0)                  # every stamp bracketed: the shortcut
    want = ref_interpolate(track, inside, 5.0)
    assert all(np.array_equal(a, b) for a, b in zip(got, want))
    outside = np.r_[inside, st[0] - 10**9, st[-1] + 10**9]
    got = track.interpolate(outside, 5.0)
    want = ref_interpolate(track, outside, 5.0)
    assert all(np.array_equal(a, b) for a, b in zip(got, want))


def test_gather_and_windows_are_plain_slicing():
    rng = np.random.default_rng(4)
    buf = rng.integers(0, 256, 5000).astype(np.uint8)
    starts = rng.integers(0, 4900, 777)
    for width in (1, 8, 31):
        assert np.array_equal(packed.windows(buf, width), sliding_window_view(buf, width))
        assert not packed.windows(buf, width).flags.writeable
        for idx in (starts, starts[:0], starts[:1]):
            got = packed.take_rows(buf, width, idx)
            assert got.shape == (len(idx), width) and got.dtype == np.uint8
            assert np.array_equal(got, ref_take_rows(buf, width, idx))
    for same in (True, False):
        starts = np.sort(rng.choice(4000, 300, replace=False))
        lengths = np.full(300, 9) if same else rng.integers(0, 40, 300)
        assert np.array_equal(packed.gather(buf, starts, lengths),
                              ref_gather(buf, starts, lengths))
    assert mcap_read.crc32(buf.tobytes()) == zlib.crc32(buf.tobytes())


def test_one_layout_imu_decode_is_the_general_decode():
    rng = np.random.default_rng(5)
    n = 500
    st = (1_700_000_000 * 10**9 + np.arange(n) * 10_000_000).astype(np.int64)
    cols = ImuColumns(st, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), 'imu_link')
    raws = cdr.encode_imu(cols)
    other = cdr.encode_imu(ImuColumns(st[:5], cols.accel[:5], cols.gyro[:5], 'a_longer_frame'))
    for msgs in (raws, raws[:1], raws[:200] + other + raws[200:]):
        sizes = np.array([len(r) for r in msgs])
        pad = rng.integers(0, 9, len(msgs))            # gaps between payloads in the buffer
        starts = np.cumsum(np.r_[0, sizes[:-1] + pad[:-1]]) + 3
        buf = np.zeros(int(starts[-1] + sizes[-1] + 5), np.uint8)
        for s, r in zip(starts, msgs):
            buf[s:s + len(r)] = np.frombuffer(r, np.uint8)
        got = cdr.decode_imu_packed(buf, starts, sizes)
        for want in (ref_decode_imu_packed(buf, starts, sizes), cdr.decode_imu(msgs)):
            assert got.frame_id == want.frame_id
            assert np.array_equal(got.stamp_ns, want.stamp_ns)
            assert np.array_equal(got.accel, want.accel) and got.accel.dtype == np.float64
            assert np.array_equal(got.gyro, want.gyro)
    bad = bytearray(raws[0])
    bad[1] = 0                                         # big-endian: refused as before
    buf = np.frombuffer(bytes(bad) * 3, np.uint8)
    with pytest.raises(ValueError, match='big-endian'):
        cdr.decode_imu_packed(buf, np.arange(3) * len(bad), np.full(3, len(bad)))
