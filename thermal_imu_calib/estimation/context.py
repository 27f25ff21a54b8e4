"""What every estimator gets, and how an estimator is found for ``--model``.

``make_context`` builds the ``Context`` (windows, options, per-axis thermal inputs, the
reference temperature, coverage); an estimator registered with ``register_estimator`` turns
it into an ``Estimate``. ``ESTIMATOR_MODULES`` lists the modules that register further
families when imported; ``AUTO_POLICY[0]`` picks the model for ``--model auto`` (replaced by
``selection``'s held-out validation).
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..collection.segments import coverage, distinct_orientations, Windows
from ..models.base import SensorModel
from ..models.field import FieldPolynomialModel
from ..thermal_input import ThermalFilter
from .options import (CalibrateOptions, CalibrationRefused, default_input_map, gyro_reference,
                      input_units)


@dataclass
class Context:
    """What every estimator gets: the windows, the options and derived per-axis inputs."""

    windows: Windows
    options: CalibrateOptions
    k: int                      # number of temperature inputs
    ta: np.ndarray              # (m, 3) per-axis accel thermal input of each window
    tg: np.ndarray              # (m, 3) per-axis gyro thermal input (degC or a proxy's unit)
    t0: np.ndarray              # (3,) reference temperature of the accel axes
    accel_input: List[int]
    gyro_input: List[int]
    coverage: dict
    n_orientations: int
    prior_model: Optional[FieldPolynomialModel]
    #: (3,) reference of the gyro axes in their input's unit (None: ``t0``, a degC input)
    t0g: Optional[np.ndarray] = None
    #: bool mask of the windows the accelerometer is fitted on (None: all); the holds left
    #: out by ``hold_consistency`` stay in ``windows`` for the gyro and the pose changes
    accel_rows: Optional[np.ndarray] = None

    def accel_view(self):
        """Return the Context of the accelerometer's windows (``accel_rows``), coverage redone."""
        if self.accel_rows is None or np.all(self.accel_rows):
            return self
        rows = self.accel_rows
        w = self.windows.select(rows)
        return dataclasses.replace(self, windows=w, ta=self.ta[rows], tg=self.tg[rows],
                                   coverage=coverage(w), n_orientations=distinct_orientations(w),
                                   accel_rows=None)

    @property
    def gyro_unit(self):
        """Return the unit of the gyro axes' thermal input ('degC' without inputs)."""
        if not self.k or not self.options.inputs:
            return 'degC'
        return getattr(self.options.inputs[self.gyro_input[0]], 'unit', 'degC')

    def subset(self, rows):
        """Return the Context of the windows ``rows`` (bool mask).

        Input mapping and references are kept, so a fit on training holds is comparable
        with the one on all windows.
        """
        return dataclasses.replace(self, windows=self.windows.select(rows), ta=self.ta[rows],
                                   tg=self.tg[rows])

    @property
    def gyro_t0(self):
        """Return the gyro reference input (t0g, or t0 when the gyro input is degC)."""
        return self.t0 if self.t0g is None else self.t0g


@dataclass
class Estimate:
    """What an estimator returns; a None gyro gets the default bias polynomial."""

    accel: Optional[SensorModel] = None
    gyro: Optional[SensorModel] = None
    notes: List[str] = field(default_factory=list)
    fit: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)
    #: the lag of the temperature inputs the models were fitted in (None: the reading)
    temperature_filter: Optional[ThermalFilter] = None


#: model name -> estimator(Context) -> Estimate; see ``register_estimator``
ESTIMATORS = {}
#: modules that register estimators when imported (one line per model family; the built-in
#: offset and field first, as ``calibrate`` imports them)
ESTIMATOR_MODULES = ['thermal_imu_calib.estimation.builtin_estimators',
                     'thermal_imu_calib.estimation.standard_fit',
                     'thermal_imu_calib.estimation.whole_unit_fit',
                     'thermal_imu_calib.estimation.baselines',
                     'thermal_imu_calib.selection.select',
                     'thermal_imu_calib.selection.static_select',
                     'thermal_imu_calib.selection.gyro_select',
                     'thermal_imu_calib.selection.history_select']


def register_estimator(name):
    """Register an estimator under a ``--model`` name (decorator)."""
    def deco(fn):
        ESTIMATORS[name] = fn
        return fn
    return deco


def model_choices():
    """Return the accepted ``--model`` names (``auto`` first)."""
    _load_plugins()
    return ('auto',) + tuple(ESTIMATORS)


def estimator(name):
    """Return the estimator registered as ``name`` (its module imported first if needed).

    KeyError for a name no module registers.
    """
    if name not in ESTIMATORS:
        _load_plugins()
    return ESTIMATORS[name]


def _load_plugins():
    import importlib
    for mod in ESTIMATOR_MODULES:
        importlib.import_module(mod)


def auto_choice(ctx):
    """Pick the model for ``--model auto``: offset-only for one pose, else the field model.

    Returns (name, reason). Model families may replace this with held-out validation.
    """
    if ctx.n_orientations == 1:
        return 'offset', 'one orientation only: offset-only drift model'
    return 'field', f'{ctx.n_orientations} orientations: seed 000 field model'


#: the ``auto`` policy; replaceable (e.g. by held-out validation across families)
AUTO_POLICY = [auto_choice]


def make_context(windows, options=None):
    """Build the estimators' Context: input mapping, per-axis inputs, reference, coverage.

    The reference temperature is the prior's, else the middle of the collected range;
    a prior must be a seed 000 field calibration (CalibrationRefused otherwise).
    """
    o = options or CalibrateOptions()
    k = windows.n_inputs
    units = input_units(o, k)
    default_accel, default_gyro = default_input_map(units)
    accel_input = o.accel_input or default_accel
    gyro_input = o.gyro_input or default_gyro
    ta = windows.temp[:, accel_input] if k else np.zeros((len(windows), 3))
    tg = windows.temp[:, gyro_input] if k else np.zeros((len(windows), 3))
    prior_model = o.prior.accel if o.prior is not None else None
    if prior_model is not None and not isinstance(prior_model, FieldPolynomialModel):
        raise CalibrationRefused('the prior calibration has no seed 000 accelerometer model',
                                 'pass a field_polynomial calibration as --prior')
    if prior_model is not None:
        t0 = prior_model.t0.copy()
    else:
        t0 = np.round((ta.min(0) + ta.max(0)) / 2.0, 2) if k else np.zeros(3)
    return Context(windows, o, k, ta, tg, t0, accel_input, gyro_input, coverage(windows),
                   distinct_orientations(windows), prior_model,
                   gyro_reference(units, gyro_input, tg, t0) if k else None)
