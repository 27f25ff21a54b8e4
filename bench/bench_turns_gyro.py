"""Time ``gyro_select.turns_gyro`` on a pickled input and optionally save/compare its output.

Usage: OPENBLAS_NUM_THREADS=1 python bench/bench_turns_gyro.py ARGS.pkl [--save OUT.pkl]
[--compare REF.pkl] [--repeat 3] [--profile]

ARGS.pkl holds ``(ctx, est, poly, rep)`` as passed to ``turns_gyro`` (e.g. the nav cold
start of ``thermal-imu-calib simulate --scenario nav-coldstart --seed 0``). Prints the
CPU seconds (``time.process_time``) of each repeat after one warm-up. ``--compare``
requires the same chosen model and kept lists and every number of the report and the
model equal to 1e-9 relative.
"""

import argparse
import pickle
import sys
import time

import numpy as np


def _numbers(x, path=''):
    """Yield (path, value) of every leaf of nested dicts/lists/arrays/dataclasses."""
    if isinstance(x, dict):
        for k in sorted(x, key=str):
            yield from _numbers(x[k], f'{path}/{k}')
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            yield from _numbers(v, f'{path}[{i}]')
    elif isinstance(x, np.ndarray):
        yield path, x
    elif hasattr(x, '__dict__') and not isinstance(x, type):
        yield from _numbers(vars(x), path + '.')
    else:
        yield path, x


def compare(a, b, rtol=1e-9):
    """Return a list of differences between two outputs (empty: equal to ``rtol``)."""
    la, lb = dict(_numbers(a)), dict(_numbers(b))
    bad = [f'keys differ: {sorted(set(la) ^ set(lb))}'] if set(la) != set(lb) else []
    worst = 0.0
    for k in sorted(set(la) & set(lb)):
        x, y = la[k], lb[k]
        if isinstance(x, (float, np.ndarray, int)) and not isinstance(x, bool):
            x, y = np.asarray(x, float), np.asarray(y, float)
            if x.shape != y.shape:
                bad.append(f'{k}: shape {x.shape} vs {y.shape}')
                continue
            both_nan = np.isnan(x) & np.isnan(y)
            d = np.where(both_nan, 0.0, np.abs(x - y))
            tol = rtol * np.maximum(np.abs(x), np.abs(y))
            if np.any(d > tol) and np.any(d > 1e-300):
                bad.append(f'{k}: max diff {np.max(d):.3g} ({x.ravel()[:3]} vs {y.ravel()[:3]})')
            if x.size:
                rel = d / np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-300)
                worst = max(worst, float(np.max(np.where(d > 0, rel, 0.0))))
        elif x != y:
            bad.append(f'{k}: {x!r} vs {y!r}')
    print(f'largest relative difference: {worst:.3g}')
    return bad


def _detail(gs, ctx, est, poly):
    """Return the intermediate results: the seed 002 fit on all windows, per-item figures."""
    acc = est.accel.correct(ctx.windows.accel, ctx.ta)
    fit = gs._whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel,
                              ctx.options.transitions)
    static = gs._whole_unit_gyro(ctx, np.ones(len(ctx.windows), bool), acc, est.accel)
    names = [c for c, _ in gs.POSE_CANDIDATES]
    return {'fit_model': fit.model, 'fit_stats': fit.stats, 'static_model': static.model,
            'static_stats': static.stats, 'rotation_after_deg': fit.rotation.error_after_deg,
            'pose': gs._pose_figures(ctx, est, poly, acc, fit)[0],
            'still': gs._still_figures(ctx, est, acc, names, fit)[0]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('args')
    ap.add_argument('--save')
    ap.add_argument('--compare')
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--profile', action='store_true')
    a = ap.parse_args(argv)
    import thermal_imu_calib.selection.gyro_select as gs
    with open(a.args, 'rb') as f:
        ctx, est, poly, rep = pickle.load(f)
    out = gs.turns_gyro(ctx, est, poly, rep)
    if a.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile()
        pr.enable()
        gs.turns_gyro(ctx, est, poly, rep)
        pr.disable()
        pstats.Stats(pr).sort_stats('cumulative').print_stats(40)
    cpu = []
    for _ in range(a.repeat):
        t = time.process_time()
        gs.turns_gyro(ctx, est, poly, rep)
        cpu.append(time.process_time() - t)
    print('turns_gyro CPU s:', ' '.join(f'{c:.3f}' for c in cpu),
          f'median {np.median(cpu):.3f} least {min(cpu):.3f}')
    print('chosen:', out[1]['gyro_choice']['model'], 'kept:', out[1]['gyro_choice']['kept'])
    result = {'model': out[0], 'report': out[1], 'notes': out[2],
              'detail': _detail(gs, ctx, est, poly)}
    if a.save:
        with open(a.save, 'wb') as f:
            pickle.dump(result, f)
    if a.compare:
        with open(a.compare, 'rb') as f:
            ref = pickle.load(f)
        bad = compare(result, ref)
        print('\n'.join(bad) if bad else 'EQUAL to 1e-9 relative')
        return 1 if bad else 0
    return 0


if __name__ == '__main__':
    sys.exit(main())
