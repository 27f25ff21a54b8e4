"""The gyro continuation's evidence by the span of the calibration that scored it.

For finished ``bench_lifelong.py month`` runs (``SEED:WORK_DIR/seedSEED[:DOCK_FRACTION]``),
every evidence row of ``gyro_continuation`` (``state.json``, ``continuation``: a hold
outside the active calibration's gyro range, its error clamped and continued, rad/s) is
paired with the gyro range width (degC) of the calibration active at its time (the
registry is the timeline). Printed per span band: the rows, the days they fall on, the
clamped and continued RMS (mrad/s) and how often continuing was the better; then per
month. Tells whether what the first calibrations, fitted over a few degC, showed carries
over to calibrations fitted over weeks (docs/lifelong.md, "Seed 178's gyro beyond its
range"). Rows an alarm cut are gone from the state.

    python bench/lifelong_continuation_by_span.py 141:/tmp/acc4/w141/seed141 \
        178:/tmp/dock/w178/seed178:0.5
"""

import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_lifelong import active_index, registry_timeline  # noqa: E402
from thermal_imu_calib.lifelong.continuation import span  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

#: gyro range widths (degC) the rows are grouped by
SPAN_BANDS = ((0, 5), (5, 10), (10, 20), (20, np.inf))


def span_rows(seed, d, dock_fraction=0.0):
    """Return (n, 4): day, the active's gyro span degC, clamped, continued error (rad/s)."""
    m = robot_month(seed, days=30, dock_fraction=dock_fraction)
    base = m.start_ns * 1e-9
    acts, cals = registry_timeline(d, m.start_ns)
    with open(os.path.join(d, 'state.json')) as f:
        rows = json.load(f).get('continuation') or []
    out = []
    for r in rows:
        i = active_index(acts, r[0] - base)
        if i >= 0:
            out.append(((r[0] - base) / DAY, span(cals[i]), r[1], r[2]))
    return np.array(out).reshape(-1, 4)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) * 1e3


def main():
    runs = []
    for spec in sys.argv[1:]:
        seed, rest = spec.split(':', 1)
        d, _, dock = rest.partition(':')
        runs.append((int(seed), span_rows(int(seed), d, float(dock or 0.0))))
    for lo, hi in SPAN_BANDS:
        per = [(s, r[(r[:, 1] >= lo) & (r[:, 1] < hi)]) for s, r in runs]
        per = [(s, r) for s, r in per if len(r)]
        if not per:
            continue
        a = np.concatenate([r for _, r in per])
        print(f'span {lo:g}-{hi:g} degC: {len(a)} rows on {len(per)} months, days '
              f'{a[:, 0].min():.1f}-{a[:, 0].max():.1f}: clamped {rms(a[:, 2]):.3f} vs '
              f'continued {rms(a[:, 3]):.3f} mrad/s, continuing better on '
              f'{np.mean(a[:, 3] < a[:, 2]):.0%}')
        print('   ' + '; '.join(f'{s}: {len(r)} rows {rms(r[:, 2]):.3f} / {rms(r[:, 3]):.3f}'
                                for s, r in per))


if __name__ == '__main__':
    main()
