"""How the swaps of finished robot months fared the next day, by the swap gate's verdicts.

Joins each month's per-swap next-day figures (``bench_lifelong.py month`` JSON, ``swaps``)
with the gate's verdicts in that month's ``decisions.jsonl`` and groups the swaps by which
sensor carried them: the gyro 'same' (the accelerometer carried it), the accelerometer
'same' (the gyro carried it), or both 'better'. Per group: the next day's error of the new
calibration over the old one's (gyro systematic error; accelerometer drift), median,
geometric mean and how many got worse. Swaps on the first day are left out (no settled
old calibration).

    python bench/lifelong_swap_verdicts.py /tmp/mf1.json:/tmp/mf1/seed1 [...]
"""

import argparse
import json
import os

import numpy as np


def swaps_with_verdicts(result_json, work_seed_dir):
    """Return [(day, gyro new/old, accel drift new/old, gyro verdict, accel verdict)]."""
    out = []
    with open(result_json) as f:
        rows = json.load(f)['rows']
    with open(os.path.join(work_seed_dir, 'decisions.jsonl')) as f:
        dec = [json.loads(x) for x in f if x.strip()]
    sw = [d for d in dec if d['action'] == 'swap']
    for r in rows:
        recs = r['swaps']
        # the bench records every swap after the first (the first replaces the raw output)
        pairs = list(zip(sw[1:], recs))
        off = [d['time'] - x['day'] * 86400.0 for d, x in pairs]
        if pairs and np.ptp(off) > 60.0:
            raise SystemExit(f'{result_json}: swaps and decisions do not line up')
        for d, x in pairs:
            if x['day'] < 1.0:
                continue
            out.append((x['day'], x['gyro_new'] / x['gyro_old'],
                        x['accel_drift_new'] / x['accel_drift_old'],
                        d['figures']['gyro']['verdict'], d['figures']['accel']['verdict']))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('pairs', nargs='+', help='RESULT.json:WORK/seedN')
    args = ap.parse_args()
    groups = {'gyro same (accelerometer carried it)': [],
              'accelerometer same (gyro carried it)': [], 'both better': []}
    names = list(groups)
    for p in args.pairs:
        res, work = p.split(':', 1)
        for day, g, a, vg, va in swaps_with_verdicts(res, work):
            key = names[0] if vg != 'better' else (names[1] if va != 'better' else names[2])
            groups[key].append((g, a))
    print('next day, new calibration over old (ratio < 1: better)')
    for k, v in groups.items():
        if not v:
            print(f'{k}: none')
            continue
        v = np.array(v)
        parts = []
        for col, what in ((0, 'gyro'), (1, 'accel drift')):
            x = v[:, col]
            parts.append(f'{what}: median {np.median(x):.2f}, geometric mean '
                         f'{np.exp(np.mean(np.log(x))):.2f}, worse {int((x > 1).sum())}, '
                         f'worse by > 25 % {int((x > 1.25).sum())}')
        print(f'{k}: {len(v)} swaps; ' + '; '.join(parts))


if __name__ == '__main__':
    main()
