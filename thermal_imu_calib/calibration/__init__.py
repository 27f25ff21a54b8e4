"""The calibration object and its versioned, self-describing YAML file.

* ``core.py``: ``Calibration`` (apply, covariance, write, load) and ``Compensated``;
* ``schema.py``: the file's schema, every field with its type, default and checks, and
  the rules that tie fields together (the file format is described there);
* ``spec.py``: the words the schema is written in (text, numbers, mapping, ...);
* ``plausible.py``: numbers no IMU has, a model that breaks inside its valid range;
* ``yaml_text.py``: the text before the schema (file, size, UTF-8, nesting, aliases);
* ``base.py``: ``CalibrationError``, ``TemperatureInput`` and the limits.

``from thermal_imu_calib.calibration import Calibration`` is the public entry point.
"""

from ..input_units import TEMPERATURE_BOUNDS
from .base import (CalibrationError, FILE_FORMATS, FORMAT, GRAVITY_BOUNDS, MAX_DEPTH,
                   MAX_FILE_BYTES, MAX_NODES, NOISE_UNITS, out_unit, OUT_OF_RANGE_POLICIES,
                   TemperatureInput)
from .core import Calibration, Compensated, spanning_range
from .yaml_text import check_yaml_shape, decode_text

__all__ = ['Calibration', 'CalibrationError', 'Compensated', 'FILE_FORMATS', 'FORMAT',
           'TemperatureInput',
           'TEMPERATURE_BOUNDS', 'GRAVITY_BOUNDS', 'MAX_DEPTH', 'MAX_FILE_BYTES', 'MAX_NODES',
           'NOISE_UNITS', 'OUT_OF_RANGE_POLICIES', 'check_yaml_shape', 'decode_text',
           'out_unit', 'spanning_range']
