"""Benchmark log I/O: bulk CDR fast path vs rosbags' per-message deserializer.

Writes ~200k sensor_msgs/msg/Imu messages to a temporary bare MCAP file, reads the raw
CDR back, then decodes it (a) with ``thermal_imu_calib.io.cdr.decode_imu`` in chunks and
(b) with rosbags ``deserialize_cdr`` one message at a time, checking both agree.  Also
times writing and streaming.  Run: ``python bench/bench_io.py [N]``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag import LogWriter, open_log
from thermal_imu_calib.io.columns import ImuColumns

CHUNK = 20000


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def run(n: int = 200_000, rosbags_n: int | None = None) -> dict[str, float]:
    """Run the benchmark on ``n`` messages; returns msgs/s per stage."""
    from rosbags.typesys import get_typestore, Stores

    rng = np.random.default_rng(0)
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000
    cols = ImuColumns(stamps, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), 'imu_link')
    rates: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'bench.mcap'
        raws, dt = _timed(lambda: cdr.encode_imu(cols))
        rates['encode_imu (fast path)'] = n / dt

        def write():
            with LogWriter(path) as w:
                w.add_topic('/imu', cdr.IMU_MSGTYPE)
                w.write_many('/imu', stamps, raws)
        _, dt = _timed(write)
        rates['write bare mcap (LogWriter)'] = n / dt

        with open_log(path) as log:
            read, dt = _timed(lambda: [m[3] for m in log.iter_raw(['/imu'])])
            rates['read raw (LogReader.iter_raw)'] = n / dt
            count, dt = _timed(lambda: sum(len(c) for c in log.stream('/imu',
                                                                      chunk_size=CHUNK)))
            assert count == n
            rates['stream + decode (LogReader.stream)'] = n / dt

    def fast():
        return ImuColumns.concat([cdr.decode_imu(read[i:i + CHUNK])
                                  for i in range(0, n, CHUNK)])
    dec, dt = _timed(fast)
    rates['(a) decode_imu (fast path)'] = n / dt
    np.testing.assert_array_equal(dec.accel, cols.accel)

    store = get_typestore(Stores.ROS2_JAZZY)
    m = n if rosbags_n is None else min(n, rosbags_n)

    def slow():
        acc = np.empty((m, 3))
        for i, raw in enumerate(read[:m]):
            a = store.deserialize_cdr(raw, cdr.IMU_MSGTYPE).linear_acceleration
            acc[i] = (a.x, a.y, a.z)
        return acc
    acc, dt = _timed(slow)
    rates['(b) rosbags deserialize_cdr'] = m / dt
    np.testing.assert_array_equal(acc, cols.accel[:m])

    (_, dt) = _timed(lambda: cdr.patch_imu(read, cols.accel * 2, cols.gyro))
    rates['patch_imu (fast path)'] = n / dt
    return rates


def main(argv=None) -> int:
    """Print a msgs/s table."""
    import argparse
    import json
    ap = argparse.ArgumentParser(description='io msgs/s benchmark')
    ap.add_argument('n', type=int, nargs='?', default=200_000, help='Imu messages')
    ap.add_argument('--json', help='write the figures here')
    args = ap.parse_args(argv)
    n = args.n
    rates = run(n)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'messages': n, 'msgs_per_s': rates}, f, indent=1)
    width = max(map(len, rates))
    print(f'io benchmark, {n} sensor_msgs/msg/Imu messages')
    print(f'{"stage":<{width}}  {"msgs/s":>12}')
    for name, rate in rates.items():
        print(f'{name:<{width}}  {rate:12,.0f}')
    fast, slow = rates['(a) decode_imu (fast path)'], rates['(b) rosbags deserialize_cdr']
    print(f'fast path speed-up over rosbags: {fast / slow:.0f}x')
    return 0


if __name__ == '__main__':
    sys.exit(main())
