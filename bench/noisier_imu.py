"""The multi-pose real recordings as a noisier IMU would give them.

Usage (from the repository root; about 6 min on 2 cores)::

    .venv/bin/python bench/noisier_imu.py [--work DIR] [--out FILE] [--levels 3 10] [--seeds 0 1]

Each multi-pose recording of ``real_recordings`` gets white Gaussian noise added to its
accelerometer samples, so that the per-sample noise is ``level`` times the recording's own
(its own: the median over axes of the sample standard deviation inside the scored still
intervals; added: ``sqrt(level^2 - 1)`` times that, numpy ``default_rng(seed)``). A consumer
MEMS part is 3-10x noisier than the xsens and the ROS 2-driver sessions here.

The noisy log is calibrated with default options (``thermal-imu-calib calibrate LOG
--imu-topic /imu --gravity G``, as ``scoreboard.py``); the calibration is then applied to
the **original** samples and scored as the scoreboard scores them: static | |mean a| - g |
RMS (ug) over the recording's scored intervals. So the figure is what the noise did to the
parameters, not the noise itself. Beside it, the floor: imu_tk's 9-parameter fit
(``imutk_reference.fit_standard``) to the noisy log's means over the scored intervals, in
sample as the scoreboard's standard-fit column, scored on the original's means (not for
Ferraris: 6 intervals < 9 parameters). Writes ``bench/results/noisier_imu.json``.
"""

import argparse
import os
import sys
import tempfile

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import imutk_reference as ref  # noqa: E402
import real_recordings as rr  # noqa: E402
import variants as vb  # noqa: E402
from thermal_imu_calib.io.columns import ImuColumns  # noqa: E402


def native_noise(accel, intervals):
    """Return the recording's own per-sample accel noise (m/s^2): median axis std in holds."""
    return float(np.median(np.concatenate(
        [accel[a:b].std(axis=0) for a, b in intervals if b - a > 2])))


def run(rec, level, seed, work):
    """Calibrate one noisy variant of ``rec``; return its row (scored on the original)."""
    imu, _ = rr.read_log(rec.log, rec.imu_topic)
    sigma = native_noise(imu.accel, rec.intervals)
    add = np.sqrt(level ** 2 - 1.0) * sigma
    rng = np.random.default_rng(seed)
    noisy = ImuColumns(imu.stamp_ns, imu.accel + rng.normal(0.0, add, imu.accel.shape),
                       imu.gyro, imu.frame_id)
    log = os.path.join(work, f'{rec.name}_x{level:g}_s{seed}.mcap')
    row = vb.calibrate_variant(rec, noisy, log, imu, rec.intervals,
                               {'recording': rec.name, 'level': level, 'seed': seed,
                                'native_noise_mps2': sigma, 'added_noise_mps2': add})
    if row['rc']:
        return row
    # the floor: imu_tk's 9-parameter fit to the noisy log's interval means (in-sample on
    # the scored intervals, as the scoreboard's column), scored on the original's
    std = None
    if len(rec.intervals) > 9:
        p, _ = ref.fit_standard(ref.interval_means(noisy.accel, rec.intervals), rec.gravity)
        std = float(ref.static_rms_ug(ref.apply_params(
            p, ref.interval_means(imu.accel, rec.intervals)), rec.gravity)[0])
    row.update(standard_fit_ug=std, undetermined=_undetermined(row.pop('yaml')))
    return row


def _undetermined(text):
    """Return the accelerometer misalignment terms the standard fit fixed (from the file)."""
    notes = yaml.safe_load(text).get('notes') or []
    return [str(n) for n in notes if 'misalignment' in str(n)
            and 'fixed' in str(n)]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--work', default=None, help='directory for the logs (default: a temp dir)')
    p.add_argument('--out', default=os.path.join(HERE, 'results', 'noisier_imu.json'))
    p.add_argument('--levels', type=float, nargs='+', default=[3.0, 10.0])
    p.add_argument('--seeds', type=int, nargs='+', default=[0, 1])
    p.add_argument('--only', nargs='*', default=None, help='recording names (default: all)')
    a = p.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='noisier_imu_')
    os.makedirs(work, exist_ok=True)
    rows = []
    for rec in vb.multi_pose(work):
        if a.only and rec.name not in a.only:
            continue
        for level in a.levels:
            for seed in a.seeds:
                row = run(rec, level, seed, work)
                rows.append(row)
                std = row.get('standard_fit_ug')
                print(vb.line(rec, f'x{level:<4g} seed {seed}', row,
                              f"  standard fit {std:8.1f} ug  x{row['score_ug'] / std:.2f}"
                              if std else ''), flush=True)
    vb.write_rows(a.out, 'noisier_imu.py', argv, rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
