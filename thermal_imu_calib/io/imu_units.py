"""Is the IMU in SI units? The accelerometer's |a| against gravity, the gyro's deg/s rows.

sensor_msgs/Imu is in m/s^2 and rad/s (REP 145). A driver publishing g, milli-g, raw counts
or deg/s gets garbage out of any calibration. ``calibrate`` refuses such holds
(``estimation.calibrate._check_accel_units``, the input gate's ``gyro_unit_rows``); the
compensator cannot refuse a stream, so ``UnitWatch`` watches it and says what is wrong.

* accelerometer: the median |a| over ``ACCEL_WINDOW`` samples over gravity. Whatever the
  robot does, over seconds it averages about 1 g; outside ``ACCEL_AT_REST`` the unit is
  wrong (0.10: g, about 100: milli-g, far more: counts);
* gyro: ``gate.gyro_unit_rows`` (|w| beyond any gyroscope in rad/s, as much as a hand
  turns in deg/s, with the accelerometer in range), ``GYRO_UNIT_ROWS`` of them.

Each problem is (what was seen, the rule it breaks, what to do); ``gate.unit_refusal``
makes a recording's refusal of it, the compensator its warning.
"""

import numpy as np

from .gate import gyro_unit_problem, gyro_unit_rows

#: range of |a| / g at rest in which the accelerometer is taken to be in m/s^2 (the loader's
#: scale-factor bounds, ``calibration.plausible``); outside it the unit is wrong
ACCEL_AT_REST = (0.25, 4.0)
#: samples whose median |a| the compensator compares with gravity (a few seconds)
ACCEL_WINDOW = 500


def accel_unit_problem(at_rest, gravity, where='at rest'):
    """Return None, or (what was seen, the rule it breaks, what to do) for a median |a|.

    ``at_rest``: the median |a| (m/s^2); ``where``: how it was taken, for the text ('at
    rest': over still holds).
    """
    r = at_rest / gravity
    if ACCEL_AT_REST[0] <= r <= ACCEL_AT_REST[1]:
        return None
    unit = ('in g' if 0.08 <= r <= 0.13 else 'in milli-g' if 80 <= r <= 130 else
            'in raw counts or another unit')
    return (f'the accelerometer reads |a| = {at_rest:.4g} {where}, {r:.3g} times gravity '
            f'({gravity:.6g} m/s^2): its values look {unit}',
            'while sensor_msgs/Imu linear_acceleration is in m/s^2 (REP 145)',
            'publish the IMU in m/s^2 (for g, multiply by 9.80665; check the driver\'s scale '
            'or unit parameters)')


class UnitWatch:
    """Watch an IMU stream for values not in m/s^2 and rad/s (``push`` batches of rows)."""

    def __init__(self, gravity, window=ACCEL_WINDOW):
        self.gravity = float(gravity)
        self.window = int(window)
        self._norms = np.empty(0)
        #: samples seen whose gyro reads like deg/s (``gate.gyro_unit_rows``)
        self.gyro_unit = 0
        #: median |a| / g of the latest full window of samples (None: none yet), so a
        #: driver fixed at run time clears it
        self.accel_ratio = None

    def push(self, accel, gyro):
        """Take (n, 3) accel (m/s^2) and gyro (rad/s) rows, finite or not."""
        self.gyro_unit += int(gyro_unit_rows(accel, gyro).sum())
        with np.errstate(over='ignore', invalid='ignore'):   # a value near 1e308: inf, left out
            a = np.linalg.norm(np.asarray(accel, float), axis=1)
        norms = np.concatenate([self._norms, a[np.isfinite(a)]])
        full = len(norms) // self.window
        if full:
            last = norms[(full - 1) * self.window:full * self.window]
            self.accel_ratio = float(np.median(last)) / self.gravity
        self._norms = norms[full * self.window:]

    def problems(self):
        """Return {'accel' / 'gyro': (seen, rule, fix)} for what looks not in SI (or {})."""
        out = {'accel': None if self.accel_ratio is None else accel_unit_problem(
                   self.accel_ratio * self.gravity, self.gravity,
                   f'(median of {self.window} samples)'),
               'gyro': gyro_unit_problem(self.gyro_unit)}
        return {k: v for k, v in out.items() if v}
