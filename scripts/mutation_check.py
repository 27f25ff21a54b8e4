#!/usr/bin/env python3
"""Mutation check: break five things in a temporary copy of the tree; which tests notice?

Issue 15 asks that each of these deliberate breaks makes at least one test fail:

1. ``model-std``: drop the model-std term from the covariance (``_combine_std``);
2. ``thermal-load``: halve one thermal coefficient (k1 of x) when a field model is loaded;
3. ``auto-field``: make ``auto`` always pick ``field``;
4. ``min-hold``: make the detector's minimum hold 3x longer;
5. ``skip-gyro``: make the compensation skip the gyro correction.

Each break is a literal text replacement (its anchor must occur exactly once, else the
break is reported as stale, not silently skipped) in a copy of the tracked files; the
listed test files then run from the copy (``PYTHONPATH`` = the copy, checked) and every
failing test id is reported. Exit status 1 when a break is caught by no test or is stale.

Usage: .venv/bin/python scripts/mutation_check.py [--only NAME ...] [--json FILE]
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PKG = 'thermal_imu_calib'

#: name -> (description, [(file, anchor, replacement)], test files to run)
BREAKS = {
    'model-std': (
        'drop the model-std term from the covariance',
        [(f'{PKG}/calibration/core.py',
          '        var = var + np.asarray(model_std) ** 2\n',
          '        pass  # MUTANT: model std dropped\n')],
        ['test/test_core_models.py', 'test/test_lab.py', 'test/test_rvm.py',
         'test/test_covariance.py']),
    'thermal-load': (
        'halve one thermal coefficient (k1 of x) on load',
        [(f'{PKG}/models/field.py',
          '        th = np.stack([require(params, n, (3,), w) for n in THERMAL_NAMES], axis=1)\n',
          '        th = np.stack([require(params, n, (3,), w) for n in THERMAL_NAMES], axis=1)\n'
          '        th[0, 1] *= 0.5  # MUTANT\n')],
        ['test/test_core_models.py', 'test/test_cli_pipeline.py']),
    'auto-field': (
        'make auto always pick field',
        [(f'{PKG}/estimation/calibrate.py',
          "                 else AUTO_POLICY[0](ctx.accel_view()))",
          "                 else ('field', 'MUTANT'))"),
         (f'{PKG}/selection/select.py',
          "name, why = (o.model, 'requested') if o.model != 'auto' else AUTO_POLICY[0](ctx)",
          "name, why = (o.model, 'requested') if o.model != 'auto' else ('field', 'MUTANT')")],
        ['test/test_select.py', 'test/test_thermal_lag.py', 'test/test_cli_pipeline.py']),
    'min-hold': (
        "make the detector's minimum hold 3x longer",
        [(f'{PKG}/collection/holds.py',
          'np.sum(b.n) < round(c.min_hold_s * rate):',
          'np.sum(b.n) < round(3 * c.min_hold_s * rate):  # MUTANT')],
        ['test/test_core_estimation.py', 'test/test_cli_pipeline.py']),
    'skip-gyro': (
        'make the compensator skip the gyro correction',
        [(f'{PKG}/calibration/core.py',
          "            g_out = self.gyro.correct(gyro, tg, aux={'accel': a_out})\n",
          '            g_out = gyro  # MUTANT: gyro correction skipped\n')],
        ['test/test_core_models.py', 'test/test_covariance.py', 'test/test_node_compensator.py']),
}


def copy_tree(dst):
    """Copy the tracked files (plus untracked, not ignored ones) of ROOT to ``dst``."""
    files = subprocess.run(['git', 'ls-files', '-z', '--cached', '--others',
                            '--exclude-standard'], cwd=ROOT, check=True,
                           capture_output=True).stdout.decode().split('\0')
    for f in filter(None, files):
        src = os.path.join(ROOT, f)
        if os.path.isfile(src):
            os.makedirs(os.path.dirname(os.path.join(dst, f)), exist_ok=True)
            shutil.copy2(src, os.path.join(dst, f))


def apply_break(tree, edits):
    """Apply the text edits; return a list of stale anchors (empty when all applied)."""
    stale = []
    for rel, old, new in edits:
        path = os.path.join(tree, rel)
        text = open(path).read()
        if text.count(old) != 1:
            stale.append(f'{rel}: anchor found {text.count(old)} times: {old.strip()!r}')
            continue
        with open(path, 'w') as f:
            f.write(text.replace(old, new))
    return stale


def run_tests(tree, tests):
    """Run pytest on ``tests`` inside ``tree``; return (failed ids, summary line, seconds)."""
    tests = [t for t in tests if os.path.exists(os.path.join(tree, t))]
    env = dict(os.environ, PYTHONPATH=tree, PYTHONDONTWRITEBYTECODE='1')
    check = subprocess.run([sys.executable, '-c', f'import {PKG}; print({PKG}.__file__)'],
                           cwd=tree, env=env, capture_output=True, text=True)
    if not check.stdout.strip().startswith(tree):
        raise SystemExit(f'the copy is not what Python imports: {check.stdout}{check.stderr}')
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-rf', '-p', 'no:cacheprovider',
                        '-m', 'not linter', *tests], cwd=tree, env=env, capture_output=True,
                       text=True)
    failed = sorted(set(re.findall(r'^(?:FAILED|ERROR) (\S+)', r.stdout, re.M)))
    lines = [ln for ln in r.stdout.splitlines() if re.search(r'\d+ (passed|failed)', ln)]
    return failed, (lines[-1] if lines else r.stdout[-300:]), time.monotonic() - t0


def main(argv=None):
    """Run the selected breaks; print a markdown table; return 1 when one is not caught."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--only', nargs='*', choices=sorted(BREAKS), default=None)
    ap.add_argument('--json', help='write the results to this file')
    args = ap.parse_args(argv)
    results, status = {}, 0
    for name in args.only or BREAKS:
        desc, edits, tests = BREAKS[name]
        tree = tempfile.mkdtemp(prefix=f'mutant-{name}-')
        try:
            copy_tree(tree)
            stale = apply_break(tree, edits)
            if stale:
                results[name] = {'break': desc, 'stale': stale, 'caught_by': []}
                status = 1
            else:
                failed, summary, secs = run_tests(tree, tests)
                results[name] = {'break': desc, 'tests_run': tests, 'caught_by': failed,
                                 'summary': summary, 'seconds': round(secs)}
                status |= not failed
        finally:
            shutil.rmtree(tree, ignore_errors=True)
        r = results[name]
        print(f'{name}: {desc}: ' + (f'STALE {r["stale"]}' if 'stale' in r else
                                     f'caught by {len(r["caught_by"])} test(s) '
                                     f'({r["summary"]})'), flush=True)
        for t in r['caught_by']:
            print(f'    {t}', flush=True)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(results, f, indent=1)
    return status


if __name__ == '__main__':
    sys.exit(main())
