"""`make demo`: simulate a cold start, calibrate, compensate, and show before/after.

The offline part goes through the ``thermal-imu-calib`` command line, exactly as a user
would type it (the commands are printed as they run); the live part (scripts/demo_live.py)
runs both ROS 2 nodes and calls the calibrate service. Output lands in ``demo_out/``.
"""

import os
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, 'demo_out')
CLI = os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib')


def run(*args, quiet=False):
    """Run one CLI command, echoing it; abort the demo on failure."""
    print(f'\n$ thermal-imu-calib {" ".join(args)}', flush=True)
    r = subprocess.run([CLI, *args], cwd=OUT, capture_output=quiet, text=True)
    if r.returncode != 0:
        if quiet:
            print(r.stdout, r.stderr)
        sys.exit(f'demo step failed: thermal-imu-calib {" ".join(args)}')
    return r


def main():
    """Run the offline demo."""
    t0 = time.perf_counter()
    shutil.rmtree(OUT, ignore_errors=True)
    os.makedirs(OUT)
    print('thermal_imu_calib demo: a consumer MEMS IMU warms up from 22 degC while someone '
          'holds it in the six face-up poses twice; a second, independent warm-up of the '
          'same device is used to check the result.')
    run('simulate', 'coldstart.mcap', '--scenario', 'demo', '--seed', '1')
    run('simulate', 'validation.mcap', '--scenario', 'demo-validation', '--seed', '1')
    run('info', 'coldstart.mcap')
    # the simulated site is at 45 deg latitude: WGS84 gravity there, and earth rotation removed
    # from the gyro
    run('calibrate', 'coldstart.mcap', '--imu-topic', '/imu/data_raw',
        '--temperature-topic', '/imu/temperature', '--latitude', '45', '-o', 'calibration.yaml')
    run('compensate', 'validation.mcap', '--calibration', 'calibration.yaml',
        '--imu-topic', '/imu/data_raw', '--output-topic', '/imu/data_compensated',
        '-o', 'validation_compensated.mcap')
    print('\nBefore/after on the validation recording (raw, our estimate, and the simulator\'s '
          'true parameters for reference):')
    run('evaluate', 'validation.mcap', '--calibration', 'calibration.yaml',
        '--calibration', 'validation.mcap.truth.yaml', '--latitude', '45', '--average', '30')
    print('\nThe compensated stream itself, as written to validation_compensated.mcap:')
    run('evaluate', 'validation_compensated.mcap', '--imu-topic', '/imu/data_compensated',
        '--average', '30')
    print('\nLive: both ROS 2 nodes over DDS (localhost only), calibrated by a service call.')
    r = subprocess.run([sys.executable, os.path.join(ROOT, 'scripts', 'demo_live.py')])
    if r.returncode != 0:
        sys.exit('demo step failed: live nodes')
    print(f'\ndemo finished in {time.perf_counter() - t0:.0f} s; files in {OUT}')


if __name__ == '__main__':
    main()
