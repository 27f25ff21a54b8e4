"""What putting header-less temperatures on the IMU's clock costs a node per message.

Usage: ``python bench/bench_headerless_clock.py [--json OUT]``. Times
``io.headerless.LiveImuClock`` (what both nodes run for a std_msgs/Float32 or Float64
thermal input) one IMU message at a time (a compensator keeping up at 1 kHz takes them one
by one): with no reading, with a reading every 10 IMU messages, and with one after every
IMU message (the um6/um7 drivers). Prints microseconds per IMU message (the median of 5
runs of 10,000 messages after a 5,000-message warm-up).
"""

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from thermal_imu_calib.io.headerless import LiveImuClock  # noqa: E402

N = 10_000


def per_message(every):
    """Return us per IMU message with a reading after every ``every`` messages (0: none)."""
    clock = LiveImuClock(1)
    for k in range(5000):
        clock.add_imu([k], [k])
    t = time.perf_counter()
    for k in range(5000, 5000 + N):
        clock.add_imu([k], [10 * k])
        if every and k % every == 0:
            clock.add_reading(0, k, 30.0)
            clock.take(0)
    return (time.perf_counter() - t) / N * 1e6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--json', default=None, help='write the figures here')
    a = ap.parse_args(argv)
    out = {}
    for every, label in ((0, 'no reading'), (10, 'a reading every 10'),
                         (1, 'a reading after every one')):
        runs = [per_message(every) for _ in range(5)]
        out[label] = {'us_per_imu_message_median': statistics.median(runs),
                      'min': min(runs), 'max': max(runs)}
        print(f'{label:>26}: {statistics.median(runs):6.2f} us per IMU message '
              f'({min(runs):.2f}..{max(runs):.2f})')
    if a.json:
        with open(a.json, 'w') as f:
            json.dump(out, f, indent=1)


if __name__ == '__main__':
    main()
