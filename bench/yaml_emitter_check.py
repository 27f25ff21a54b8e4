"""libyaml's emitter against the pure-Python one on every calibration file found.

``Calibration.to_yaml`` writes with ``yaml.CSafeDumper`` when PyYAML has it. This loads
every calibration YAML under the given directories (files that are not calibrations are
skipped), writes each with both emitters (the file's options, and ``Calibration.id``'s
sorted dump of the core), and prints how many texts are equal and the seconds each
emitter took. Exit 1 when a text differs (its path is printed).

    python bench/yaml_emitter_check.py . /tmp/acc3/w144 /tmp/acc3/w145
"""

import argparse
import glob
import os
import sys
import time

import yaml

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..'))

from thermal_imu_calib.calibration import Calibration  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('dirs', nargs='+', help='directories searched for *.yaml (recursively)')
    args = ap.parse_args(argv)
    found = (glob.glob(os.path.join(d, '**', '*.yaml'), recursive=True) for d in args.dirs)
    files = sorted({f for fs in found for f in fs if f'{os.sep}.venv' not in f})
    n = same = 0
    t_py = t_c = 0.0
    for path in files:
        try:
            cal = Calibration.load(path)
        except Exception:  # noqa: B902 - not a calibration: skipped
            continue
        d = cal.to_dict()
        t = time.perf_counter()
        a = yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=100)
        t_py += time.perf_counter() - t
        t = time.perf_counter()
        b = yaml.dump(d, Dumper=yaml.CSafeDumper, sort_keys=False, default_flow_style=None,
                      width=100)
        t_c += time.perf_counter() - t
        core = cal._core_dict()
        core.pop('created', None)
        equal = a == b and (yaml.safe_dump(core, sort_keys=True)
                            == yaml.dump(core, Dumper=yaml.CSafeDumper, sort_keys=True))
        n += 1
        same += equal
        if not equal:
            print(f'differs: {path}')
    print(f'{n} calibrations, {same} texts equal; pure Python {t_py:.1f} s, libyaml '
          f'{t_c:.1f} s')
    return 0 if same == n else 1


if __name__ == '__main__':
    sys.exit(main())
