"""`make bench`: run every benchmark and evaluation script; figures go to bench/results/.

Each script prints a markdown table (copied into the README's results section) and writes
its figures as JSON. Run one alone with ``python bench/<name>.py --help``.
"""

import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, 'results')
#: (script, extra arguments) in the order they run
BENCHES = [
    ('bench_io.py', []),
    ('bench_nodes.py', []),
    ('bench_nav_accuracy.py', []),
    ('bench_nav_accuracy.py', ['--variant', 'uniform']),
    ('bench_nav_accuracy.py', ['--variant', 'short']),
    ('bench_mems.py', []),
    ('bench_real_data.py', []),
    ('bench_thermal.py', []),
    ('bench_chamber.py', []),
    ('bench_proxy.py', []),
    ('mounting_and_rate.py', []),     # the posing recordings turned and slowed (~6 min)
    ('noisier_imu.py', []),           # the posing recordings with accel noise x3/x10 (~8 min)
    ('robot_log_calibrate.py', []),   # calibrate of robot logs, seeds 24-31 (~4 min)
    ('scoreboard.py', []),     # every shared real recording, offline and live (~17 min)
    ('headerless_real.py', []),       # the temperature logs as std_msgs/Float64 (~1.5 min)
    ('bench_headerless_clock.py', []),   # LiveImuClock per IMU message (~5 s)
]
#: scripts that name their outputs by a base path instead of --json FILE
OUT_BASE = {'scoreboard.py'}
#: scripts that write their JSON to --out FILE
OUT_FILE = {'mounting_and_rate.py', 'noisier_imu.py', 'robot_log_calibrate.py'}


def main():
    """Run the benchmarks that exist; exit non-zero if any failed to run."""
    os.makedirs(RESULTS, exist_ok=True)
    only = sys.argv[1:]
    failed = []
    for script, extra in BENCHES:
        path = os.path.join(HERE, script)
        name = script[:-3] + (f'_{extra[-1]}' if extra else '')
        if not os.path.exists(path) or (only and name not in only):
            continue
        print(f'\n## {name}\n', flush=True)
        t0 = time.perf_counter()
        out = (['--out', os.path.join(RESULTS, name)] if script in OUT_BASE
               else ['--out', os.path.join(RESULTS, f'{name}.json')] if script in OUT_FILE
               else ['--json', os.path.join(RESULTS, f'{name}.json')])
        r = subprocess.run([sys.executable, path, *extra, *out])
        print(f'\n({name}: {time.perf_counter() - t0:.0f} s, exit {r.returncode})', flush=True)
        if r.returncode not in (0, 1):  # 1: ran, but an acceptance target was missed
            failed.append(name)
    if failed:
        sys.exit(f'benchmarks that failed to run: {", ".join(failed)}')


if __name__ == '__main__':
    main()
