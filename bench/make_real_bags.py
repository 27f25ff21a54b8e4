"""Write the real recordings in test/fixtures/real as MCAP logs (SI units) for the CLI.

``python bench/make_real_bags.py OUTDIR`` writes ``ferraris.mcap`` (imucal example session,
102.4 Hz), ``mpu6050.mcap`` (tomisuarez2 calibration session, 100 Hz) and ``bmi270_hot.mcap``
/ ``bmi270_cold.mcap`` (no time base in the files: 80 Hz assumed, with the die temperature
on /imu/temperature). The IMU topic is /imu in every log.
"""

import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from thermal_imu_calib.io.bag_writer import write_columns  # noqa: E402
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns  # noqa: E402
from thermal_imu_calib.io.csv_logs import (read_bmi270_rows, read_imucal_session,  # noqa: E402
                                           read_mpu6050_csv)

FIX = os.path.join(ROOT, 'test', 'fixtures', 'real')
BMI_RATE_HZ = 80.0


def bmi270_rows(path):
    """Return the (n, 7) rows of a BMI270 soak (csv_logs.read_bmi270_rows)."""
    return read_bmi270_rows(path)[0]


def main(out):
    """Write the logs into ``out``."""
    os.makedirs(out, exist_ok=True)
    fer = os.path.join(FIX, 'imucal_ferraris')
    s = read_imucal_session(os.path.join(fer, 'example_ferraris_session.csv.gz'),
                            os.path.join(fer, 'example_ferraris_session_list.json'))
    write_columns(os.path.join(out, 'ferraris.mcap'), '/imu', s.imu, overwrite=True)
    m = read_mpu6050_csv(os.path.join(FIX, 'mpu6050_tomisuarez',
                                      'example_data_calibration.csv.gz'))
    write_columns(os.path.join(out, 'mpu6050.mcap'), '/imu', m.imu, overwrite=True)
    for tag, name in (('hot', 'BMI_270_hot_test.csv'), ('cold', 'BMI_270_cold_test_.csv')):
        x = bmi270_rows(os.path.join(FIX, 'bmi270', name))
        stamp = 1_700_000_000 * 10 ** 9 + np.round(np.arange(len(x)) * 1e9 / BMI_RATE_HZ)
        stamp = stamp.astype(np.int64)
        imu = ImuColumns(stamp, x[:, 1:4] * 4.0 * 9.80665, np.radians(x[:, 4:7]), 'imu')
        temp = TemperatureColumns(stamp, x[:, 0], 'imu')
        write_columns(os.path.join(out, f'bmi270_{tag}.mcap'), '/imu', imu,
                      {'/imu/temperature': temp}, overwrite=True)
    print(f'wrote ferraris.mcap, mpu6050.mcap, bmi270_hot.mcap, bmi270_cold.mcap to {out}')


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'real_bags')
