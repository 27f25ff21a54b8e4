"""Replay IMU and temperature columns onto ROS topics, evenly paced (demo, tests, benches).

A recording from ``thermal_imu_calib.sim`` (or any ImuColumns + temperature series) is
published in header-stamp order at a chosen IMU message rate, so live nodes can be driven
faster than real time without the bursts that best-effort queues would drop.
"""

import math
import time


class Pacer:
    """Sleep so that event i happens at ``start + i / rate`` (evenly paced replay)."""

    def __init__(self, rate):
        self.period = 1.0 / rate if rate and math.isfinite(rate) else 0.0
        self.start = time.perf_counter()

    def wait(self, i):
        """Block until event ``i`` is due (returns at once when behind schedule)."""
        if not self.period:
            return
        delay = self.start + i * self.period - time.perf_counter()
        if delay > 0.0005:
            time.sleep(delay)


def imu_msg(stamp_ns, accel, gyro, frame_id='imu_link'):
    """Build a sensor_msgs/Imu with unknown orientation (orientation_covariance[0] = -1)."""
    from sensor_msgs.msg import Imu
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    m.header.frame_id = frame_id
    m.orientation_covariance[0] = -1.0
    v, w = m.linear_acceleration, m.angular_velocity
    v.x, v.y, v.z = (float(x) for x in accel)
    w.x, w.y, w.z = (float(x) for x in gyro)
    return m


def temperature_msg(stamp_ns, value, frame_id='imu_link'):
    """Build a sensor_msgs/Temperature."""
    from sensor_msgs.msg import Temperature
    m = Temperature()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    m.header.frame_id = frame_id
    m.temperature = float(value)
    return m


def replay(imu_pub, imu, temperatures=(), rate=None, frame_id='imu_link'):
    """Publish IMU columns and temperature series merged in stamp order, evenly paced.

    ``imu`` has ``stamp_ns``, ``accel``, ``gyro``; ``temperatures`` is a sequence of
    (publisher, stamp_ns, values). ``rate`` is IMU messages per second (None: as fast as
    possible). Returns the number of IMU messages published.
    """
    events = [(int(s), 0, i) for i, s in enumerate(imu.stamp_ns)]
    for j, (_, stamps, _) in enumerate(temperatures):
        events += [(int(s), j + 1, i) for i, s in enumerate(stamps)]
    events.sort()
    accel, gyro = imu.accel.tolist(), imu.gyro.tolist()
    pace = Pacer(rate)
    count = 0
    for stamp, kind, i in events:
        if kind == 0:
            pace.wait(count)
            imu_pub.publish(imu_msg(stamp, accel[i], gyro[i], frame_id))
            count += 1
        else:
            pub, _, values = temperatures[kind - 1]
            pub.publish(temperature_msg(stamp, values[i], frame_id))
    return count
