"""One lifelong re-estimate on a copy of a month's store: its decision and its time.

For the speed of ``Lifelong.estimate`` (the re-estimates are about 90 % of a simulated
month): copies a lifelong directory (``bench_lifelong.py month --work DIR``'s
``DIR/seedN``, finished or not), runs one ``estimate`` there with the bench's settings
(latitude 45 deg, ``LifelongConfig`` defaults unless ``--gyro-continuation``), and writes
the decision with its wall time (``seconds``). ``--compare OLD.json`` prints what differs
from a decision written the same way by another commit (numbers: the largest relative
difference; text: the keys), so a change meant for speed can show it decides the same.

    # two commits side by side on the same store (each from its own checkout)
    python bench/lifelong_estimate_time.py /tmp/j41b/base139/seed139 --output /tmp/new.json \\
        --compare /tmp/old.json
"""

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..'))

from thermal_imu_calib.app.calibrate import CalibrateSettings  # noqa: E402
from thermal_imu_calib.lifelong.config import GYRO_CONTINUATIONS, LifelongConfig  # noqa: E402
from thermal_imu_calib.lifelong.manager import Lifelong  # noqa: E402
from thermal_imu_calib.sim.robot_month import RobotMonthConfig  # noqa: E402


def differences(a, b, path=''):
    """Return [(path, relative difference or None for a non-numeric one)] of two decisions."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b), key=str)
                for d in differences(a.get(k), b.get(k), f'{path}.{k}')]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b))
                for d in differences(x, y, f'{path}[{i}]')]
    if isinstance(a, float) and isinstance(b, float):
        return [] if a == b else [(path, abs(a - b) / max(abs(a), 1e-300))]
    return [] if a == b else [(path, None)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('store', help="a lifelong directory (a month's DIR/seedN)")
    ap.add_argument('--gyro-continuation', choices=GYRO_CONTINUATIONS,
                    default=LifelongConfig.gyro_continuation)
    ap.add_argument('--output', required=True, help='the decision, with its seconds (JSON)')
    ap.add_argument('--compare', default='', help='a decision written the same way')
    args = ap.parse_args()
    cfg = RobotMonthConfig()
    with tempfile.TemporaryDirectory() as tmp:
        d = os.path.join(tmp, 'store')
        shutil.copytree(args.store, d)
        life = Lifelong(d, CalibrateSettings(latitude=45.0), 1, [cfg.temp_topic], cfg.frame_id,
                        registry_dir=os.path.join(d, 'registry'),
                        config=LifelongConfig(gyro_continuation=args.gyro_continuation))
        t = time.perf_counter()
        decision = life.estimate('timed')
        decision['seconds'] = round(time.perf_counter() - t, 2)
    with open(args.output, 'w') as f:
        json.dump(decision, f, indent=1, default=str)
    print(f'{args.store}: {decision["action"]} in {decision["seconds"]} s')
    if args.compare:
        with open(args.compare) as f:
            old = json.load(f)
        new = json.loads(json.dumps(decision, default=str))
        diff = [d for d in differences(old, new) if d[0] != '.seconds']
        num = [d for d in diff if d[1] is not None]
        print(f'against {args.compare} ({old.get("seconds")} s): action '
              f'{old.get("action")} -> {new["action"]}; numbers differing {len(num)}, the '
              f'largest relative {max((d[1] for d in num), default=0):.2g}'
              f'{" at " + max(num, key=lambda d: d[1])[0] if num else ""}; other keys: '
              f'{", ".join(d[0] for d in diff if d[1] is None) or "none"}')


if __name__ == '__main__':
    main()
