"""Shared pieces of the lifelong tests' synthetic stops (rad/s, m/s^2, s, degC).

The earth rate a level sensor reads at a heading, and the windows built from rows of
(hold, t0 s, t1 s, temperature degC, gyro (3,) rad/s, accel (3,) m/s^2). Neither draws
random numbers, so the tests that use them keep their own draws.
"""

import numpy as np

from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.gyro_static import earth_rate_parts


def earth_rate(heading, lat_deg):
    """Return the earth rate (3,) rad/s a level sensor reads at ``heading`` rad, latitude deg.

    ``lat_deg`` None: no earth rate (zeros).
    """
    if lat_deg is None:
        return np.zeros(3)
    vertical, horizontal = earth_rate_parts(lat_deg)
    return np.array([horizontal * np.cos(heading), horizontal * np.sin(heading), vertical])


def windows_of(rows, gyro_var=1e-8, accel_var=1e-6, samples=600):
    """Return Windows of ``rows``; per-sample variances (m/s^2)^2 and (rad/s)^2."""
    m = len(rows)
    col = [np.array([r[i] for r in rows]) for i in range(6)]
    return Windows(col[0], col[1], col[2], np.full(m, samples), col[5], col[4],
                   np.full((m, 3), accel_var), np.full((m, 3), gyro_var), col[3][:, None],
                   np.zeros((m, 1)))
