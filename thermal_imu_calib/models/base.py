"""The one interface every thermal model family implements, and its parameter container."""

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Optional

import numpy as np

MODEL_KINDS = {}


def highest_power(rows):
    """Return the highest power with a non-zero entry; 0 when none.

    ``rows``: (m, 3) coefficients per axis, row i multiplying the input's power i + 1.
    """
    used = np.flatnonzero(np.any(np.asarray(rows) != 0.0, axis=1))
    return int(used[-1]) + 1 if used.size else 0


def register(cls):
    """Class decorator: make a model family loadable from a calibration file by its ``kind``."""
    MODEL_KINDS[cls.kind] = cls
    return cls


@dataclass
class Param:
    """One named parameter: value, unit, 1-sigma standard deviation (same shape, or None)."""

    value: np.ndarray
    unit: str
    std: Optional[np.ndarray] = None
    description: str = ''

    def to_dict(self):
        """Return a YAML-friendly dict (lists of floats)."""
        d = {'value': np.asarray(self.value, float).tolist(), 'unit': self.unit}
        if self.std is not None:
            d['std'] = np.asarray(self.std, float).tolist()
        if self.description:
            d['description'] = self.description
        return d

    @staticmethod
    def from_dict(d, name='parameter'):
        """Rebuild from ``to_dict`` output; raises ValueError naming the bad parameter."""
        if not isinstance(d, dict) or 'value' not in d or 'unit' not in d:
            raise ValueError(f'parameter {name!r} needs "value" and "unit"')
        value = np.asarray(d['value'], float)
        std = None if d.get('std') is None else np.asarray(d['std'], float)
        if not np.all(np.isfinite(value)):
            raise ValueError(f'parameter {name!r} has non-finite values')
        if std is not None and std.shape != value.shape:
            raise ValueError(f'parameter {name!r}: std shape {std.shape} != value shape '
                             f'{value.shape}')
        return Param(value, str(d['unit']), std, str(d.get('description', '')))


class SensorModel(ABC):
    """Raw triad output -> corrected triad output, as a function of per-axis temperature.

    ``temps`` is always (n, 3) in the input unit (degC, or a thermal proxy's unit such as
    Hz: ``input_unit``), already mapped to axes and clamped by the Calibration; ``aux``
    carries other corrected signals a family may need (e.g. the corrected specific force
    for a gyro g-sensitivity term), keyed by name.
    """

    kind: ClassVar[str] = ''
    #: 'accel' (m/s^2) or 'gyro' (rad/s)
    sensor: str = 'accel'
    #: unit of the thermal input the model is a function of: degC, or a proxy's unit (Hz);
    #: reference values and temperature coefficients are in it (``Calibration`` sets it
    #: from the inputs the model is mapped to)
    input_unit: str = 'degC'

    @abstractmethod
    def correct(self, raw, temps, aux=None):
        """Return the corrected (n, 3) signal for raw (n, 3) at thermal inputs (n, 3)."""

    def forward(self, true, temps, aux=None):
        """Return the raw (n, 3) output this model predicts for a true input (the inverse)."""
        raise NotImplementedError(f'{self.kind} has no forward model')

    def predict_std(self, temps):
        """Return the (n, 3) 1-sigma model uncertainty of the corrected output, or None."""
        return None

    def temperature_degree(self):
        """Return the highest power of the thermal input the model uses (inf: not a polynomial).

        0: temperature-independent; 1: linear. A model that is not a polynomial in its input
        (e.g. kernels) returns ``math.inf``.
        """
        return math.inf

    @abstractmethod
    def params(self):
        """Return an ordered dict name -> Param."""

    @classmethod
    @abstractmethod
    def from_params(cls, params, meta):
        """Rebuild from a name -> Param dict and the model's metadata dict."""

    def meta(self):
        """Return the family's non-parameter settings (orders, flags) for the file."""
        return {}

    @property
    def unit(self):
        """Return the unit of the corrected signal."""
        return 'm/s^2' if self.sensor == 'accel' else 'rad/s'

    def to_dict(self):
        """Return the model section of a calibration file."""
        return {'kind': self.kind, 'sensor': self.sensor, 'unit': self.unit,
                'meta': self.meta(),
                'parameters': {k: p.to_dict() for k, p in self.params().items()}}


def model_from_dict(d, where='model'):
    """Rebuild any registered model family from its file section."""
    if not isinstance(d, dict) or 'kind' not in d:
        raise ValueError(f'{where}: missing "kind"')
    kind = d['kind']
    if kind not in MODEL_KINDS:
        raise ValueError(f'{where}: unknown model kind {kind!r}; known: {sorted(MODEL_KINDS)}. '
                         'Was the file written by a newer thermal_imu_calib?')
    raw_params = d.get('parameters') or {}
    params = {k: Param.from_dict(v, f'{where}.{k}') for k, v in raw_params.items()}
    model = MODEL_KINDS[kind].from_params(params, d.get('meta') or {})
    model.sensor = d.get('sensor', model.sensor)
    return model


def input_unit_of(params, meta, ref='T0'):
    """Return the input unit a model section was written in.

    That is ``meta.input_unit``, else the unit of its reference value ``ref``, else degC
    (files written before proxy inputs).
    """
    if meta.get('input_unit'):
        return str(meta['input_unit'])
    if ref in params and params[ref].unit:
        return params[ref].unit
    return 'degC'


def with_input_unit(meta, unit):
    """Return ``meta`` plus ``input_unit`` when it is not degC (degC files stay as before)."""
    return meta if unit == 'degC' else {**meta, 'input_unit': unit}


def require(params, name, shape, where):
    """Fetch a parameter value of a given shape or raise ValueError naming it."""
    if name not in params:
        raise ValueError(f'{where}: missing parameter {name!r}')
    v = params[name].value
    if v.shape != shape:
        raise ValueError(f'{where}: parameter {name!r} has shape {v.shape}, expected {shape}')
    return v
