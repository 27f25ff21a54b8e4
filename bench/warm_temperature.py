"""A warming temperature on the real several-pose sessions: does a span do harm?

Most IMU drivers publish a temperature, and a sensor warms after power-on, so a posing
session recorded from a driver often carries a temperature that rises a few degC. The
shared posing sessions have none. This adds one, the same for every session: 30 degC
rising by ``--span`` degC with a first-order warm-up (time constant a third of the
session), 1 Hz, 0.02 degC noise, quantised to 0.0625 degC (a common driver step), on
``/imu/temperature``. It is not the sensor's real temperature (the session's own drift
has no reason to follow it), so the honest outcome is "no worse than without it".

Each session is calibrated with default options twice (without the topic; with it) and
scored as ``scoreboard.py`` scores it (| |mean a| - g | RMS over the reference intervals,
the calibration applied to the whole log with the added temperature where it uses one).

    .venv/bin/python bench/warm_temperature.py [--span 3] \
        [--json bench/results/warm_temperature.json]

The logs come from ``real_recordings.py`` (in ``--work``, shared with the scoreboard).
"""

import argparse
import json
import os
import sys

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import real_recordings as rr  # noqa: E402
import scoreboard as sb  # noqa: E402
from thermal_imu_calib.io.columns import TemperatureColumns  # noqa: E402

#: the driver's temperature step (degC) and rate (Hz)
STEP_DEGC = 0.0625
RATE_HZ = 1.0


def warming(imu, span, seed=0):
    """Return a 30 degC + ``span`` first-order warm-up over the span of ``imu``."""
    t0, t1 = int(imu.stamp_ns[0]), int(imu.stamp_ns[-1])
    stamps = np.arange(t0, t1 + 1, int(1e9 / RATE_HZ), dtype=np.int64)
    x = (stamps - t0) / 1e9
    tau = max((t1 - t0) / 1e9 / 3.0, 1.0)
    rng = np.random.default_rng(seed)
    temp = 30.0 + span * (1 - np.exp(-x / tau)) + rng.normal(0.0, 0.02, len(x))
    return TemperatureColumns(stamps, np.round(temp / STEP_DEGC) * STEP_DEGC)


def run(rec, span, out):
    imu, _ = rr.read_log(rec.log, rec.imu_topic)
    tc = warming(imu, span)
    path = os.path.join(out, f'{rec.name}_warm{span:g}.mcap')
    rr.write_columns(path, rec.imu_topic, imu, {rr.TEMP_TOPIC: tc}, overwrite=True)
    row = {'recording': rec.name}
    for label, log, topic in (('without', rec.log, None), ('warming', path, rr.TEMP_TOPIC)):
        off = sb.offline(log, rec, os.path.join(out, f'{rec.name}_{label}.yaml'), topic)
        if not off['yaml']:
            row[label] = {'rc': off['rc'], 'last_lines': off['last_lines']}
            continue
        a = sb.calibrated_accel(off['yaml'], imu, tc if topic else None)
        s = sb.interval_score(a, rec.intervals, rec.gravity)
        choice = yaml.safe_load(off['yaml'])['fit'].get('model_choice', {})
        row[label] = {'rms_ug': round(s[0], 1), 'max_ug': round(s[1], 1),
                      'model': choice.get('model'), 'reason': choice.get('reason'),
                      'command': off['command']}
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--span', type=float, default=3.0, help='warm-up (degC)')
    ap.add_argument('--work', default=os.path.join('/tmp', f'thermal-scoreboard-{os.getuid()}'))
    ap.add_argument('--json', default=os.path.join(HERE, 'results', 'warm_temperature.json'))
    args = ap.parse_args(argv)
    os.makedirs(args.work, exist_ok=True)
    out = os.path.join(args.work, 'warm')
    os.makedirs(out, exist_ok=True)
    recs = [r for r in rr.all_recordings(args.work)
            if r.temperature_topic is None and len(r.intervals) > 3]
    rows = []
    print(f'| recording | without a temperature [ug] | with a {args.span:g} degC warm-up [ug] '
          '| ratio |')
    print('|---|---|---|---|')
    for rec in recs:
        row = run(rec, args.span, out)
        rows.append(row)
        a, b = row['without'], row['warming']
        ratio = (b['rms_ug'] / a['rms_ug']) if 'rms_ug' in a and 'rms_ug' in b else float('nan')
        fmt = (lambda r: f'{r["rms_ug"]:.1f} ({r["model"]})' if 'rms_ug' in r
               else f'refused (exit {r["rc"]})')
        print(f'| {rec.name} | {fmt(a)} | {fmt(b)} | {ratio:.3f} |', flush=True)
    with open(args.json, 'w') as f:
        json.dump({'command': ' '.join(['bench/warm_temperature.py'] + (argv or sys.argv[1:])),
                   'span_degc': args.span, 'rows': rows}, f, indent=1)
    print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
