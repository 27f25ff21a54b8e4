"""Column containers exchanged between log I/O, estimators and compensation.

Every reader yields these, every estimator consumes them; nothing downstream sees a
per-message object, so a bulk CDR decoder can replace a per-message one freely.
"""

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ImuColumns:
    """A chunk of IMU samples as columns.

    Attributes
    ----------
    stamp_ns: (n,) int64 header stamps in nanoseconds.
    accel: (n, 3) float64 specific force in m/s^2 (``linear_acceleration``).
    gyro: (n, 3) float64 angular rate in rad/s (``angular_velocity``).
    frame_id: header frame_id of the chunk ('' when mixed or unknown).

    """

    stamp_ns: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    frame_id: str = ''

    def __len__(self):
        return int(self.stamp_ns.shape[0])

    @property
    def t(self):
        """Stamps in seconds (float64)."""
        return self.stamp_ns.astype(np.float64) * 1e-9

    def slice(self, sl):
        """Return the rows selected by ``sl`` as a new chunk."""
        return ImuColumns(self.stamp_ns[sl], self.accel[sl], self.gyro[sl], self.frame_id)

    @staticmethod
    def concat(chunks):
        """Concatenate chunks (keeps the first frame_id)."""
        chunks = [c for c in chunks if len(c)]
        if not chunks:
            return ImuColumns.empty()
        return ImuColumns(np.concatenate([c.stamp_ns for c in chunks]),
                          np.concatenate([c.accel for c in chunks]),
                          np.concatenate([c.gyro for c in chunks]),
                          chunks[0].frame_id)

    @staticmethod
    def empty(frame_id=''):
        """Return a chunk with no rows."""
        return ImuColumns(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), frame_id)


@dataclass
class TemperatureColumns:
    """Temperature samples of one input as columns: stamps (int64 ns) and values in degC."""

    stamp_ns: np.ndarray
    temperature: np.ndarray
    frame_id: str = ''

    def __len__(self):
        return int(self.stamp_ns.shape[0])

    @staticmethod
    def empty():
        """Return a series with no samples."""
        return TemperatureColumns(np.zeros(0, np.int64), np.zeros(0))


@dataclass
class AlignedChunk:
    """IMU samples with every temperature input resolved at the IMU stamps.

    Attributes
    ----------
    imu: the IMU columns.
    temps: (n, k) float64 degC, one column per temperature input (k may be 0).
    temp_age: (n, k) float64 seconds to the nearest real temperature sample
        (0 when interpolated between samples closer than the gap limit).
    extra: passthrough data a reader attaches (e.g. raw CDR buffers for patching).

    """

    imu: ImuColumns
    temps: np.ndarray
    temp_age: np.ndarray
    extra: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.imu)
