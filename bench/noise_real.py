"""Run the real BMI270 and MPU-6050 recordings through ``thermal-imu-calib noise``.

The CSVs have no time stamps: each is written as an MCAP log (``write_columns``) with
stamps from its sample rate (MPU-6050: ``Fs`` = 100 Hz from the file; BMI270: none known,
the rate is estimated from the 38400-baud UART as 38400 / (10 bits x mean line length),
an upper bound if the link was saturated), then ``noise`` is run with default options.
Prints a Markdown table (docs/noise.md) and writes the Allan plots of the MPU-6050 static
log to docs/img/. Usage::

    .venv/bin/python bench/noise_real.py [--data ../shared/data/real] [--out /tmp/noise_real]
"""

import argparse
import os
import shutil
import subprocess
import sys

import numpy as np
import yaml

from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import ImuColumns
from thermal_imu_calib.io.csv_logs import read_bmi270_rows, read_mpu6050_csv

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
G = 9.80665
DEG = np.pi / 180
DATASHEET = {
    # Bosch BST-BMI270-DS000 (gyro performance mode) / InvenSense PS-MPU-6000A-00 rev 3.4
    'BMI270': {'accel_N': 160e-6 * G, 'gyro_N': 0.007 * DEG},
    'MPU-6050': {'accel_N': 400e-6 * G, 'gyro_N': 0.005 * DEG},
}


def bmi270(path):
    """Return (rate estimate Hz, accel m/s^2, gyro rad/s, temperature degC) of a soak CSV."""
    a, nbytes, nlines = read_bmi270_rows(path)
    rate = 38400.0 / (10.0 * nbytes / nlines)
    return rate, a[:, 1:4] * 4.0 * G, np.radians(a[:, 4:7]), a[:, 0]


def write_log(path, rate, acc, gyr):
    """Write a still IMU series as an MCAP log with synthesized stamps."""
    stamps = (np.arange(len(acc)) * (1e9 / rate)).astype(np.int64) + 10 ** 18
    write_columns(path, '/imu/data_raw', ImuColumns(stamps, acc, gyr, 'imu_link'))


def run_noise(log, out_dir, name, png_dir=None):
    """Run the CLI; return its Kalibr dict."""
    yml = os.path.join(out_dir, name + '.imu.yaml')
    cmd = [os.path.join(ROOT, '.venv', 'bin', 'thermal-imu-calib'), 'noise', log, '-o', yml]
    if png_dir:
        cmd += ['--png-dir', png_dir]
    print('$ ' + ' '.join(cmd), file=sys.stderr)
    subprocess.run(cmd, check=True)
    with open(yml) as f:
        return yaml.safe_load(f)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--data', default=os.path.join(os.path.dirname(ROOT), 'shared', 'data',
                                                   'real'))
    ap.add_argument('--out', default='/tmp/noise_real')
    args = ap.parse_args()
    if not os.path.isdir(args.data):
        args.data = '/work/shared/data/real'
    shutil.rmtree(args.out, ignore_errors=True)
    os.makedirs(args.out)
    runs = []
    mpu = os.path.join(args.data, 'mpu6050_tomisuarez')
    for fname, label, png in (('example_data_tinit_calc.csv', 'static 449 s', True),
                              ('example_data_calibration.csv', 'multi-pose, holds', False)):
        log = read_mpu6050_csv(os.path.join(mpu, fname))
        path = os.path.join(args.out, 'mpu6050_' + fname.split('_')[2] + '.mcap')
        write_log(path, log.rate_hz, log.imu.accel, log.imu.gyro)
        png_dir = os.path.join(ROOT, 'docs', 'img', 'noise_mpu6050') if png else None
        runs.append(('MPU-6050', label, log.rate_hz, len(log.imu.accel),
                     run_noise(path, args.out, os.path.basename(path)[:-5], png_dir)))
    bmi = os.path.join(args.data, 'bmi270_hot_cold')
    for fname, label in (('BMI_270_cold_test_.csv', 'cold soak ~13 degC'),
                         ('BMI_270_hot_test.csv', 'hot soak ~48 degC')):
        rate, acc, gyr, temp = bmi270(os.path.join(bmi, fname))
        path = os.path.join(args.out, 'bmi270_' + fname.split('_')[2] + '.mcap')
        write_log(path, rate, acc, gyr)
        runs.append(('BMI270', f'{label}, rate {rate:.1f} Hz (estimated)', rate, len(acc),
                     run_noise(path, args.out, os.path.basename(path)[:-5])))
    print('| sensor | record | samples | accel N worst [ug/sqrt(Hz)] (datasheet) | '
          'gyro N worst [deg/s/sqrt(Hz)] (datasheet) | accel K / gyro K | gyro B [deg/h] |')
    print('|---|---|---|---|---|---|---|')
    for sensor, label, rate, n, d in runs:
        ds = DATASHEET[sensor]
        ex = d['thermal_imu_calib']
        bound = '<' if ex['random_walk_upper_bound'] else ''
        b = max(ex['gyro']['axes'][a]['bias_instability'] for a in 'xyz') / DEG * 3600
        print(f'| {sensor} | {label} | {n} ({ex["still_seconds"]:.0f} s still, '
              f'{ex["source"]}) | {d["accelerometer_noise_density"] / G * 1e6:.0f} '
              f'({ds["accel_N"] / G * 1e6:.0f}) | {d["gyroscope_noise_density"] / DEG:.4f} '
              f'({ds["gyro_N"] / DEG:.4f}) | {bound}{d["accelerometer_random_walk"]:.2g} m/s^3'
              f'/sqrt(Hz) / {bound}{d["gyroscope_random_walk"]:.2g} rad/s^2/sqrt(Hz) | '
              f'{b:.0f} |')


if __name__ == '__main__':
    main()
