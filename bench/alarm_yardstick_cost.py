"""What the alarm yardstick costs a calibration (CPU seconds), on simulated fleet logs.

A calibration of several orientations fits the field model once more for the registry's
drift alarms (``estimation/alarm_yardstick.py``): with S estimated when there is no prior,
so since 2026-12-03 a field calibration without a prior gets one too. This times
``calibrate_windows`` on the holds of simulated fleet logs (``simulate-fleet``, one log per
unit), ``--model standard`` and ``auto``, with the yardstick and with it switched off, each
``--repeats`` times, and prints the median CPU seconds per calibration.

    .venv/bin/python bench/alarm_yardstick_cost.py            # ~2 min
"""

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from thermal_imu_calib import cli  # noqa: E402
from thermal_imu_calib.app import calibrate as app  # noqa: E402
from thermal_imu_calib.cli.fleet import fleet_settings  # noqa: E402
from thermal_imu_calib.collection.collected import merge_transitions, merge_windows  # noqa
from thermal_imu_calib.estimation import calibrate as est  # noqa: E402
from thermal_imu_calib.fleet.inputs import expand_inputs  # noqa: E402


def _cpu(fn):
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--units', type=int, default=3)
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--seed', type=int, default=0)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        subprocess.run([sys.executable, '-m', 'thermal_imu_calib.cli.entry', 'simulate-fleet',
                        d, '--units', str(args.units), '--logs-per-unit', '1', '--seed',
                        str(args.seed), '--workers', '1'], check=True, capture_output=True)
        settings = fleet_settings(cli.build_parser().parse_args(
            ['fleet', 'calibrate', '-', '-o', '-']))
        rows = []
        for path in expand_inputs([d]):
            c = app.collect(settings, path)
            windows = merge_windows([c])
            opts = app.options(settings, [c], merge_transitions([c]))
            for model in ('standard', 'auto'):
                o = dataclasses.replace(opts, model=model)
                times = {True: [], False: []}
                kinds = {}
                for _ in range(args.repeats):
                    for on in (True, False):
                        needed = est.alarm_yardstick.needed
                        if not on:
                            est.alarm_yardstick.needed = lambda *a, **k: False
                        try:
                            dt, res = _cpu(lambda: est.calibrate_windows(windows, o))
                        finally:
                            est.alarm_yardstick.needed = needed
                        times[on].append(dt)
                        kinds[on] = ('alarm_yardstick' in res.calibration.fit,
                                     res.calibration.accel.kind)
                rows.append((os.path.basename(path), model, np.median(times[True]),
                             np.median(times[False]), kinds[True]))
        for name, model, with_, without, (fitted, kind) in rows:
            print(f'{name} {model:8s} -> {kind:18s} yardstick fitted: {fitted!s:5s} CPU s '
                  f'median of {args.repeats}: with {with_:.2f}, without {without:.2f} '
                  f'({with_ / without:.2f}x)')


if __name__ == '__main__':
    main()
