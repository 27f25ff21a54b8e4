"""Do the gyro rotation fits converge on the real recordings? Every call counted.

The accelerometer's whole-unit term selection counts its fold fits that stop at their
evaluation budget (``fit.accel_cv``); the gyro rotation fit (``estimation.gyro_rotations``)
does not count its own. This bench calibrates every recording of ``../shared/data/real``
(``real_recordings``) with the CLI's default options, in process, with
``gyro_rotations.fit_free`` wrapped to record each call's kind (evaluation budget, prior
rows, robust loss) and whether it converged (``observability.converged``): the first fit
(budget 100, with the prior rows), the leave-pose-changes-out fold fits (budget 50) and the
final fit (budget 100, robust).

Usage: ``python bench/rotation_convergence.py [--work DIR] [--out FILE.json]``
(THERMAL_REAL_DATA overrides the data folder; about 15 minutes on a slow 2-core machine).
"""

import argparse
import collections
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import real_recordings as rr  # noqa: E402
from thermal_imu_calib import cli  # noqa: E402
from thermal_imu_calib.estimation import gyro_rotations, observability  # noqa: E402

CALLS = collections.Counter()
_FIT_FREE = gyro_rotations.fit_free


def _counted(resid, std, base, free, with_prior=False, robust=False, tight=True, **kw):
    p, res = _FIT_FREE(resid, std, base, free, with_prior, robust, tight, **kw)
    kind = (f"budget {kw.get('max_nfev')}, {'prior rows' if with_prior else 'no prior'}, "
            f"{'robust' if robust else 'plain'}")
    CALLS[kind, observability.converged(res)] += 1
    return p, res


def run(rec, work):
    """Calibrate ``rec`` with default options; return {'rc', kind: 'converged of calls'}."""
    CALLS.clear()
    out = os.path.join(work, f'{rec.name}.yaml')
    args = ['calibrate', rec.log, '--imu-topic', rec.imu_topic, '--gravity',
            repr(rec.gravity), '-o', out]
    if rec.temperature_topic:
        args += ['--temperature-topic', rec.temperature_topic]
    if os.path.exists(out):
        os.unlink(out)
    try:
        rc = cli.main(args)
    except SystemExit as e:
        rc = e.code
    kinds = sorted({k for k, _ in CALLS})
    return {'rc': rc, **{k: f'{CALLS[k, True]} of {CALLS[k, True] + CALLS[k, False]} converged'
                         for k in kinds}}


def main(argv=None):
    """Run every recording; print a JSON line each and the total; write ``--out``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--work', default='/tmp/rotation_convergence')
    ap.add_argument('--out', default=None)
    a = ap.parse_args(argv)
    os.makedirs(a.work, exist_ok=True)
    gyro_rotations.fit_free = _counted
    rows = {}
    for rec in rr.all_recordings(a.work):
        rows[rec.name] = run(rec, a.work)
        print(rec.name, json.dumps(rows[rec.name]), flush=True)
    total = {'recordings': len(rows), 'stopped calls': sum(
        int(v.split(' of ')[1].split()[0]) - int(v.split(' of ')[0])
        for r in rows.values() for k, v in r.items() if k != 'rc')}
    print(json.dumps(total))
    if a.out:
        with open(a.out, 'w') as f:
            json.dump({'rows': rows, 'total': total}, f, indent=1)


if __name__ == '__main__':
    main()
