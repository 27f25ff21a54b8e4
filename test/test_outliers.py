"""Spike rejection (streaming, chunk-invariant, counted) and robust estimation."""

import numpy as np

from thermal_imu_calib.collection.outliers import (despike, ImuSpikeFilter, robust_least_squares,
                                                   SpikeFilter)
from thermal_imu_calib.estimation.whole_unit_accel import fit_whole_unit_accel
from thermal_imu_calib.io.columns import AlignedChunk, ImuColumns

from test_whole_unit import directions, G, synth_windows, truth_accel


def signals(rng, n=20_000):
    """Three channels: a sine (motion), a quantised still signal, a ramp with a kink."""
    t = np.arange(n) / 200.0
    x = np.column_stack([3 * np.sin(t), np.zeros(n), np.where(t > 50, 2 * (t - 50), 0.0)])
    x += rng.normal(0, 0.01, x.shape)
    x[:, 1] = np.round(x[:, 1] / 0.01) * 0.01
    return t, x


def test_spikes_are_found_counted_and_replaced_nothing_else_moves():
    rng = np.random.default_rng(0)
    t, x = signals(rng)
    clean = x.copy()
    # isolated spikes: at most one per window of 2h + 1 = 7 samples and channel
    idx = 600 + np.sort(rng.choice((len(t) - 600) // 8, 40, replace=False)) * 8
    ch = rng.integers(0, 3, 40)
    x[idx, ch] += rng.choice([-1, 1], 40) * rng.uniform(0.3, 5.0, 40)
    out, mask, filt = despike(x)
    assert set(zip(*np.nonzero(mask))) == set(zip(idx, ch))
    assert filt.rejected.sum() == 40 and filt.counts()['rejected_total'] == 40
    assert np.max(np.abs(out[idx, ch] - clean[idx, ch])) < 0.06     # replaced by the median
    keep = ~mask
    assert np.array_equal(out[keep], x[keep])                      # untouched elsewhere


def test_streaming_equals_offline_whatever_the_chunking():
    rng = np.random.default_rng(1)
    t, x = signals(rng, 4000)
    x[rng.choice(len(t), 10, replace=False), 0] += 2.0
    ref, mask, _ = despike(x)
    assert mask.sum() >= 8
    for size in (1, 7, 512, 5000):
        f = SpikeFilter(3)
        vals, ts = [], []
        for i in range(0, len(t), size):
            o = f.push(x[i:i + size], [t[i:i + size]])
            vals.append(o.values)
            ts.append(o.extra[0])
        o = f.flush()
        vals.append(o.values)
        ts.append(o.extra[0])
        assert np.array_equal(np.concatenate(vals), ref)
        assert np.array_equal(np.concatenate(ts), t)
        assert f.delay == 3


def test_imu_filter_delays_stamps_and_temperatures_with_the_samples():
    rng = np.random.default_rng(2)
    n = 3000
    stamps = np.arange(n, dtype=np.int64) * 5_000_000
    acc = rng.normal(0, 0.02, (n, 3)) + [0, 0, G]
    gyr = rng.normal(0, 1e-3, (n, 3))
    gyr[1500, 2] += 0.5                                             # one bump
    temps = np.linspace(20, 21, n)[:, None]
    f = ImuSpikeFilter()
    outs = []
    for i in range(0, n, 700):
        sl = slice(i, i + 700)
        raw = [bytes([i % 251]) * 3 for i in range(i, min(i + 700, n))]
        outs.append(f.push(AlignedChunk(ImuColumns(stamps[sl], acc[sl], gyr[sl]), temps[sl],
                                        np.zeros((len(temps[sl]), 1)),
                                        {'imu_raw': raw, 'imu_log_time_ns': stamps[sl] + 7})))
    outs.append(f.flush())
    assert sum((o.extra['imu_raw'] for o in outs), []) == [bytes([i % 251]) * 3
                                                           for i in range(n)]
    assert np.array_equal(np.concatenate([o.extra['imu_log_time_ns'] for o in outs]),
                          stamps + 7)
    st = np.concatenate([o.imu.stamp_ns for o in outs])
    tm = np.concatenate([o.temps for o in outs])
    g = np.concatenate([o.imu.gyro for o in outs])
    assert np.array_equal(st, stamps) and np.array_equal(tm, temps)
    assert abs(g[1500, 2]) < 0.01 and f.counts()['rejected'] == [0, 0, 0, 0, 0, 1]


def test_robust_least_squares_ignores_a_cluster_of_bad_points():
    rng = np.random.default_rng(3)
    x = np.linspace(0, 10, 200)
    y = 2.0 + 0.5 * x + rng.normal(0, 0.01, 200)
    y[50:60] += 1.0                                                 # a bumped stretch

    def fun(p):
        return (y - p[0] - p[1] * x) / 0.01

    res = robust_least_squares(fun, np.zeros(2))
    assert np.allclose(res.x, [2.0, 0.5], atol=3e-3)
    assert res.outliers[50:60].all() and res.outliers.sum() <= 15


def test_one_bumped_hold_does_not_corrupt_the_whole_unit_fit():
    rng = np.random.default_rng(4)
    model = truth_accel(rng)
    w = synth_windows(rng, model, directions(rng, tilted=4), reps=3)
    temps = w.temp[:, [0, 0, 0]]
    clean = fit_whole_unit_accel(w, temps, G, model.t0, select=False)
    bumped = w.select(np.ones(len(w), bool))
    hold = int(np.unique(w.hold)[7])
    bumped.accel = bumped.accel.copy()
    bumped.accel[bumped.hold == hold] *= 1.003                       # ~3 mg on one hold
    rob = fit_whole_unit_accel(bumped, temps, G, model.t0, select=False)
    plain = fit_whole_unit_accel(bumped, temps, G, model.t0, robust=False, select=False)
    assert hold in rob.outlier_holds
    err_rob = np.abs(rob.model.m1 - clean.model.m1).max()
    err_plain = np.abs(plain.model.m1 - clean.model.m1).max()
    assert err_rob < 3e-5 and err_plain > 5 * err_rob, (err_rob, err_plain)
    assert np.abs(rob.model.offset[0] - clean.model.offset[0]).max() < 3e-4
