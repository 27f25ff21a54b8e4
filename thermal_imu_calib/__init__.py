"""thermal_imu_calib: temperature compensation and field thermal calibration of IMUs.

The core (``models``, ``estimation``, ``io``, ``calibration``, ``sim``) imports no ROS
package; ``nodes`` holds the thin rclpy adapters and ``cli`` the offline command line.
All quantities are SI: m/s^2, rad/s, degC, seconds (stamps are int64 nanoseconds).
"""

__version__ = '0.1.0'

# --- user-facing names, imported on first use (restructure.py) ---
_EXPORTS = {
    'calibrate_windows': 'estimation.calibrate',
    'Calibration': 'calibration',
    'CalibrationError': 'calibration',
    'load_transitions': 'collection.motion',
    'LogError': 'io.log_info',
    'LogReader': 'io.bag',
    'LogWriter': 'io.bag_writer',
    'MotionCollector': 'collection.motion',
    'open_log': 'io.bag',
    'save_transitions': 'collection.motion',
    'write_columns': 'io.bag_writer',
}


def __getattr__(name):
    """Resolve ``thermal_imu_calib.<name>`` for the user-facing names above."""
    if name not in _EXPORTS:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import importlib
    module = importlib.import_module(f'{__name__}.{_EXPORTS[name]}')
    return getattr(module, name)
