"""Units of the thermal inputs: degC temperatures and non-temperature thermal proxies.

A thermal input is any header-stamped scalar the thermal error follows: a die temperature
in degC, or a *proxy* such as a MEMS gyro's drive-mode resonance frequency in Hz (seed
002). Every input declares its unit; the models' reference values and coefficients are in
that unit (a gyro bias slope in rad/s/Hz for a Hz input).

* ``degC`` (also written ``C``, ``°C``, ``celsius``) is the temperature unit. Its values must be
  plausible die temperatures (``TEMPERATURE_BOUNDS``); anything else is a units mistake.
* Kelvin and Fahrenheit are refused: convert the readings to degC (sensor_msgs/Temperature
  is defined in degC) and declare degC.
* Any other unit string (``Hz``, ``kHz``, ``V``, ``counts``, ...) is a proxy: its values
  need only be finite and its ranges ordered; no bound is assumed.

Nothing here imports ROS; the CLI, the nodes and the calibration file share these rules.
"""

import re

import numpy as np

DEGC = 'degC'
#: plausible die temperatures, degC; anything outside is a units mistake (K or F) or garbage
TEMPERATURE_BOUNDS = (-80.0, 200.0)
_DEGC_ALIASES = {'degc', 'c', '°c', 'celsius', 'deg_c', 'degrees_c'}
_KELVIN = {'k', 'kelvin', 'degk', '°k', 'deg_k'}
_FAHRENHEIT = {'f', 'degf', '°f', 'fahrenheit', 'deg_f', 'degrees_f'}
#: a proxy unit: letters, digits and unit punctuation, no spaces (e.g. Hz, rad/s, 1e-3*V)
_UNIT_RE = re.compile(r'^[A-Za-z0-9µ°%_./^*()+-]{1,32}$')


def normalize_unit(unit, what='temperature input'):
    """Return the canonical unit string (``degC`` for Celsius spellings) or raise ValueError.

    ``what`` names the input in the message (e.g. ``temperature input '/imu/temperature'``).
    """
    u = str(unit).strip()
    low = u.lower()
    if low in _DEGC_ALIASES:
        return DEGC
    if low in _KELVIN:
        return _refuse(what, u, 'Kelvin', 'T[degC] = T[K] - 273.15')
    if low in _FAHRENHEIT:
        return _refuse(what, u, 'Fahrenheit', 'T[degC] = (T[degF] - 32) / 1.8')
    if not _UNIT_RE.match(u):
        raise ValueError(f'{what} has unit {u!r}, which is not a unit string; write degC for '
                         'a temperature or a short unit such as Hz for a thermal proxy (letters, '
                         'digits and ./^*()%_+- only, no spaces)')
    return u


def _refuse(what, unit, name, formula):
    raise ValueError(f'{what} has unit {unit!r} ({name}): temperatures must be in degC; '
                     f'convert the readings ({formula}) and declare degC')


def is_temperature(unit):
    """Return True when ``unit`` is the temperature unit degC."""
    return unit == DEGC


def check_values(values, unit, what):
    """Refuse implausible values of one input: (k,) or (k, 2) in ``unit``; raises ValueError.

    degC values must lie within ``TEMPERATURE_BOUNDS`` (else Kelvin or Fahrenheit by
    mistake); proxy values need only be finite.
    """
    v = np.asarray(values, float)
    if not np.all(np.isfinite(v)):
        raise ValueError(f'{what} {v.tolist()} {unit} is not finite')
    if is_temperature(unit):
        lo, hi = TEMPERATURE_BOUNDS
        if np.any(v < lo) or np.any(v > hi):
            raise ValueError(f'{what} {v.tolist()} degC is outside {lo}..{hi} degC (Kelvin or '
                             'Fahrenheit by mistake?)')


def coefficient_unit(output_unit, input_unit, power):
    """Return the unit of the coefficient of (X - X0)^power in ``output_unit``.

    ``coefficient_unit('rad/s', 'Hz', 1)`` is ``rad/s/Hz``; power 0 is ``output_unit``.
    """
    if power == 0:
        return output_unit
    return f'{output_unit}/{input_unit}' if power == 1 else f'{output_unit}/{input_unit}^{power}'


def reference_description(unit):
    """Return the description of a model's reference input value (T0) in ``unit``."""
    if is_temperature(unit):
        return 'reference temperature per axis'
    return f'reference value of the thermal input per axis ({unit})'


def parse_unit_map(items, topics, option='--input-unit'):
    """Return the units of ``topics`` from ``TOPIC=UNIT`` strings (unnamed topics: degC).

    Topics match as written or without a leading '/'. Raises ValueError naming a topic
    that is not an input, a malformed item or a refused unit.
    """
    units = [DEGC] * len(topics)
    bare = [t.lstrip('/') for t in topics]
    for item in items or ():
        topic, sep, unit = str(item).rpartition('=')
        if not sep or not topic or not unit:
            raise ValueError(f'{option} {item!r} is not TOPIC=UNIT (e.g. '
                             '/imu/gyro_resonance=Hz)')
        if topic.lstrip('/') not in bare:
            raise ValueError(f'{option} names {topic!r}, which is not a thermal input; the '
                             f'inputs are {", ".join(topics) or "none"} (add it with '
                             '--temperature-topic)')
        units[bare.index(topic.lstrip('/'))] = normalize_unit(
            unit, f'thermal input {topic!r}')
    return units


def broadcast_units(units, topics, parameter='temperature_units'):
    """Return one unit per topic from a node parameter: one entry for all, or one per topic.

    Raises ValueError naming the mismatch or the refused unit.
    """
    units = list(units)
    if len(units) == 1:
        units = units * len(topics)
    if len(units) != len(topics):
        raise ValueError(f'{parameter} has {len(units)} entries for {len(topics)} '
                         f'temperature_topics {list(topics)}; give one unit per topic, in the '
                         'same order, or a single unit for all')
    return [normalize_unit(u, f'{parameter} entry for {t!r}') for u, t in zip(units, topics)]
