"""What one estimation run is asked and gives back, and how its inputs map to the axes.

``CalibrateOptions`` (SI units) and ``CalibrationResult``; ``CalibrationRefused`` says what
is wrong and what to collect. The temperature (or proxy) inputs: their units, the default
axis mapping (``default_input_map``), the gyro's reference input, and the valid range a
calibration gets (the collected range widened by ``input_margins``).
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..calibration import Calibration, TemperatureInput
from ..gravity import STANDARD_GRAVITY
from ..input_units import DEGC, is_temperature

#: valid-range margin of a proxy input (e.g. Hz) when no degC input is there to scale the
#: degC margin by: this fraction of the collected span on both sides (1 degC of a 17-degC
#: warm-up is 6 %)
PROXY_MARGIN_FRACTION = 0.05


def hold_seconds(s):
    """Return a hold duration (s) for a refusal's advice: '0.5', '10' (not '0' or '0.50')."""
    return f'{round(float(s), 2):g}'


class CalibrationRefused(Exception):
    """Estimation refused: ``reason`` says what is wrong, ``advice`` what to collect."""

    def __init__(self, reason, advice=''):
        super().__init__(f'{reason}. {advice}'.strip())
        self.reason = reason
        self.advice = advice


@dataclass
class CalibrateOptions:
    """Settings of one estimation run (SI units)."""

    model: str = 'auto'
    gravity: float = STANDARD_GRAVITY
    gravity_source: str = 'standard gravity 9.80665 m/s^2'
    prior: Optional[Calibration] = None
    inputs: List[TemperatureInput] = field(default_factory=list)
    accel_input: Optional[List[int]] = None
    gyro_input: Optional[List[int]] = None
    frame_id: str = ''
    out_of_range: str = 'clamp'
    order: int = 2
    refine: bool = True
    min_hold_s: float = 10.0
    #: the valid range is the collected range widened by this much on both sides (degC):
    #: a low-order polynomial is trustworthy just past its data, a clamp at the exact data
    #: edge is not (the next warm-up often ends a little higher)
    range_margin: float = 1.0
    #: None: every model gets ``range_margin``. A number (degC): a sensor whose model is
    #: above first order in its input (``SensorModel.temperature_degree``) gets this margin
    #: instead (0: clamped at the collected range), through ``Calibration.sensor_range``.
    #: Off by default: judged in docs/lifelong.md (2026-12-05). For both sensors the
    #: lifelong gyro lost; for the accelerometer alone the months gained but the seed 000
    #: warm-ups (bench_nav_accuracy) lost, since their validation runs past the range
    high_order_margin: Optional[float] = None
    #: the sensors ``high_order_margin`` applies to: 'both', 'accel' or 'gyro'
    high_order_sensors: str = 'accel'
    #: the holds are separate placements (a robot's stops: each an unknown pose), so a
    #: held-out fold of the thermal history never keeps a test hold's other windows in
    #: training (``selection.time_folds.whole_holds``); False: window folds (one mounting)
    placement_folds: bool = False
    #: one orientation, holds that are separate placements (lifelong): a sensor's thermal
    #: model must also be no worse than its output as it is when whole placements (groups
    #: of holds) are left out (``selection.placements``); else it gets no thermal terms.
    #: Checked on every candidate of the one-way bands, on the family kept without bands and
    #: on the history path's choice. False: the held-out blocks alone decide
    placement_floor: bool = False
    #: the holds are separate placements: in the thermal-history fits (``hysteresis.fit_spec``)
    #: each hold's level is a random effect, its variance estimated (REML,
    #: ``estimation.placement_levels``), so levels that differ from stop to stop (floor
    #: tilt, heading) are not read as temperature. False: every window independent
    placement_levels: bool = False
    #: the sensors ``placement_levels`` applies to: 'both', 'accel' or 'gyro'
    #: (``HIGH_ORDER_SENSORS``' names)
    placement_levels_sensors: str = 'both'
    #: {sensor: ``hysteresis.Spec`` or 'rvm'}: the spec of the calibration in use (lifelong
    #: ``incumbent_spec``). The history path (``time_folds.select_history``) scores it with
    #: the other candidates and keeps it whenever it is in the pool (within ``MARGIN`` of the
    #: best, no worse than the flight stacks' cubic); None: the simplest of the pool
    incumbent_specs: Optional[dict] = None
    #: margins by unit, {unit: margin in that unit} (e.g. {'Hz': 2.0}); a proxy unit not
    #: named here gets ``range_margin`` scaled by the ratio of its collected span to the
    #: degC inputs' (see ``input_margins``)
    unit_margins: Optional[dict] = None
    #: geodetic latitude (deg) when known: the gyro fit removes earth rotation with it
    latitude: Optional[float] = None
    #: pose changes between holds (``gyro_fit.Transition``, e.g. from
    #: ``gyro_fit.MotionCollector``; hold ids as in the windows): the ``whole_unit``
    #: estimator fits gyro scale and misalignment (Omega1, Omega2, Omega3) from them
    transitions: list = field(default_factory=list)
    #: accelerometer residual of ``whole_unit``: 'norm' (|a| - g per window) or 'vector'
    whole_unit_residual: str = 'norm'
    #: prior means and stds of ``whole_unit`` (``whole_unit_fit.Priors``; None: the
    #: consumer-MEMS defaults)
    whole_unit_priors: Optional[object] = None

    def level_sensors(self):
        """Return the sensors whose fits take a random level per placement (a tuple)."""
        if not self.placement_levels:
            return ()
        return sensor_set('placement_levels_sensors', self.placement_levels_sensors)

    def levels(self, sensor):
        """Return whether ``sensor``'s fits take a random level per placement."""
        return sensor in self.level_sensors()


@dataclass
class CalibrationResult:
    """A new calibration, a one-line human summary and a machine-readable report."""

    calibration: Calibration
    summary: str
    report: dict


def _default_axis_inputs(k):
    if k == 0:
        return [0, 0, 0]
    return [0, 1, 2] if k == 3 else [0, 0, 0]


def input_units(options, k):
    """Return the unit of each of the k inputs (degC when the options name none)."""
    units = [getattr(i, 'unit', DEGC) for i in options.inputs]
    return units if len(units) == k else [DEGC] * k


def default_input_map(units):
    """Return the default (accel_input, gyro_input) axis mapping for inputs of ``units``.

    The accelerometer follows the degC inputs: three of them drive the x, y, z axes, else
    the first drives all three. The gyro follows the one non-degC input (a thermal proxy
    such as its resonance frequency) when there is exactly one, else input 0. With only
    degC inputs this is the mapping of files written before proxies.
    """
    k = len(units)
    temps = [j for j, u in enumerate(units) if is_temperature(u)]
    proxies = [j for j, u in enumerate(units) if not is_temperature(u)]
    if len(temps) == k:
        accel = _default_axis_inputs(k)
    elif len(temps) == 3:
        accel = temps
    else:
        accel = [temps[0] if temps else 0] * 3
    gyro = [proxies[0]] * 3 if len(proxies) == 1 else [0, 0, 0]
    return accel, gyro


def gyro_reference(units, gyro_input, tg, t0):
    """Return the gyro models' (3,) reference input: ``t0`` for degC, else mid-range of tg.

    A proxy has no relation to the accelerometer's reference temperature; its reference
    is the middle of its collected range (rounded to 0.01 of its unit).
    """
    if not units or all(is_temperature(units[i]) for i in gyro_input):
        return t0
    return np.round((tg.min(0) + tg.max(0)) / 2.0, 2)


def input_margins(windows, options):
    """Return the (k,) valid-range margin of each input, in its unit.

    An input whose unit is in ``unit_margins`` gets that; other degC inputs get
    ``range_margin``; other proxies ``range_margin`` degC expressed in their unit through
    the ratio of their collected span to the median span of the degC inputs (exact for a
    proxy linear in the same temperature), else, without a degC input,
    ``PROXY_MARGIN_FRACTION`` of their span.
    """
    k = windows.n_inputs
    units = input_units(options, k)
    explicit = options.unit_margins or {}
    span = np.ptp(windows.temp, axis=0) if len(windows) else np.zeros(k)
    t_span = [span[j] for j, u in enumerate(units) if is_temperature(u) and span[j] > 0]
    out = np.full(k, float(options.range_margin))
    for j, u in enumerate(units):
        if u in explicit:
            out[j] = float(explicit[u])
        elif is_temperature(u):
            continue
        elif t_span:
            out[j] = options.range_margin * span[j] / float(np.median(t_span))
        else:
            out[j] = PROXY_MARGIN_FRACTION * span[j]
    return out


def valid_range(windows, options):
    """Return the (k, 2) valid range: the collected range widened by ``input_margins``."""
    if not windows.n_inputs:
        return None
    m = input_margins(windows, options)
    return np.stack([windows.temp.min(0) - m, windows.temp.max(0) + m], 1)


#: ``high_order_sensors`` -> the sensors ``high_order_margin`` applies to
HIGH_ORDER_SENSORS = {'both': ('accel', 'gyro'), 'accel': ('accel',), 'gyro': ('gyro',)}


def sensor_set(option, value):
    """Return the sensors a ``HIGH_ORDER_SENSORS`` name stands for; refuse another name."""
    if value not in HIGH_ORDER_SENSORS:
        raise ValueError(f'{option} {value!r} is not one of {", ".join(HIGH_ORDER_SENSORS)}')
    return HIGH_ORDER_SENSORS[value]


def narrow_high_order(cal, windows, options):
    """Give each model above first order ``high_order_margin`` instead of ``range_margin``.

    In place on ``cal`` (its ``valid_range`` as ``valid_range`` gives it): such a model's
    range becomes the collected range widened by ``high_order_margin`` (proxies scaled as
    in ``input_margins``), through ``Calibration.sensor_range``; when every model is above
    first order, ``valid_range`` itself. Nothing changes when ``high_order_margin`` is None
    or there are no inputs.
    """
    which = sensor_set('high_order_sensors', options.high_order_sensors)
    if options.high_order_margin is None or cal.valid_range is None:
        return
    narrow = valid_range(windows, dataclasses.replace(
        options, range_margin=float(options.high_order_margin), unit_margins=None))
    models = {w: getattr(cal, w) for w in ('accel', 'gyro') if getattr(cal, w) is not None}
    high = [w for w, m in models.items() if w in which and m.temperature_degree() > 1]
    if high and len(high) == len(models):
        cal.valid_range = narrow
    else:
        cal.sensor_range = {w: narrow.copy() for w in high}
