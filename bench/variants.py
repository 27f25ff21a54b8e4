"""What the variant benches share: calibrate a changed copy of a multi-pose recording.

``mounting_and_rate.py`` (rotated, slower) and ``noisier_imu.py`` (noise added) write a
variant of each multi-pose real recording (``real_recordings``), calibrate it with default
options as ``scoreboard.py`` does, and score the calibration as the scoreboard scores it.
"""

import json
import os
import sys

import real_recordings as rr
import scoreboard as sb
from thermal_imu_calib.io.bag_writer import write_columns


def multi_pose(work):
    """Yield the multi-pose recordings (one per session: the rosbag2 copies left out)."""
    for rec in rr.all_recordings(os.path.join(work, 'logs')):
        if rec.kind == 'multi' and not rec.name.endswith('rosbag2'):
            yield rec


def calibrate_variant(rec, imu, log, scored, intervals, row):
    """Write ``imu`` to ``log``, calibrate it with default options; return ``row`` filled.

    The calibration is applied to ``scored`` (ImuColumns: the variant itself, or the
    original samples) and scored over ``intervals`` (sample index ranges of ``scored``).
    Adds rc, and refusal or holds, auto, accel_kind, score_ug, max_ug; ``row['yaml']`` is
    the calibration text (popped by the caller).
    """
    write_columns(log, '/imu', imu, {}, overwrite=True)
    off = sb.offline(log, rr.Recording(rec.name, log, '/imu', rec.gravity, rec.kind),
                     log + '.yaml')
    row['rc'] = off['rc']
    if off['rc']:
        row['refusal'] = off['last_lines'][-1] if off['last_lines'] else ''
        return row
    s = sb.summary_of(off['yaml'])
    rms, worst = sb.interval_score(sb.calibrated_accel(off['yaml'], scored), intervals,
                                   rec.gravity)
    row.update(holds=s['holds'], auto=s['auto'], accel_kind=s['accel_kind'],
               score_ug=float(rms), max_ug=float(worst), yaml=off['yaml'])
    return row


def line(rec, label, row, extra=''):
    """Return the progress line of one variant."""
    return f"{rec.name:18s} {label:22s} " + (
        f"{row['holds']:3d} holds  {row['auto']:10s} {row['score_ug']:8.1f} ug{extra}"
        if not row['rc'] else f"refused: {row['refusal']}")


def write_rows(path, script, argv, rows):
    """Write the bench's rows with the command that made them."""
    with open(path, 'w') as f:
        json.dump({'command': ' '.join([f'bench/{script}'] + (argv or sys.argv[1:])),
                   'rows': rows}, f, indent=1)
    print(f'wrote {path}')
