"""The multi-pose real recordings as other IMUs would give them: mounted otherwise, or slower.

Usage (from the repository root; about 6 min on 2 cores)::

    .venv/bin/python bench/mounting_and_rate.py [--work DIR] [--out FILE]

Each multi-pose recording of ``real_recordings`` is calibrated with default options
(``thermal-imu-calib calibrate LOG --imu-topic /imu --gravity G``, as ``scoreboard.py``)
as it is and as four variants of the same samples:

* ``rotated 1`` / ``rotated 2``: accel and gyro turned by a fixed random rotation
  (``scipy.spatial.transform.Rotation.random``, seeds 1 and 2), an IMU mounted at an odd
  angle in the cube. The norm-based standard fit is invariant under a fixed rotation
  (any 3x3 matrix is a rotation times an upper triangle, and the rotation drops out of
  |a|), so only what depends on the axes can move: hold detection (per-axis noise
  floors), faces, and which parameters are fixed when the holds leave them undetermined;
* ``half rate (mean of 2)``: every two samples averaged, at the second one's stamp (a
  half-rate IMU with its anti-alias filter, crudely);
* ``every 2nd sample``: every other sample dropped, no filter (a driver that decimates
  without one; vibration above the new Nyquist rate aliases into the hold means).

Score: static | |mean a| - g | RMS over the recording's scored intervals (imu_tk's,
the bench detector's, the annotated ones; indices mapped to the variant), the calibration
applied as ``scoreboard.py`` applies it. Writes ``bench/results/mounting_and_rate.json``.
"""

import argparse
import os
import sys
import tempfile

from scipy.spatial.transform import Rotation

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import real_recordings as rr  # noqa: E402
import variants as vb  # noqa: E402
from thermal_imu_calib.io.columns import ImuColumns  # noqa: E402

VARIANTS = ('as is', 'rotated 1', 'rotated 2', 'half rate (mean of 2)', 'every 2nd sample')


def variant(imu, intervals, name):
    """Return (ImuColumns, intervals as sample index ranges) of one variant of a log."""
    if name == 'as is':
        return imu, list(intervals)
    if name.startswith('rotated'):
        r = Rotation.random(random_state=int(name.split()[-1])).as_matrix()
        return ImuColumns(imu.stamp_ns, imu.accel @ r.T, imu.gyro @ r.T,
                          imu.frame_id), list(intervals)
    if name == 'every 2nd sample':
        return imu.slice(slice(0, None, 2)), [((a + 1) // 2, (b + 1) // 2)
                                              for a, b in intervals]
    n = len(imu) // 2 * 2
    return (ImuColumns(imu.stamp_ns[1:n:2], imu.accel[:n].reshape(-1, 2, 3).mean(1),
                       imu.gyro[:n].reshape(-1, 2, 3).mean(1), imu.frame_id),
            [(a // 2, b // 2) for a, b in intervals])


def run(rec, name, work):
    """Calibrate one variant of ``rec`` with default options; return its row."""
    imu, _ = rr.read_log(rec.log, rec.imu_topic)
    im, intervals = variant(imu, rec.intervals, name)
    slug = ''.join(c if c.isalnum() else '_' for c in name).strip('_')
    row = vb.calibrate_variant(rec, im, os.path.join(work, f'{rec.name}_{slug}.mcap'), im,
                               intervals, {'recording': rec.name, 'variant': name})
    row.pop('yaml', None)
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--work', default=None, help='directory for the logs (default: a temp dir)')
    p.add_argument('--out', default=os.path.join(HERE, 'results', 'mounting_and_rate.json'))
    a = p.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='mounting_and_rate_')
    os.makedirs(work, exist_ok=True)
    rows = []
    for rec in vb.multi_pose(work):
        base = None
        for name in VARIANTS:
            row = run(rec, name, work)
            base = row.get('score_ug') if name == 'as is' else base
            if base and row.get('score_ug'):
                row['ratio'] = row['score_ug'] / base
            rows.append(row)
            print(vb.line(rec, name, row, f"  x{row.get('ratio', 1.0):.2f}"), flush=True)
    vb.write_rows(a.out, 'mounting_and_rate.py', argv, rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
