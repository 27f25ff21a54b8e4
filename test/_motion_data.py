"""Simulated recordings whose gyro has a known scale/misalignment, for the pose-change tests.

``Distorted`` multiplies the simulated raw gyro by ``GYRO_M`` (raw' = M raw: scale errors
0.25-0.3 %, misalignment 0.6-1.2 mrad), so the true Omega1 of what is written is
``Omega1_sim M^-1`` whatever the simulator's own gyro errors are.
"""

import numpy as np

from thermal_imu_calib import sim
from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import ImuColumns

GYRO_M = np.array([[1.003, 8e-4, -1.2e-3], [-6e-4, 0.9975, 9e-4], [1.1e-3, -7e-4, 1.002]])
#: a shorter mems-coldstart: 2 x (six faces + 4 corners up), 25-35 s holds (11 min, 130k
#: samples at 200 Hz, 19 pose changes)
SHORT_COLDSTART = dict(faces=sim.SIX_FACES + (sim.TILTED,) * 4, repetitions=2,
                       hold_s=(25.0, 35.0))


class Distorted:
    """A SimRecording whose raw gyro is ``GYRO_M`` times the simulated one."""

    def __init__(self, rec):
        self.rec = rec

    def __getattr__(self, name):
        return getattr(self.rec, name)

    def imu_chunks(self, chunk_size=None):
        """Yield the recording's ImuColumns with the gyro distorted."""
        for c in self.rec.imu_chunks(chunk_size):
            yield ImuColumns(c.stamp_ns, c.accel, c.gyro @ GYRO_M.T, c.frame_id)

    def imu(self):
        """Return the whole (distorted) recording as one ImuColumns."""
        return ImuColumns.concat(list(self.imu_chunks()))

    def true_omega1(self):
        """Return the Omega1 that maps the written raw gyro to the true rate."""
        p = self.rec.truth.gyro.params()
        om1 = p['Omega1'].value if 'Omega1' in p else np.eye(3)
        return om1 @ np.linalg.inv(GYRO_M)

    def write(self, path):
        """Write the distorted recording as a log (IMU + temperature topics)."""
        write_columns(path, self.rec.imu_topic, self.imu_chunks(), self.rec.temperatures)
        return path


def recording(scenario, seed, **overrides):
    """Return ``Distorted(sim.simulate(scenario, seed, **overrides))``."""
    return Distorted(sim.simulate(scenario, seed, **overrides))
