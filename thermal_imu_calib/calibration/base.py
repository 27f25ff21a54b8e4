"""What every part of the calibration package shares: its error, its input type, its limits."""

from dataclasses import dataclass

from ..input_units import DEGC, normalize_unit

FORMAT = 'thermal_imu_calib/1'
#: format 1 plus ``temperature.sensor_range`` (one sensor's model valid over a narrower range,
#: a lifelong one-sensor swap). Written only by files that have it, so that a version that
#: knows format 1 only refuses them ("needs a newer version") instead of ignoring the range
#: and extrapolating that model; every other file stays format 1.
FORMAT_SENSOR_RANGE = 'thermal_imu_calib/2'
#: format 2 plus the out-of-range policies 'linear' and 'linear_gyro'. Written only by files
#: that use them, so that an older version refuses them instead of clamping a model that
#: was meant to be continued.
FORMAT_LINEAR = 'thermal_imu_calib/3'
#: format 3 plus ``gyro_ageing`` (a gyro bias that drifts in time at a fitted rate, carried
#: forward from the estimate's time on the IMU's stamps). Written only by files that have
#: it, so that an older version refuses them instead of holding the bias of that time
FORMAT_AGEING = 'thermal_imu_calib/4'
#: format 4 plus ``gyro_ageing.offset`` (the gyro bias moved by a constant at the epoch: a
#: lifelong node's offset follower, ``lifelong.follower``). Written only by files that have
#: it, so that an older version refuses them instead of dropping that offset
FORMAT_OFFSET = 'thermal_imu_calib/5'
FILE_FORMATS = (FORMAT, FORMAT_SENSOR_RANGE, FORMAT_LINEAR, FORMAT_AGEING, FORMAT_OFFSET)
#: seconds per day: the unit of ``Calibration.gyro_ageing``'s rate and bound
DAY_S = 86400.0
#: outside the valid range: 'clamp' holds the edge value (as PX4 and ArduPilot do);
#: 'extrapolate' evaluates the models there; 'linear' continues each model from the edge
#: with its slope over the last ``LINEAR_STEP_DEGC`` inside, no further than the range's
#: width (then held); 'linear_gyro' continues the
#: gyro linearly and clamps the accelerometer
OUT_OF_RANGE_POLICIES = ('clamp', 'extrapolate', 'linear', 'linear_gyro')
#: the policies of format 1 and 2 files
OUT_OF_RANGE_V1 = ('clamp', 'extrapolate')
#: the step (degC) inside the edge a linear continuation takes its slope over; an input in
#: another unit (a proxy) uses ``LINEAR_STEP_FRACTION`` of its valid range
LINEAR_STEP_DEGC = 1.0
LINEAR_STEP_FRACTION = 0.05
#: a calibration file is a few kB; these bound what a hostile one can cost before it is read
MAX_FILE_BYTES = 4 * 2 ** 20
#: deepest nesting of YAML mappings/sequences accepted (a real file nests < 10 deep)
MAX_DEPTH = 64
#: most YAML nodes after alias expansion (an alias bomb expands to billions)
MAX_NODES = 200_000
#: gravity values a file may carry, m/s^2 (cf. gravity.resolve_gravity)
GRAVITY_BOUNDS = (9.7, 9.9)
#: units of the Allan noise-model entries of the ``noise`` section
NOISE_UNITS = {'accel_noise_density': 'm/s^2/sqrt(Hz)', 'gyro_noise_density': 'rad/s/sqrt(Hz)',
               'accel_random_walk': 'm/s^3/sqrt(Hz)', 'gyro_random_walk': 'rad/s^2/sqrt(Hz)',
               'rate_hz': 'Hz', 'horizon_s': 's'}


class CalibrationError(ValueError):
    """A calibration file or object that cannot be used; the message says why and what to do."""


@dataclass
class TemperatureInput:
    """One thermal input the models use (a topic in ROS, a column offline).

    ``unit`` is degC for a temperature, or a proxy's unit (e.g. Hz); Kelvin and Fahrenheit
    raise ValueError (convert to degC).
    """

    name: str
    topic: str = 'imu/temperature'
    unit: str = DEGC

    def __post_init__(self):
        self.unit = normalize_unit(self.unit, f'temperature input {self.name!r}')


def out_unit(name):
    """Return the SI unit of the accel or gyro output."""
    return 'm/s^2' if name == 'accel' else 'rad/s'


def type_name(x):
    """Name the YAML type of a value for a message: 'text', 'a list', 'nothing', ..."""
    if x is None:
        return 'nothing'
    if isinstance(x, bool):
        return 'a boolean'
    if isinstance(x, str):
        return 'text'
    if isinstance(x, (int, float)):
        return 'a number'
    if isinstance(x, dict):
        return 'a mapping'
    if isinstance(x, (list, tuple)):
        return 'a list'
    return f'a {type(x).__name__}'


def short(x, n=60, use_repr=True):
    """Return ``repr(x)`` (or ``str``) cut to ``n`` characters for a message."""
    s = repr(x) if use_repr else str(x)
    return s if len(s) <= n else s[:n] + '...'
