"""Window statistics for the thermal-model tests: simulator, synthetic, real BMI270 slices."""

import os

import numpy as np

from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation.calibrate import CalibrateOptions
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.io.csv_logs import read_bmi270_rows
from thermal_imu_calib.collection.feed import windows_from_columns

G = 9.80665


def sim_windows(rec):
    """Run the stationary detector over a simulated recording (no bag round trip)."""
    return windows_from_columns(rec.imu_chunks(),
                                [rec.temperatures[t] for t in rec.config.temp_topics])


def options(k=1):
    """Return calibration options for k temperature topics."""
    return CalibrateOptions(inputs=[TemperatureInput(f't{i}', f'/imu/temperature{i or ""}')
                                    for i in range(k)])


def make_windows(t, temp, accel, gyro, hold=None, n=500, sigma_a=1e-3, sigma_g=1e-4,
                 rng=None, window_s=5.0):
    """Return Windows with the given means plus white noise of n-sample averages.

    t: (m,) window start times s; temp: (m,) degC; accel, gyro: (m, 3) noise-free means.
    """
    rng = rng or np.random.default_rng(0)
    m = len(t)
    hold = np.zeros(m, int) if hold is None else np.asarray(hold)
    acc = accel + rng.normal(0, sigma_a / np.sqrt(n), (m, 3))
    gyr = gyro + rng.normal(0, sigma_g / np.sqrt(n), (m, 3))
    rate = np.gradient(temp, t) if m > 1 else np.zeros(m)
    return Windows(hold, np.asarray(t, float), np.asarray(t, float) + window_s,
                   np.full(m, n), acc, gyr, np.full((m, 3), sigma_a ** 2),
                   np.full((m, 3), sigma_g ** 2), np.asarray(temp, float)[:, None],
                   rate[:, None])


BMI270 = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'fixtures', 'real', 'bmi270')


def bmi270_windows(directory=BMI270, window=64, rate_hz=100.0):
    """Return Windows of the cold (hold 0) and hot (hold 1) BMI270 soaks (see SOURCE.md).

    Lines that are not 7 floats are skipped; accel g/4 -> m/s^2, gyro deg/s -> rad/s. There
    is no time base: ``rate_hz`` is assumed and the hot soak placed an hour after the cold.
    """
    parts, t_off = [], 0.0
    for hold, name in enumerate(('BMI_270_cold_test_.csv', 'BMI_270_hot_test.csv')):
        a, _, _ = read_bmi270_rows(os.path.join(directory, name))
        m = len(a) // window
        blocks = a[:m * window].reshape(m, window, 7)
        acc = blocks[:, :, 1:4] * 4.0 * G
        gyr = np.radians(blocks[:, :, 4:7])
        t0 = t_off + np.arange(m) * window / rate_hz
        parts.append(Windows(np.full(m, hold), t0, t0 + window / rate_hz, np.full(m, window),
                             acc.mean(1), gyr.mean(1), acc.var(1, ddof=1), gyr.var(1, ddof=1),
                             blocks[:, :, :1].mean(1), np.zeros((m, 1))))
        t_off = t0[-1] + 3600.0
    return Windows.concat(parts)
