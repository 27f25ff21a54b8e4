"""The windows the stationary detector gives on a simulated robot month (lifelong tests)."""

from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.collection.stationary import DetectorConfig, StationaryDetector
from thermal_imu_calib.io.align import StreamAligner


def detector_windows(m):
    """Return the ``Windows`` of every stop of the RobotMonth ``m`` (one thermal input)."""
    det, al = StationaryDetector(DetectorConfig(), 1), StreamAligner(1, 2.0)
    parts = []
    for seg in m.segments():
        for a in al.push_columns(seg.imu, [seg.temperature]):
            parts.append(det.update(a.imu.t, a.imu.accel, a.imu.gyro, a.temps))
    parts.append(det.finish())
    return Windows.concat(parts)
