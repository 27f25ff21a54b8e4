"""Outputs that a refactoring must leave bit for bit the same (issue 23).

Writes, with default options through the real CLI (``cli.main``):

* the calibration files of ``bench_nav_accuracy`` seeds 0 and 1 (``nav-coldstart`` with its
  lab prior, as docs/results.md runs it);
* the calibration files of the real Ferraris and MPU-6050 recordings (the scoreboard's bags,
  ``bench/real_recordings.py``);
* a fleet registry (``fleet calibrate`` of a 3-unit simulated fleet on a local cluster);

then prints one SHA-256 per file. What is stamped with the wall clock (a calibration's
``created``, the registry's run times) is blanked before hashing; nothing else is touched.

Usage::

    python bench/identity.py OUT_DIR [--json hashes.json] [--compare other.json]

``--compare`` exits 1 and lists the files whose hash differs from an earlier run (for example
one made on the commit before a refactoring).
"""

import argparse
import hashlib
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

#: wall-clock stamps blanked before hashing (a regex per line)
STAMPS = [re.compile(rb"^(\s*created: ).*$", re.M),
          re.compile(rb"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?(Z|[+-]\d\d:\d\d)?)")]


def _digest(path):
    data = open(path, 'rb').read()
    data = STAMPS[0].sub(rb'\1<created>', data)
    if not path.endswith(('.yaml', '.yml')):
        data = STAMPS[1].sub(rb'<time>', data)
    return hashlib.sha256(data).hexdigest()


def _files(root):
    out = []
    for dp, dn, fn in os.walk(root):
        dn.sort()
        for f in sorted(fn):
            if f.endswith(('.yaml', '.csv', '.json', '.txt')) and 'logs' not in dp.split(os.sep):
                out.append(os.path.join(dp, f))
    return out


def make(out):
    """Write every output into ``out`` (made fresh); return {relative path: sha256}."""
    from thermal_imu_calib import cli, sim
    from thermal_imu_calib.fleet.simulate import FleetDesign, simulate_fleet
    import real_recordings as rr

    os.makedirs(out, exist_ok=True)
    cwd = os.getcwd()
    os.chdir(out)          # relative paths only, so the files do not name the directory
    try:
        for seed in (0, 1):
            bag = f'nav{seed}.mcap'
            if not os.path.exists(bag):
                sim.write_scenario(bag, 'nav-coldstart', seed)
            _run(cli, ['calibrate', bag, '--prior', f'{bag}.prior.yaml',
                       '-o', f'cal/nav{seed}.yaml', '--force'])
        os.makedirs('real', exist_ok=True)
        for rec in (rr.ferraris('real'), rr.mpu6050('real')):
            _run(cli, ['calibrate', os.path.relpath(rec.log), '--imu-topic', rec.imu_topic,
                       '--gravity', str(rec.gravity), '-o', f'cal/{rec.name}.yaml', '--force'])
        if not os.path.isdir('fleet/logs'):
            simulate_fleet('fleet/logs', FleetDesign(units=3, logs_per_unit=2, seed=0))
        _run(cli, ['fleet', 'calibrate', 'fleet/logs', '--workers', '2', '-o', 'fleet/registry'])
        return {os.path.relpath(p): _digest(p) for p in _files('cal') + _files('fleet/registry')}
    finally:
        os.chdir(cwd)


def _run(cli, argv):
    code = cli.main(argv)
    if code != 0:
        raise SystemExit(f'thermal-imu-calib {" ".join(argv)} exited {code}')


def main(argv=None):
    """Parse the command line, write the outputs and print or compare their hashes."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('out', help='directory for the outputs (inputs are reused if present)')
    ap.add_argument('--json', help='write {file: sha256} here')
    ap.add_argument('--compare', help='an earlier --json: exit 1 if any file differs')
    args = ap.parse_args(argv)
    import shutil
    for d in ('cal', os.path.join('fleet', 'registry')):
        shutil.rmtree(os.path.join(args.out, d), ignore_errors=True)
    hashes = make(args.out)
    for k, v in sorted(hashes.items()):
        print(f'{v}  {k}')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(hashes, f, indent=1, sort_keys=True)
    if args.compare:
        old = json.load(open(args.compare))
        diff = sorted(k for k in set(old) | set(hashes) if old.get(k) != hashes.get(k))
        print(f'{len(diff)} of {len(set(old) | set(hashes))} files differ' +
              (':\n  ' + '\n  '.join(diff) if diff else ''))
        return 1 if diff else 0
    return 0


if __name__ == '__main__':
    sys.exit(main())
