"""Temperature alignment: track interpolation/hold rules and streaming equivalence."""

import math

import numpy as np
import pytest

from thermal_imu_calib.io.align import StreamAligner, TemperatureTrack
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

S = 1_000_000_000


def _track(stamps_s, values, history=math.inf):
    tr = TemperatureTrack(history)
    tr.add((np.asarray(stamps_s) * S).astype(np.int64), values)
    return tr


def test_interpolate_inside_gap_edges_and_empty():
    tr = _track([0.0, 1.0, 2.0, 10.0], [20.0, 21.0, 23.0, 30.0])
    q = (np.array([0.5, 1.5, 2.0, 3.0, 9.0, -2.0, 12.5, 1.0]) * S).astype(np.int64)
    v, age = tr.interpolate(q, max_gap_s=2.0)
    np.testing.assert_allclose(v, [20.5, 22.0, 23.0, 23.0, 30.0, 20.0, 30.0, 21.0])
    np.testing.assert_allclose(age, [0, 0, 0, 1.0, 1.0, 2.0, 2.5, 0])
    # The same gap interpolates once the limit allows it.
    v, age = tr.interpolate(int(6 * S), max_gap_s=8.0)
    assert v[0] == pytest.approx(26.5) and age[0] == 0
    empty = TemperatureTrack()
    v, age = empty.interpolate(np.array([0, 1]), 1.0)
    assert np.all(np.isnan(v)) and np.all(np.isinf(age))
    one = _track([5.0], [40.0])
    v, age = one.interpolate(np.array([4 * S, 5 * S, 7 * S]), 1.0)
    np.testing.assert_allclose(v, 40.0)
    np.testing.assert_allclose(age, [1.0, 0.0, 2.0])


def test_add_sorts_dedups_drops_nan_and_bounds_history():
    tr = TemperatureTrack(max_history_s=10.0)
    tr.add(np.array([3, 1]) * S, [3.0, 1.0])
    tr.add(2 * S, 2.0)
    tr.add(2 * S, 2.5)  # duplicate stamp: last value wins
    tr.add(4 * S, np.nan)  # no reading
    assert tr.stamps_ns.tolist() == [S, 2 * S, 3 * S]
    assert tr.values.tolist() == [1.0, 2.5, 3.0]
    tr.add(np.arange(4, 30) * S, np.arange(4, 30, dtype=float))
    # 10 s of history behind the newest sample plus one bracketing sample.
    assert tr.stamps_ns[0] == 18 * S and tr.newest_ns == 29 * S
    with pytest.raises(ValueError, match='matching'):
        tr.add(np.array([1, 2]), [1.0])


def test_latest_is_causal_hold_last():
    tr = _track([1.0, 2.0, 3.0], [10.0, 20.0, 30.0])
    v, age = tr.latest((np.array([2.5, 3.0, 7.0, 0.5]) * S).astype(np.int64))
    np.testing.assert_allclose(v, [20.0, 30.0, 30.0, 10.0])
    np.testing.assert_allclose(age, [0.5, 0.0, 4.0, 0.5])
    v, age = TemperatureTrack().latest(0)
    assert np.isnan(v[0]) and np.isinf(age[0])


def _scenario(rng, n=6000, dt=0.005):
    """IMU at 200 Hz, two temperature inputs at ~1 Hz / ~7 Hz, one with a 6 s dropout."""
    stamps = (np.arange(n) * dt * S).astype(np.int64) + 123
    imu = ImuColumns(stamps, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), 'imu')
    ta = np.sort(rng.uniform(0, n * dt, 30))
    tb = np.arange(0, n * dt, 0.14)
    tb = tb[(tb < 10.0) | (tb > 16.0)]  # dropout longer than max_gap_s
    temps = [TemperatureColumns((ta * S).astype(np.int64), 20 + ta * 0.1),
             TemperatureColumns((tb * S).astype(np.int64) + 7, 40 - tb * 0.05)]
    return imu, temps


def _feed(aligner, imu, temps, rng, lag_s=0.3):
    """Push random-size chunks; temperature samples arrive ``lag_s`` after their stamp."""
    out, i, n = [], 0, len(imu)
    sent = [0] * len(temps)
    while i < n:
        j = min(n, i + int(rng.integers(1, 900)))
        now = imu.stamp_ns[j - 1]
        new = []
        for k, tc in enumerate(temps):
            e = int(np.searchsorted(tc.stamp_ns, now - int(lag_s * S), side='right'))
            e = max(e, sent[k])
            new.append(TemperatureColumns(tc.stamp_ns[sent[k]:e], tc.temperature[sent[k]:e]))
            sent[k] = e
        extra = {'imu_log_time_ns': imu.stamp_ns[i:j] + 1, 'row': list(range(i, j))}
        out += aligner.push_columns(imu.slice(slice(i, j)), new, extra)
        assert aligner.pending <= (6.0 + 0.3) / 0.005 + 900  # the dropout + lag + one chunk
        i = j
    rest = [TemperatureColumns(tc.stamp_ns[s:], tc.temperature[s:]) for tc, s in zip(temps, sent)]
    out += aligner.push_columns(ImuColumns.empty(), rest, {'imu_log_time_ns': np.zeros(0, int),
                                                           'row': []})
    out += aligner.finish()
    return out


def test_stream_aligner_equals_whole_log_interpolation():
    # Exact, including a 6 s dropout (> max_gap_s, < max_wait_s) and samples logged late.
    rng = np.random.default_rng(11)
    imu, temps = _scenario(rng)
    max_gap = 2.0
    out = _feed(StreamAligner(2, max_gap_s=max_gap), imu, temps, rng)
    assert len(out) > 5
    rows = [r for c in out for r in c.extra['row']]
    assert rows == list(range(len(imu)))  # every row once, in order
    for c in out:
        assert c.temps.shape == (len(c), 2) == c.temp_age.shape
        np.testing.assert_array_equal(c.extra['imu_log_time_ns'], c.imu.stamp_ns + 1)
    temps_got = np.concatenate([c.temps for c in out])
    age_got = np.concatenate([c.temp_age for c in out])
    np.testing.assert_array_equal(np.concatenate([c.imu.accel for c in out]), imu.accel)
    for k, tc in enumerate(temps):
        ref = TemperatureTrack(math.inf)
        ref.add(tc.stamp_ns, tc.temperature)
        ref_v, ref_age = ref.interpolate(imu.stamp_ns, max_gap)
        # Rows before the first sample of the 1 Hz input: held, with the age reported.
        np.testing.assert_allclose(temps_got[:, k], ref_v, rtol=0, atol=1e-12)
        np.testing.assert_allclose(age_got[:, k], ref_age, rtol=0, atol=1e-9)
    # The dropout of input 1 is visible as held values with growing age.
    in_gap = (imu.t > 11.0) & (imu.t < 15.0)
    assert np.all(age_got[in_gap, 1] > 1.0)
    assert np.all(age_got[(imu.t > 1.0) & (imu.t < 9.0), 1] == 0)


def test_silent_input_does_not_hold_rows_forever():
    n = 4000
    imu = ImuColumns((np.arange(n) * 0.01 * S).astype(np.int64), np.zeros((n, 3)),
                     np.zeros((n, 3)))
    aligner = StreamAligner(1, max_gap_s=0.5, max_wait_s=1.0)
    first = aligner.push_columns(imu.slice(slice(0, 10)), [
        TemperatureColumns(np.array([0, S // 20]), np.array([25.0, 25.5]))])
    assert sum(len(c) for c in first) == 6  # rows up to the newest sample (0.05 s)
    released = 0
    for i in range(10, n, 100):
        got = aligner.push_columns(imu.slice(slice(i, i + 100)), [TemperatureColumns.empty()])
        released += sum(len(c) for c in got)
        assert aligner.pending <= 1.0 / 0.01 + 100 + 5
    last = aligner.finish()
    assert released + sum(len(c) for c in last) + 6 == n
    assert last[-1].temps[-1, 0] == 25.5
    assert last[-1].temp_age[-1, 0] == pytest.approx(39.99 - 0.05)


def test_zero_inputs_pass_straight_through_and_names_select_topics():
    imu = ImuColumns(np.arange(5, dtype=np.int64), np.ones((5, 3)), np.zeros((5, 3)))
    out = StreamAligner(0).push_columns(imu, [])
    assert len(out) == 1 and out[0].temps.shape == (5, 0) and out[0].temp_age.shape == (5, 0)

    class Chunk:
        pass

    ch = Chunk()
    ch.imu = imu
    ch.imu_log_time_ns = np.arange(5) + 100
    ch.imu_raw = [b'%d' % i for i in range(5)]
    ch.temps = {'/b': TemperatureColumns(np.array([0, 10]), np.array([1.0, 2.0])),
                '/a': TemperatureColumns(np.array([0, 10]), np.array([5.0, 5.0]))}
    out = StreamAligner(['/a', '/b'], max_gap_s=1.0).push(ch)
    assert len(out) == 1
    np.testing.assert_allclose(out[0].temps[:, 0], 5.0)
    np.testing.assert_allclose(out[0].temps[:, 1], 1.0 + np.arange(5) / 10)
    assert out[0].extra['imu_raw'] == ch.imu_raw
    assert out[0].extra['imu_log_time_ns'].tolist() == [100, 101, 102, 103, 104]
    with pytest.raises(KeyError, match="no temperature input '/c'"):
        StreamAligner(['/c'], 1.0).push(ch)
    with pytest.raises(ValueError, match='built for 2'):
        StreamAligner(2).push_columns(imu, [])


def test_aligner_over_a_real_log(tmp_path):
    rng = np.random.default_rng(3)
    imu, temps = _scenario(rng, n=3000)
    path = tmp_path / 'log.mcap'
    write_columns(path, '/imu', imu, {'/ta': temps[0], '/tb': temps[1]})
    aligner = StreamAligner(['/ta', '/tb'], max_gap_s=2.0)
    out = []
    with open_log(path) as log:
        for raw in log.stream('/imu', ['/ta', '/tb'], chunk_size=500, keep_raw=True):
            out += aligner.push(raw)
    out += aligner.finish()
    got = np.concatenate([c.temps for c in out])
    for k, tc in enumerate(temps):
        ref = TemperatureTrack(math.inf)
        ref.add(tc.stamp_ns, tc.temperature)
        np.testing.assert_allclose(got[:, k], ref.interpolate(imu.stamp_ns, 2.0)[0], atol=1e-12)
    assert sum(len(c.extra['imu_raw']) for c in out) == len(imu)
    np.testing.assert_array_equal(np.concatenate([c.extra['imu_log_time_ns'] for c in out]),
                                  imu.stamp_ns)
