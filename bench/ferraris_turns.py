"""Turn-angle error of calibration files on the imucal Ferraris session's three 360 deg turns.

``python bench/ferraris_turns.py CAL.yaml [CAL.yaml ...]`` applies each calibration to the
whole session (test/fixtures/real/imucal_ferraris, 102.4 Hz) and prints, per labelled turn
(x_rot, y_rot, z_rot), |integrated angle| - 360 deg and their RMS (deg), plus the raw data's.
Make the calibration with ``python bench/make_real_bags.py bags`` and
``thermal-imu-calib calibrate bags/ferraris.mcap --imu-topic /imu --gravity 9.81 -o f.yaml``.
"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_real_data as R  # noqa: E402
from thermal_imu_calib.calibration import Calibration  # noqa: E402


def turn_errors(t, gyro, sections):
    """Return {turn: |integrated angle| - 360 deg} of the labelled turns (deg)."""
    out = {}
    for k in R.ROTATIONS:
        a, b = sections[k]
        sel = (t >= t[a] - R.ROTATION_MARGIN_S) & (t <= t[b - 1] + R.ROTATION_MARGIN_S)
        out[k] = R.turn_angle_error_deg(t[sel], gyro[sel])
    return out


def main(paths):
    """Print the turn-angle errors of raw data and of each calibration file."""
    s = R.read_imucal_session(os.path.join(R.FERRARIS, 'example_ferraris_session.csv.gz'),
                              os.path.join(R.FERRARIS, 'example_ferraris_session_list.json'))
    t, acc, gyr = s.imu.t, s.imu.accel, s.imu.gyro
    rows = [('raw', gyr)]
    for p in paths:
        cal = Calibration.load(p)
        rows.append((p, cal.apply(acc, gyr, np.zeros((len(t), 0))).gyro))
    for name, g in rows:
        e = turn_errors(t, g, s.sections)
        v = np.array(list(e.values()))
        print(f'{name}: ' + ' / '.join(f'{k} {x:.3g}' for k, x in e.items())
              + f' deg, RMS {np.sqrt(np.mean(v ** 2)):.3g} deg')


if __name__ == '__main__':
    main(sys.argv[1:])
