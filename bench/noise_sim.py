"""Scatter of N and K read back from simulated 2-h still records (docs/noise.md).

8 seeds x 3 axes x (accel, gyro), 100 Hz, white noise + random walk around the ADIS16448
figures of Kalibr's IMU noise-model page. Usage: ``.venv/bin/python bench/noise_sim.py``
"""

import numpy as np

from thermal_imu_calib import sim
from thermal_imu_calib.estimation import allan

RATE = 100.0
N = {'accel': np.array([1.86e-3, 1.5e-3, 2.2e-3]), 'gyro': np.array([1.87e-4, 1.5e-4, 2.2e-4])}
K = {'accel': np.array([4.33e-4, 3.5e-4, 5e-4]), 'gyro': np.array([2.66e-5, 2.2e-5, 3e-5])}


def main(hours=2.0, seeds=range(1, 9)):
    """Print the relative errors of N and K per seed, then their RMS and maximum."""
    en, ek = [], []
    for seed in seeds:
        n = int(hours * 3600 * RATE)
        acc = sim.still_noise(n, RATE, N['accel'], K['accel'], seed) + [0, 0, 9.80665]
        gyr = sim.still_noise(n, RATE, N['gyro'], K['gyro'], seed + 100)
        m = allan.noise_model([acc], [gyr], RATE)
        for s in ('accel', 'gyro'):
            en += list(np.array([a.N for a in m[s]]) / N[s] - 1)
            ek += list(np.array([a.K for a in m[s]]) / K[s] - 1)
    for name, e in (('N', np.array(en)), ('K', np.array(ek))):
        print(f'{name}: {len(e)} axis records, relative error RMS {np.sqrt(np.mean(e ** 2)):.3f}, '
              f'mean {e.mean():+.3f}, max |.| {np.abs(e).max():.3f}, > 10 %: '
              f'{int((np.abs(e) > 0.1).sum())}')


if __name__ == '__main__':
    main()
