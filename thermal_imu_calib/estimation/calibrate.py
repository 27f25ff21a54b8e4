"""From stationary windows to a Calibration: model choice, observability, refusal, summary.

This is the one estimation entry point used by the CLI (offline logs) and the calibrator
node (live segment statistics).

Cohesive: the calibrate_windows entry point, its context and estimator registry, and the
offset/field estimators that define the registry.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..calibration import Calibration, TemperatureInput
from ..gravity import STANDARD_GRAVITY
from ..input_units import DEGC, is_temperature
from ..models.base import SensorModel
from ..models.field import FieldPolynomialModel
from ..thermal_input import ThermalFilter
from .field_estimator import fit_field_model, per_axis_vertical_range
from .hold_consistency import hold_consistency
from .observability import ORDER_SPAN
from .offset_fit import fit_offset_model, time_groups
from .allan import window_noise
from ..collection.segments import coverage, distinct_orientations, FACE_NAMES, Windows

#: warn when an axis was never vertical within this many degC of the collected range's ends
EXTRAPOLATION_WARN_DEGC = 2.0
#: valid-range margin of a proxy input (e.g. Hz) when no degC input is there to scale the
#: degC margin by: this fraction of the collected span on both sides (1 degC of a 17-degC
#: warm-up is 6 %)
PROXY_MARGIN_FRACTION = 0.05


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


def _margin_report(windows, options):
    units = input_units(options, windows.n_inputs)
    if all(map(is_temperature, units)) and not options.unit_margins:
        return {'value': options.range_margin, 'unit': DEGC}
    return {'value': input_margins(windows, options).tolist(), 'unit': units,
            'note': 'per input; a proxy without an explicit margin gets range_margin degC '
                    'scaled by its span relative to the degC inputs\''}


def _face_text(cov):
    parts = []
    for f in FACE_NAMES:
        n = cov['faces'][f]['holds']
        if n:
            parts.append(f'{f}({n})' if n > 1 else f)
    if cov['tilted_holds']:
        parts.append(f'{cov["tilted_holds"]} tilted')
    return ' '.join(parts) or 'none'


def _span_text(cov, units=None):
    span = cov['temperature_span']
    if not span:
        return 'no temperature'
    units = units if units and len(units) == len(span) else [DEGC] * len(span)
    return ', '.join(f'{lo:.1f}-{hi:.1f} {u}' for (lo, hi), u in zip(span, units))


#: tilted holds the whole-unit model asks for before it calls the collection complete
WHOLE_UNIT_TILTED = 3


def readiness(windows, model='auto', min_holds=1):
    """Say whether ``calibrate_windows`` would succeed now and what to hold next.

    Returns a dict: ready (bool), mode, reason, next_pose (face label or None), coverage.
    Cheap: no fitting, only the coverage rules.
    """
    cov = coverage(windows)
    if cov['holds'] < min_holds:
        return {'ready': False, 'mode': None, 'reason': 'no stationary holds yet',
                'next_pose': '+z', 'coverage': cov}
    n_orient = distinct_orientations(windows)
    missing = cov['missing']
    if model == 'offset' or (model == 'auto' and n_orient == 1):
        return {'ready': True, 'mode': 'offset', 'reason': 'single orientation: offset-only model',
                'next_pose': missing[0] if missing else None, 'coverage': cov}
    if missing:
        return {'ready': False, 'mode': 'field', 'reason': f'faces missing: {" ".join(missing)}',
                'next_pose': missing[0], 'coverage': cov}
    # all faces held: suggest the face seen at the fewest temperatures to repeat
    least = min(FACE_NAMES, key=lambda f: cov['faces'][f]['holds'])
    if model == 'whole_unit':
        tilted = cov['tilted_holds']
        if tilted < WHOLE_UNIT_TILTED:
            return {'ready': True, 'mode': 'whole_unit',
                    'reason': f'all six faces held; {tilted} of {WHOLE_UNIT_TILTED} corner-up '
                              '(tilted) holds for the misalignment (it stays at its prior '
                              'until then)', 'next_pose': 'tilted', 'coverage': cov}
        return {'ready': True, 'mode': 'whole_unit',
                'reason': f'all six faces and {tilted} tilted holds', 'next_pose': least,
                'coverage': cov}
    return {'ready': True, 'mode': 'field', 'reason': 'all six faces held',
            'next_pose': least, 'coverage': cov}


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
#: modules that register further estimators when imported (one line per model family)
ESTIMATOR_MODULES = ['thermal_imu_calib.estimation.standard_fit',
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


def _apply_hold_rule(ctx, keep):
    """Return (applied, report) for a rule leaving holds out; replaced by held-out judging."""
    return True, {}


#: ``fn(ctx, keep) -> (applied, report)``: whether a rule's leaving out ``~keep`` stands
#: (``selection/static_select.judge_rule``: held out, against the standard fit)
HOLD_RULE_JUDGE = [_apply_hold_rule]


def _no_magnitudes(ctx):
    """Return None: the pose-repeat test then uses its own rough bias and scale fit."""
    return None


#: ``fn(ctx) -> (holds,) |a| of each hold mean after a calibration of all holds, or None``
#: (installed by ``standard_fit``: the standard fit)
HOLD_MAGNITUDES = [_no_magnitudes]


def _without_flat_temperature(windows, o):
    """Return (windows, options, notes) with degC inputs that barely moved taken out.

    Several orientations: when every thermal input is a temperature (degC) spanning less
    than ``ORDER_SPAN[1]`` over the holds, no temperature term can be resolved from it, so
    the estimation is the one without the inputs (the same calibration as without the
    topic, temperature-independent) and a note says so. One orientation keeps them: its
    offset model is what ``auto`` ends at either way (``select.SINGLE_MIN_SPAN``).
    """
    k = windows.n_inputs
    if not k or distinct_orientations(windows) < 2:
        return windows, o, []
    units = input_units(o, k)
    if not all(is_temperature(u) for u in units):
        return windows, o, []
    span = float(np.max(np.ptp(windows.temp, axis=0)))
    if span >= ORDER_SPAN[1]:
        return windows, o, []
    w = dataclasses.replace(windows, temp=windows.temp[:, :0],
                            temp_rate=windows.temp_rate[:, :0])
    trs = [dataclasses.replace(t, temps=np.asarray(t.temps)[:0]) for t in o.transitions]
    o = dataclasses.replace(o, inputs=[], accel_input=None, gyro_input=None, transitions=trs)
    return w, o, [f'the temperature spanned only {span:.2f} degC over the holds (< '
                  f'{ORDER_SPAN[1]:g} degC, too little for any temperature term): treated as '
                  'no temperature input, a temperature-independent calibration (the same as '
                  'without the topic); collect across a warm-up for thermal terms']


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


def calibrate_windows(windows, options=None):
    """Estimate a Calibration from stationary windows; raise CalibrationRefused if impossible."""
    o = options or CalibrateOptions()
    choices = model_choices()
    if o.model not in choices:
        raise CalibrationRefused(f'unknown model {o.model!r}', f'use one of {choices}')
    if len(windows) == 0:
        raise CalibrationRefused(
            'no stationary segments were found',
            f'hold the IMU still for at least {o.min_hold_s:.0f} s in each pose (check the '
            'IMU topic, and that the log contains still periods)')
    if len(o.inputs) != windows.n_inputs:
        raise ValueError(f'{len(o.inputs)} temperature inputs named but windows carry '
                         f'{windows.n_inputs}')
    windows, o, flat = _without_flat_temperature(windows, o)
    ctx = make_context(windows, o)
    keep, consistency = hold_consistency(windows, o.gravity, ctx.ta if ctx.k else None,
                                         magnitudes=HOLD_MAGNITUDES[0](ctx))
    if not np.all(keep):
        applied, consistency['heldout'] = HOLD_RULE_JUDGE[0](ctx, keep)
        if applied:
            ctx.accel_rows = keep
        else:
            consistency['not_applied'] = consistency.pop('left_out')
            consistency['left_out'] = []
    accel_input, gyro_input, units = ctx.accel_input, ctx.gyro_input, input_units(o, ctx.k)
    name, why = ((o.model, 'requested') if o.model != 'auto'
                 else AUTO_POLICY[0](ctx.accel_view()))
    est = ESTIMATORS[name](ctx)
    notes = flat + _consistency_notes(consistency) + list(est.notes)
    report = {'coverage': ctx.coverage, 'distinct_orientations': ctx.n_orientations,
              'model_choice': {'model': name, 'reason': why}, **est.report}
    gyro_model = est.gyro
    if gyro_model is None:
        gyro_model, gyro_report, gyro_notes = DEFAULT_GYRO[0](ctx, est)
        report.update(gyro_report)
        notes += gyro_notes
    cov = ctx.coverage
    g = o.gravity
    cal = Calibration(
        accel=est.accel, gyro=gyro_model, inputs=list(o.inputs),
        valid_range=valid_range(windows, o),
        out_of_range=o.out_of_range, accel_input=accel_input, gyro_input=gyro_input,
        frame_id=o.frame_id, gravity=g, gravity_source=o.gravity_source,
        accel_noise_std=np.sqrt(np.median(windows.accel_var, axis=0)),
        gyro_noise_std=np.sqrt(np.median(windows.gyro_var, axis=0)), notes=notes,
        temperature_filter=est.temperature_filter, noise_model=window_noise(windows))
    before, after = gravity_residuals(ctx.accel_view().windows, cal, g)
    fit_stats = dict(est.fit)
    fit_stats.update({
        'hold_consistency': consistency,
        'model_choice': _model_choice(name, why, report),
        'holds': cov['holds'], 'windows': cov['windows'],
        'distinct_orientations': ctx.n_orientations,
        'faces': {f: cov['faces'][f]['holds'] for f in FACE_NAMES},
        'tilted_holds': cov['tilted_holds'],
        'temperature_span': cov['temperature_span'],
        'valid_range_margin': _margin_report(windows, o),
        'gravity_residual_ug': {'before_rms': _rms(before), 'after_rms': _rms(after),
                                'before_max': _amax(before), 'after_max': _amax(after),
                                'note': 'per hold, |mean f| - g in micro-g, on the fit data'},
    })
    rot = _rotation_stats(est.fit, report)
    if o.transitions or rot:
        fit_stats['pose_changes'] = report['pose_changes'] = {
            'collected': len(o.transitions), 'used': int(rot.get('rotations_used', 0))}
    if 'rotation_direction_error_deg' in rot:
        fit_stats['rotation_direction_error_deg'] = rot['rotation_direction_error_deg']
    cal.fit = fit_stats
    kind = est.accel.kind if est.accel is not None else 'gyro bias only'
    if name == 'standard':
        kind = 'standard static fit (imu_tk)'
    cal.notes = list(cal.notes) + _adequacy_notes(fit_stats, kind)
    summary = (f'{kind}: {cov["holds"]} holds ({cov["windows"]} windows), faces '
               f'{_face_text(cov)}, {_span_text(cov, units)}, gravity residual '
               f'{_amax(before):.0f} -> {_amax(after):.1f} ug max')
    if flat:
        summary += ' (the temperature input barely moved: treated as none, see notes)'
    if consistency['left_out']:
        summary += (f', {len(consistency["left_out"])} holds left out of the accelerometer '
                    'fit (pose repeats that disagree, sensor-state epochs; held-out holds '
                    'support it; see notes)')
    elif consistency.get('not_applied'):
        summary += (f', {len(consistency["not_applied"])} holds disagree with a repeat of '
                    'their pose but stay in (held-out holds do not support leaving them out)')
    if 'residual_rms' in fit_stats:
        summary += f', fit residual {fit_stats["residual_rms"]["value"] * 1e6 / g:.1f} ug RMS'
    gyro_text = report.get('gyro_choice', {}).get('text')
    summary += _pose_change_text(rot, len(o.transitions))
    summary += f'; {gyro_text}' if gyro_text else ''
    return CalibrationResult(cal, summary, report)


def _model_choice(name, why, report):
    """Return fit.model_choice: the model, why, and the gyro comparison with pose changes."""
    out = {'model': name, 'reason': why}
    if 'heldout' in report:       # every candidate's held-out figure (one orientation)
        out['heldout'] = report['heldout']
    gyro = report.get('gyro_choice', {})
    if 'text' in gyro:
        out['gyro'] = {'model': gyro['model'], 'reason': gyro['text'],
                       'heldout': gyro['candidates']}
    return out


def _consistency_notes(report):
    """Return the notes on the holds ``hold_consistency`` left out of the accel fit."""
    held = report.get('heldout', {})
    if report.get('not_applied'):
        holds = ', '.join(str(h['hold']) for h in report['not_applied'])
        return [f'pose-repeat test: holds {holds} disagree with a visit of the same pose '
                f'(fit.hold_consistency), but they are not left out: '
                f'{held.get("text", "held-out holds do not support it")}']
    out = []
    for h in report['left_out']:
        if 'epoch' in h:
            continue
        out.append(
            f'hold {h["hold"]} left out of the accelerometer fit: still, but its |a| differs '
            f'by {h["difference_ug"]:.0f} ug ({h["z"]:.1f} sigma, limit '
            f'{report["z_limit"]:.1f}) from hold {h["reference_hold"]} in the same pose, so '
            'the sensor output changed between the two (handling, a temperature step); '
            'it is still used for the gyro')
    for k, ep in enumerate(report.get('epochs', [])):
        held = [h['hold'] for h in report['left_out'] if h.get('epoch') == k]
        poses = ', '.join(f'{p["difference_ug"]:.0f} +- {p["sigma_ug"]:.0f} ug'
                          for p in ep['tail_poses'])
        tail = (f'the later repeat visits differ from the earlier holds by {poses} (chi2 '
                f'{ep["tail_chi2"]:.1f} on {ep["tail_dof"]} poses, p {ep["tail_p"]:.2g}: '
                f'the change {"lasted" if ep["lasting"] else "is not shown to last"})'
                if ep['tail_dof'] else 'no later repeat visit to test whether it lasted')
        if not held:
            out.append(f'sensor-state change at hold {ep["holds"][0]}: {tail}; only the '
                       'visits that disagree are left out')
            continue
        obs = ep['observability']
        out.append(f'sensor-state epochs: the output changed by hold {ep["holds"][0]} and '
                   f'{tail}; holds {", ".join(map(str, ep["holds"]))} are one epoch, the '
                   f'{ep["accel_uses"]} one observes more of a bias and scale per axis (rank '
                   f'{obs["earlier"][0]} earlier, {obs["changed"][0]} changed), so holds '
                   f'{", ".join(map(str, held))} are left out of the accelerometer fit; they '
                   'are still used for the gyro')
    if out and held.get('text'):
        out.append(f'pose-repeat test: the holds above are left out because {held["text"]}')
    return out


def _rotation_stats(fit, report):
    """Return the stats of the gyro fit that could use pose changes ({} if none ran).

    The estimator's own gyro (``whole_unit``) reports them in its fit, the seed 002 gyro
    chosen for an accelerometer-only estimator in ``report['gyro_whole_unit']``.
    """
    for stats in (fit, report.get('gyro_whole_unit') or {}):
        if 'rotations_used' in stats:
            return stats
    return {}


def _pose_change_text(rot, collected):
    """Return the summary's clause on the pose changes between holds."""
    if rot and not collected:
        return (', no pose changes between holds: gyro scale and misalignment stay at their '
                'prior')
    if not collected:
        return ''
    if not rot:
        return (f', {collected} pose changes collected but not used (the gyro model chosen has '
                'no scale or misalignment terms)')
    return (f', {rot["rotations_used"]} of {collected} pose changes used for gyro scale and '
            'misalignment')


def _default_gyro(ctx, est):
    """Return (bias polynomial, report, notes); replaced by ``gyro_select.default_gyro``."""
    model, rep = _gyro_bias(ctx)
    return model, {'gyro_offset': rep}, ['gyroscope: bias polynomial from stationary windows; '
                                         'earth rotation is not removed (up to 7.3e-5 rad/s)']


#: the gyro model of an Estimate without one: ``fn(ctx, estimate) -> (model, report, notes)``
DEFAULT_GYRO = [_default_gyro]


def _gyro_bias(ctx):
    """Fit the default gyro bias polynomial; groups = holds when there are enough."""
    w = ctx.windows
    groups = w.hold if len(np.unique(w.hold)) >= 3 else time_groups(w.t0)
    orders = (0, 1, 2, 3) if ctx.k else (0,)
    return fit_offset_model(w, ctx.tg, ctx.gyro_t0 if ctx.k else np.zeros(3), 'gyro', 'gyro',
                            include_constant=True, orders=orders, groups=groups)


@register_estimator('offset')
def estimate_offset(ctx):
    """Single orientation: per-axis drift relative to T0 (offset-only)."""
    if ctx.k == 0:
        return Estimate(notes=[
            'accelerometer not calibrated: a single orientation without temperature cannot '
            'separate bias or scale factor from gravity; hold the six faces (+x -x +y -y +z '
            '-z up)'])
    model, rep = fit_offset_model(ctx.windows, ctx.ta, ctx.t0, 'accel', 'accel',
                                  include_constant=False)
    return Estimate(accel=model, report={'accel_offset': rep},
                    fit={'pose': 'single orientation (offset-only)'},
                    notes=['offset-only model for a single orientation: removes the drift of '
                           'each axis relative to its output at the reference temperature T0; '
                           'bias and scale factor are not separable from gravity in one pose '
                           'and are not estimated. Valid for this mounting pose only.'])


def check_faces_up_and_down(ctx):
    """Refuse unless every axis was held pointing up and pointing down (within 45 deg).

    Seed 000 sect. 3: bias and scale of an axis separate only between its up and down
    poses; the tilt is unknown, so a horizontal axis alone does not pin its bias.
    """
    w, o, cov = ctx.windows, ctx.options, ctx.coverage
    _, means = w.hold_means()
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    c45 = np.cos(np.radians(45.0))
    weak = [a for i, a in enumerate('xyz')
            if not (np.any(u[:, i] > c45) and np.any(u[:, i] < -c45))]
    if weak:
        missing = cov['missing']
        raise CalibrationRefused(
            f'scale factor and bias of axis {",".join(weak)} are not observable: faces held '
            f'{_face_text(cov)}; missing {" ".join(missing) or "none"}',
            f'hold each missing face ({" ".join(missing)}) still for at least '
            f'{o.min_hold_s:.0f} s, ideally repeated during the warm-up so each face is '
            'seen at several temperatures')


@register_estimator('field')
def estimate_field(ctx):
    """Seed 000 field model: two-step iteration plus joint refinement."""
    ctx = ctx.accel_view()
    w, o, k, ta = ctx.windows, ctx.options, ctx.k, ctx.ta
    check_faces_up_and_down(ctx)
    notes = []
    u = input_units(o, k)[ctx.accel_input[0]] if k else DEGC   # span rules: in this unit
    order = o.order if k else 0
    span = float(np.max(np.ptp(ta, axis=0))) if k else 0.0
    while order > 0 and span < ORDER_SPAN[order]:
        notes.append(f'temperature span {span:.2f} {u} is below {ORDER_SPAN[order]} {u}: '
                     f'polynomial order reduced from {order} to {order - 1}; collect during a '
                     'warm-up for temperature coefficients')
        order -= 1
    if k == 0:
        notes.append('no temperature input: temperature-independent scale factor and bias '
                     'only (dk0, db0)')
    k0 = b0 = s = None
    pm = ctx.prior_model
    if pm is not None:
        k0 = pm.k0 + pm.thermal[:, 0]
        b0 = pm.b0 + pm.thermal[:, 3]
        s = pm.s
    else:
        notes.append('no prior calibration: k0 = 1, b0 = 0, S = identity; dk0 and db0 hold '
                     'the full scale-factor and bias errors at T0, non-orthogonality is not '
                     'estimated')
    fit = fit_field_model(w, ta, o.gravity, ctx.t0, k0, b0, s, order=order, refine=o.refine)
    vert = per_axis_vertical_range(w, ta, fit.tilts, fit.hold_ids)
    axis_span = np.nan_to_num(vert[:, 1] - vert[:, 0])
    for i, a in enumerate('xyz'):
        if order >= 1 and axis_span[i] < ORDER_SPAN[1]:
            notes.append(f'axis {a} was near vertical over only {axis_span[i]:.2f} {u}: its '
                         'scale temperature coefficients are poorly determined (see their std)')
        if k:
            lo, hi = ta[:, i].min(), ta[:, i].max()
            gap_lo, gap_hi = vert[i, 0] - lo, hi - vert[i, 1]
            if max(gap_lo, gap_hi) > EXTRAPOLATION_WARN_DEGC:
                notes.append(
                    f'axis {a} was held vertical only between {vert[i, 0]:.1f} and '
                    f'{vert[i, 1]:.1f} {u} of the {lo:.1f}-{hi:.1f} {u} collected: its '
                    'temperature terms are extrapolated outside that; next time hold every '
                    'face once early in the warm-up (a quick first pass of ~1 min per face)')
    stats = {'iterations': fit.iterations, 'converged': bool(fit.converged),
             'joint_refinement': bool(fit.refined), 'order': order,
             'residual_rms': {'value': fit.residual_rms, 'unit': 'm/s^2'},
             'chi2_per_dof': fit.chi2_dof,
             'axis_vertical_temperature_range': {'value': vert.tolist(), 'unit': u}}
    return Estimate(accel=fit.model, notes=notes, fit=stats)


#: chi2/dof of the accelerometer fit above which the notes say the model is inadequate
#: (a device the model describes gives ~1-1.3; errors outside it, 3 and more)
ADEQUACY_CHI2 = 2.5


def _adequacy_notes(fit_stats, kind):
    """Return a note when the fit residuals are well above what the sensor noise explains."""
    chi2 = fit_stats.get('chi2_per_dof')
    if chi2 is None or not np.isfinite(chi2) or chi2 <= ADEQUACY_CHI2:
        return []
    return [f'fit inadequate: the residuals are {np.sqrt(chi2):.1f}x what the sensor noise '
            f'explains (chi2/dof {chi2:.1f} > {ADEQUACY_CHI2:g}); the device has errors the '
            f'{kind} model does not describe (higher-order or lagged thermal response, '
            'hysteresis, bias wander), so the error left after compensation can exceed the '
            'reported std. Check it on an independent recording (thermal-imu-calib '
            'evaluate), or record longer holds over a slower warm-up']


def gravity_residuals(windows, cal, g):
    """Return per-hold |mean f| - g in micro-g, before and after ``cal`` (fit data)."""
    ids = windows.hold_ids
    before = np.zeros(len(ids))
    after = np.zeros(len(ids))
    temps = windows.temp if windows.n_inputs else None
    if temps is not None and cal.temperature_filter is not None:
        temps = cal.temperature_filter.window_temperatures(windows)
    res = cal.apply(windows.accel, windows.gyro, temps)
    for j, h in enumerate(ids):
        m = windows.hold == h
        wts = windows.n[m]
        before[j] = np.linalg.norm(np.average(windows.accel[m], 0, wts)) - g
        after[j] = np.linalg.norm(np.average(res.accel[m], 0, wts)) - g
    return before / g * 1e6, after / g * 1e6


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def _amax(x):
    return float(np.max(np.abs(x))) if len(x) else 0.0
