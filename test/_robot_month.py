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


def lifelong_month(directory, config, seed=3, days=1.5, latitude=45.0):
    """Return the ``Lifelong`` loop after ``days`` of robot month ``seed`` fed through it.

    The node's path without DDS (``lifelong.feed.Feeder``, a ``cmd_vel`` motion hint), in
    ``directory``, with ``LifelongConfig`` ``config`` and the latitude (deg) known.
    """
    from thermal_imu_calib.app.calibrate import CalibrateSettings
    from thermal_imu_calib.lifelong.feed import Feeder
    from thermal_imu_calib.lifelong.hints import HintGate, HintSource
    from thermal_imu_calib.lifelong.manager import Lifelong
    from thermal_imu_calib.sim.robot_month import robot_month
    m = robot_month(seed, days=days)
    life = Lifelong(str(directory), CalibrateSettings(latitude=latitude), 1,
                    ['/imu/temperature'], 'imu_link', config=config)
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    for seg in m.segments():
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    return life
