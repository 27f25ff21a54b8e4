"""Calibrate: the use case every adapter shares, from logs or a live collection to a file.

``CalibrateSettings`` holds every option of an estimation with its default, in SI units
(gravity m/s^2, latitude deg, altitude m, margins degC unless a unit is named, gaps and
detector lengths s). The command line builds its options from it
(``cli.calibrate.add_calibrate_parser``), the calibrator node declares its parameters from
it (``nodes/calibrator_params.py``) and the shipped ``config/calibrator.yaml`` repeats its
values (``test/test_defaults.py`` fails when they differ).

``calibrate_logs`` is ``thermal-imu-calib calibrate``: it reads each log (``read_log``: the
windows, pose changes and input-gate warnings, as ``fleet calibrate``'s map step reads
them), estimates (``calibrate_collected``) and writes the file (``write_calibration``).
``calibrate_collected`` turns the holds collected from logs or live (the node's
``~/calibrate``) into a validated calibration with its random walk
(``app.noise.add_random_walk``): the same holds give the same calibration whichever path
collected them.
"""

from dataclasses import dataclass, field, replace
import os
import shutil
from typing import List, Optional

from ..calibration import Calibration, CalibrationError, TemperatureInput
from ..collection.collected import Collected, merge_transitions, merge_windows
from ..collection.motion import save_transitions
from ..collection.stationary import DetectorConfig
from ..estimation.calibrate import CalibrateOptions, calibrate_windows, readiness as _readiness
from ..formats import load_prior
from ..gravity import resolve_gravity
from ..input_units import parse_unit_map
from ..io.gate import check_report
from ..io.output import CALIBRATION, Outputs, write_atomic
from .collect import collect_windows
from .noise import add_random_walk

#: terrestrial gravity accepted (m/s^2): anything else is a typo or wrong units
GRAVITY_RANGE = (9.7, 9.9)


class SettingsError(ValueError):
    """A setting no estimation can use; the message says which and what to give instead."""


@dataclass
class CalibrateSettings:
    """Every option of one calibration with its default (the node's, the CLI's, the fleet's)."""

    #: model family (``estimation.calibrate.model_choices``); auto: chosen held out
    model: str = 'auto'
    #: highest temperature polynomial order of the field model (0..2)
    order: int = 2
    #: joint refinement of the field model after the two-step estimate
    refine: bool = True
    #: outside the valid range: 'clamp' (hold the edge value), 'extrapolate', 'linear' or
    #: 'linear_gyro' (``calibration.OUT_OF_RANGE_POLICIES``)
    out_of_range: str = 'clamp'
    #: valid range = collected range widened by this (degC)
    range_margin: float = 1.0
    #: None: ``range_margin`` for every model; a number (degC): the margin of a model above
    #: first order in temperature (``CalibrateOptions.high_order_margin``; judged, off)
    high_order_margin: Optional[float] = None
    #: the sensors it applies to: 'both', 'accel' or 'gyro'
    high_order_sensors: str = 'accel'
    #: holds are separate placements (``CalibrateOptions.placement_folds``; lifelong)
    placement_folds: bool = False
    #: per sensor, no worse than its raw output on held-out placements
    #: (``CalibrateOptions.placement_floor``; lifelong)
    placement_floor: bool = False
    #: a random level per placement in the thermal-history fits
    #: (``CalibrateOptions.placement_levels``; lifelong)
    placement_levels: bool = False
    #: the sensors it applies to: 'both', 'accel' or 'gyro'
    placement_levels_sensors: str = 'both'
    #: temperature samples further apart than this (s) are a gap: the nearest is held
    max_gap_s: float = 5.0
    #: local gravity (m/s^2); None: from ``latitude``/``altitude``, else standard gravity
    gravity: Optional[float] = None
    #: geodetic latitude (deg) for WGS84 normal gravity and the earth rate; None: unknown
    latitude: Optional[float] = None
    #: ellipsoidal height (m), with ``latitude``
    altitude: float = 0.0
    #: lab calibration file the field model refines (any ``formats.load_prior`` format)
    prior: Optional[str] = None
    #: frame_id recorded in the calibration ('': the first IMU message's)
    frame_id: str = ''
    #: ``TOPIC=UNIT`` items: unit of each thermal input (unnamed: degC)
    input_units: List[str] = field(default_factory=list)
    #: ``UNIT=VALUE`` items: valid-range margin per unit
    input_margins: List[str] = field(default_factory=list)
    #: ``TOPIC[,TOPIC,TOPIC]``: the input(s) driving the accelerometer / gyro axes
    accel_input: Optional[str] = None
    gyro_input: Optional[str] = None
    #: stationary detector; every None is derived from the log (rate, noise floor, LSB)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    #: most pose changes between holds kept for the gyro's scale and misalignment
    max_transitions: int = 500
    #: longest pose change kept (s, end of one hold to the start of the next)
    max_transition_s: float = 30.0


def resolve(settings):
    """Return (gravity m/s^2, its source text); SettingsError when it is not terrestrial."""
    try:
        g, src = resolve_gravity(settings.gravity, settings.latitude, settings.altitude)
    except ValueError as e:
        raise SettingsError(str(e)) from None
    lo, hi = GRAVITY_RANGE
    if not lo <= g <= hi:
        raise SettingsError(f'gravity {g:.6g} m/s^2 is not a terrestrial value ({lo}..{hi}); '
                            'give it in m/s^2, or check the altitude (metres)')
    return g, src


def input_name(topic, index):
    """Return the name a thermal input gets in the calibration (from its topic)."""
    return topic.strip('/').replace('/', '_') or f't{index}'


def thermal_inputs(settings, topics):
    """Return the TemperatureInputs (with units) and the axis-mapping options of ``topics``."""
    try:
        units = parse_unit_map(settings.input_units, topics)
    except ValueError as e:
        raise SettingsError(str(e)) from None
    inputs = [TemperatureInput(input_name(t, i), t, u)
              for i, (t, u) in enumerate(zip(topics, units))]
    margins = {}
    for item in settings.input_margins:
        unit, sep, value = item.partition('=')
        try:
            margins[unit] = float(value)
        except ValueError:
            sep = ''
        if not sep or margins[unit] < 0:
            raise SettingsError(f'input margin {item!r} is not UNIT=VALUE with VALUE >= 0 '
                                '(e.g. Hz=1.5)')
    mapping = {'unit_margins': margins or None}
    bare = [t.lstrip('/') for t in topics]
    for sensor in ('accel', 'gyro'):
        spec = getattr(settings, f'{sensor}_input')
        if not spec:
            continue
        names = [n.strip().lstrip('/') for n in spec.split(',')]
        if len(names) not in (1, 3) or any(n not in bare for n in names):
            raise SettingsError(f'{sensor} input {spec!r} must name one or three of the '
                                f'thermal inputs ({", ".join(topics) or "none"}), '
                                'comma-separated')
        mapping[f'{sensor}_input'] = [bare.index(n) for n in names] * (3 // len(names))
    return inputs, mapping


def options(settings, collected, transitions=(), incumbent_specs=None):
    """Return the CalibrateOptions of ``settings`` for holds collected as ``collected``.

    ``incumbent_specs``: ``CalibrateOptions.incumbent_specs`` (the lifelong loop's).
    """
    g, g_src = resolve(settings)
    prior = load_prior(os.path.expanduser(settings.prior)) if settings.prior else None
    inputs, mapping = thermal_inputs(settings, collected[0].temperature_topics)
    det = collected[0].detector or {}
    return CalibrateOptions(
        model=settings.model, gravity=g, gravity_source=g_src, prior=prior, inputs=inputs,
        frame_id=settings.frame_id or collected[0].frame_id,
        out_of_range=settings.out_of_range, order=settings.order, refine=settings.refine,
        min_hold_s=settings.detector.min_hold_s or det.get('min_hold_s') or 1.0,
        range_margin=settings.range_margin, high_order_margin=settings.high_order_margin,
        high_order_sensors=settings.high_order_sensors,
        placement_folds=settings.placement_folds,
        placement_floor=settings.placement_floor,
        placement_levels=settings.placement_levels,
        placement_levels_sensors=settings.placement_levels_sensors,
        latitude=settings.latitude, incumbent_specs=incumbent_specs,
        transitions=list(transitions), **mapping)


#: the pose changes ``save_collection`` writes go to ``<windows file><this>``
TRANSITIONS_SUFFIX = '.transitions.npz'


@dataclass
class LogRead:
    """What reading one log gave: its collection and the input gate's warnings (for people)."""

    path: str
    collected: Collected
    warnings: List[str] = field(default_factory=list)


@dataclass
class CalibrateRun:
    """What ``calibrate_logs`` did: the estimate (``CalibrationResult``) and what it read."""

    result: object
    logs: List[LogRead]
    #: (windows, pose changes) written by ``save_windows``; None when not asked
    saved: Optional[tuple] = None


def check(settings):
    """Refuse settings no estimation can use before any log is read (SettingsError)."""
    resolve(settings)
    if settings.prior:
        load_prior(os.path.expanduser(settings.prior))


def collect(settings, path, imu_topic=None, temperature_topics=None, chunk_size=20000,
            progress=None):
    """Collect one log's holds and pose changes as ``calibrate`` does; a Collected.

    The detector, the gap and the input units are the settings'; the input gate drops what
    no sensor gives and counts it (``Collected.gate``).
    """
    return collect_windows(path, imu_topic, temperature_topics, replace(settings.detector),
                           chunk_size, settings.max_gap_s, progress, motion=True,
                           input_units=list(settings.input_units))


def read_log(settings, path, imu_topic=None, temperature_topics=None, chunk_size=20000,
             progress=None):
    """Collect one log (``collect``) and gate it; returns a LogRead.

    A log no calibration can come from is refused (``io.gate.check_report``: LogError);
    what the gate dropped and counted is in ``LogRead.warnings``.
    """
    c = collect(settings, path, imu_topic, temperature_topics, chunk_size, progress)
    return LogRead(path, c, check_report(path, c.gate, settings.max_gap_s))


def save_collection(path, collected):
    """Write the merged windows (JSON lines) and pose changes (``.transitions.npz``).

    Returns (windows, pose changes) written.
    """
    windows, transitions = merge_windows(collected), merge_transitions(collected)
    write_atomic(path, windows.to_jsonl())
    write_atomic(path + TRANSITIONS_SUFFIX, lambda f: save_transitions(f, transitions))
    return len(windows), len(transitions)


def calibrate_logs(settings, paths, output=None, imu_topic=None, temperature_topics=None,
                   chunk_size=20000, progress=None, save_windows=None, on_log=None):
    """Calibrate from logs: read each, estimate from all, write ``output``; a CalibrateRun.

    ``on_log(LogRead)`` is called as each log has been read (what the adapter reports while
    the next one is read). With ``save_windows`` the merged windows and pose changes are
    written before the estimate (``save_collection``). The pose changes between holds are
    always collected: the gyro fits its scale and misalignment from them when the model
    chosen has those terms (~0.09 s CPU per 375k messages). Refusals: SettingsError,
    LogError, CalibrationRefused; nothing is written then.
    """
    check(settings)
    logs = []
    for path in paths:
        read = read_log(settings, path, imu_topic, temperature_topics, chunk_size, progress)
        if on_log is not None:
            on_log(read)
        logs.append(read)
    collected = [r.collected for r in logs]
    saved = save_collection(save_windows, collected) if save_windows else None
    result = calibrate_collected(settings, collected, paths, imu_topic)
    if output:
        write_calibration(result.calibration, output)
    return CalibrateRun(result, logs, saved)


def write_calibration(cal, path, inputs=(), keep_backup=False):
    """Write ``cal`` to ``path`` (atomically, ``Calibration.save``).

    With ``keep_backup`` (the node's calibration_file) ``path`` is checked first
    (``io.output.Outputs``: not a directory, a special file or one of ``inputs``) and the
    previous file, whatever it holds, is kept as ``<path>.bak``. OSError/ValueError when it
    cannot be written.
    """
    if keep_backup:
        Outputs(list(inputs), force=True).file(
            path, 'calibration_file', 'calibration file', CALIBRATION)
        if os.path.exists(path):
            with open(path, 'rb') as f:
                write_atomic(path + '.bak', lambda out: shutil.copyfileobj(f, out))
    cal.save(path)


def calibrate_collected(settings, collected, paths=(), imu_topic=None, incumbent_specs=None):
    """Estimate one calibration from the holds of one or more collections.

    ``collected``: the ``collection.collected.Collected`` of each log (or of the live
    collection), all with the same thermal inputs. ``paths``: the logs, if any (their names
    go to ``fit.inputs`` and long holds are re-read for the random walk,
    ``app.noise.add_random_walk``). Returns the
    CalibrationResult, checked by the loader the compensator uses (SettingsError when it
    would be refused: nothing usable can be written). ``incumbent_specs``: the specs of the
    calibration in use (``CalibrateOptions.incumbent_specs``; the lifelong loop's).
    """
    topics = collected[0].temperature_topics
    for c in collected[1:]:
        if c.temperature_topics != topics:
            raise SettingsError(f'inputs have different temperature topics ({topics} vs '
                                f'{c.temperature_topics}); name the topics to use')
    windows = merge_windows(collected)
    transitions = merge_transitions(collected)
    result = calibrate_windows(windows, options(settings, collected, transitions,
                                                incumbent_specs))
    cal = result.calibration
    if paths:
        cal.fit['inputs'] = [os.path.basename(os.path.normpath(p)) for p in paths]
    cal.fit['detector'] = (collected[0].detector if len(collected) == 1
                           else [c.detector for c in collected])
    if paths:
        note = add_random_walk(cal, paths, windows, imu_topic)
        cal.notes += [note] if note else []
    for c in collected:     # an input put on the IMU's clock, a type followed: in the file
        cal.notes += [f'input: {n}' for n in c.input_notes if f'input: {n}' not in cal.notes]
    try:
        Calibration.from_yaml(cal.to_yaml(), 'the new calibration')
    except CalibrationError as e:
        raise SettingsError(f'{e}: the data cannot support a usable calibration (see the '
                            'notes), so nothing was written') from None
    limits = limitations(cal)
    if limits:
        result.summary = f'{limits}; {result.summary}'
    return result


def readiness(settings, windows):
    """Say whether ``calibrate_collected`` would succeed on ``windows`` now, and what to hold.

    The calibrator node's ``~/progress``: the coverage rules of the estimator the settings'
    model would run, no fitting (``estimation.calibrate.readiness``). Returns its dict:
    ready, mode, reason, next_pose, coverage.
    """
    return _readiness(windows, model=settings.model)


def limitations(cal):
    """Return what the calibration could not include, for the first words of an answer.

    '' when the holds covered several orientations. With one orientation the accelerometer
    gets at most an offset drift model for that mounting pose (nothing without a
    temperature input) and the gyro a bias only; the faces to add are named.
    """
    fit = cal.fit or {}
    if fit.get('distinct_orientations', 2) > 1 and cal.accel is not None:
        return ''
    faces = fit.get('faces', {})
    held = [f for f, n in faces.items() if n] or ['one pose']
    missing = [f for f, n in faces.items() if not n]
    add = (f'hold the faces {" ".join(missing)} up (each still for a few seconds) and call '
           'calibrate again') if missing else 'hold more orientations'
    if cal.accel is None:
        acc = ('accelerometer NOT calibrated: one orientation ({}) without a temperature '
               'input cannot separate bias or scale from gravity').format(' '.join(held))
    else:
        acc = ('accelerometer: one orientation only ({}): an offset drift model for this '
               'mounting pose, no bias or scale factor').format(' '.join(held))
    return f'{acc}; gyro: bias only; to calibrate both {add}'
