"""thermal_imu_calib: temperature compensation and field thermal calibration of IMUs.

The core (``models``, ``estimation``, ``io``, ``calibration``, ``sim``) imports no ROS
package; ``nodes`` holds the thin rclpy adapters and ``cli`` the offline command line.
All quantities are SI: m/s^2, rad/s, degC, seconds (stamps are int64 nanoseconds).
"""

__version__ = '0.1.0'
