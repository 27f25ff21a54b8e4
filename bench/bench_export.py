"""What each export format keeps of a calibration: the loss figures of docs/export.md.

Cases (each exported with the calibration's own windows as refit/loss samples):

* ``px4`` and ``ardupilot`` models of a simulated 40-min single-pose cold start
  (single-warmup, seed 2): cubic offsets, written exactly;
* the seed 000 field model the default ``auto`` fits on a simulated MEMS cold start
  (mems-coldstart, seed 0, six faces + tilts): scale-factor temperature terms, refitted
  for PX4/ArduPilot, evaluated at T0 for imu_tk/imucal/Kalibr;
* the seed 002 whole-unit model fitted on the real MPU-6050 session (no temperature).

Usage: ``python bench/bench_export.py``
"""

import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'test'))
sys.path.insert(0, os.path.join(ROOT, 'bench'))

from _thermal_data import options, sim_windows  # noqa: E402
import bench_real_data as R  # noqa: E402
from thermal_imu_calib import sim  # noqa: E402
from thermal_imu_calib.calibration import Calibration  # noqa: E402
from thermal_imu_calib.estimation.calibrate import calibrate_windows  # noqa: E402
from thermal_imu_calib.collection.motion import collect_motion  # noqa: E402
from thermal_imu_calib.estimation.whole_unit_fit import fit_whole_unit  # noqa: E402
from thermal_imu_calib.formats import export_calibration  # noqa: E402
from thermal_imu_calib.formats.common import loss_text  # noqa: E402
from thermal_imu_calib.io.csv_logs import read_mpu6050_csv  # noqa: E402

NOISE = ('accelerometer_noise_density: 1.0e-3\naccelerometer_random_walk: 1.0e-4\n'
         'gyroscope_noise_density: 1.0e-4\ngyroscope_random_walk: 1.0e-5\n'
         'rostopic: /imu/data_raw\nupdate_rate: 100.0\n')


def report(title, cal, windows, formats):
    """Print the loss lines of each format."""
    print(f'## {title}: accel {cal.accel.kind}, gyro {cal.gyro.kind}')
    for fmt in formats:
        kw = {'noise_text': NOISE, 'kalibr_model': 'scale-misalignment'} \
            if fmt == 'kalibr' else {}
        out = export_calibration(cal, fmt, windows=windows, **kw)
        for which, loss in out.loss.items():
            print(f'  {fmt:9s} {loss_text(which, loss)}')


def main():
    """Run the three cases."""
    rec = sim.simulate('single-warmup', 2, hold_s=(2400.0, 2400.0), imu_rate=100.0)
    w = sim_windows(rec)
    for name in ('px4', 'ardupilot'):
        o = options()
        o.model = name
        report(f'single-warmup seed 2, --model {name}', calibrate_windows(w, o).calibration, w,
               ('px4', 'ardupilot'))
    rec = sim.simulate('mems-coldstart', 0)
    w = sim_windows(rec)
    cal = calibrate_windows(w, options()).calibration
    report('mems-coldstart seed 0, --model auto (default)', cal, w,
           ('px4', 'ardupilot', 'imu_tk', 'json', 'kalibr'))
    s = read_mpu6050_csv(os.path.join(R.MPU, 'example_data_calibration.csv.gz'))
    w, transitions, _ = collect_motion(s.aligned(), R.HAND_HELD, 0)
    fit = fit_whole_unit(w, R.G, transitions=transitions)
    report('real MPU-6050 session, seed 002 whole-unit fit',
           Calibration(accel=fit.accel.model, gyro=fit.gyro.model), w,
           ('imu_tk', 'json', 'kalibr'))
    return 0


if __name__ == '__main__':
    np.set_printoptions(precision=4)
    sys.exit(main())
