"""The calibrator node's parameters: declared from the shared CalibrateSettings, read back.

``declare`` declares every parameter of ``nodes/calibrator.py`` (descriptions, ranges,
read-only ones) with the defaults of ``app.calibrate.CalibrateSettings``, the command
line's too; ``settings`` turns their current values into the CalibrateSettings the
calibrate use case runs with (``test/test_defaults.py`` checks both against
``config/calibrator.yaml`` and the command line). Units as CalibrateSettings: gravity
m/s^2, latitude deg, altitude m, margins degC, detector lengths s.
"""

from . import common, lifelong as lifelong_mode
from ..app import calibrate as app
from ..app.calibrate import CalibrateSettings
from ..calibration import OUT_OF_RANGE_POLICIES, TemperatureInput
from ..collection.stationary import DetectorConfig
from ..estimation import calibrate as estimation
from ..estimation.options import HIGH_ORDER_SENSORS
from ..gravity import resolve_gravity

#: the defaults every calibrate path shares (app.calibrate.CalibrateSettings)
DEFAULTS = CalibrateSettings()
_DET = DEFAULTS.detector


def _param_default(value, derived=0.0):
    """Return a detector default as a parameter value: None (derived) becomes ``derived``."""
    return derived if value is None else float(value)


#: DetectorConfig fields exposed as parameters: (default, lo, hi, description); 0 (the guard:
#: -1) means derived from the first samples, as the command line's options left out
DETECTOR_PARAMS = {
    'block_s': (_param_default(_DET.block_s), 0.0, 60.0,
                'Block length (s) of the stillness test; 0: derived from the rate (~0.1 s, '
                '>= 5 samples).'),
    'window_s': (_param_default(_DET.window_s), 0.0, 3600.0,
                 'Length (s) of the windows a hold is cut into; 0: derived.'),
    'min_hold_s': (_param_default(_DET.min_hold_s), 0.0, 36000.0,
                   'Minimum segment length (s): shorter holds (after the guards) are '
                   'discarded; 0: derived.'),
    'guard_s': (_param_default(_DET.guard_s, -1.0), -1.0, 600.0,
                'Seconds trimmed from both ends of each hold; -1: derived.'),
    'accel_factor': (_param_default(_DET.accel_factor), 0.0, 1e4,
                     'A block is still when its accel variance is below this factor times '
                     'the noise floor; 0: derived (chi-square).'),
    'gyro_factor': (_param_default(_DET.gyro_factor), 0.0, 1e4,
                    'Same for the gyro variance; 0: derived.'),
    'mean_sigmas': (_DET.mean_sigmas, 1.0, 1000.0, 'Neighbouring block means may differ by '
                                                   'this many standard errors in a hold.'),
    'noise_quantile': (_DET.noise_quantile, 0.001, 0.9,
                       'Quantile of block variances taken as noise floor.'),
    'rotation_dps': (_DET.rotation_dps, 0.001, 100.0,
                     'Rotation rate (deg/s) still counted as held (tremor).'),
}


def declare(node):
    """Declare the parameters on ``node`` and set its attributes from them.

    Returns (input QoS depth, progress period s, the thermal inputs' message types).
    """
    p = common.Parameters(node)
    ro = {'read_only': True}
    node.calibration_file = p.declare(
        'calibration_file', '~/.ros/thermal_imu_calib/calibration.yaml',
        'Where ~/calibrate and ~/save write the calibration (atomically; the previous '
        'file is kept as <file>.bak).')
    node.resume_max_gap = p.declare(
        'resume_max_gap', 3600.0, 'Seconds (header stamps) after the newest resumed hold '
        'within which the first data after a restart continue the collection; data stamped '
        'earlier (a replayed or another recording) or later start a new one, and the '
        'resumed collection is moved aside (<collection_file>.previous-<time>).',
        lo=1.0, hi=1e9, **ro)
    node.collection_file = p.declare(
        'collection_file', '~/.ros/thermal_imu_calib/collection.jsonl',
        'JSON-lines file the collected windows are appended to and resumed from at start '
        '(empty: keep them in memory only).', **ro)
    node.temperature_topics = common.topic_list(p.declare(
        'temperature_topics', ['imu/temperature'],
        'Thermal input topics (sensor_msgs/Temperature unless temperature_types says '
        'otherwise), one model input each, in this order; they are written into the '
        'calibration as the inputs\' topics; empty ([] or [\'\']): no thermal input (a '
        'temperature-independent calibration).', **ro))
    node.temperature_units, scalar_types = common.declare_thermal_inputs(
        p, node.temperature_topics, ' Written into the calibration; by default the gyro '
        'follows the one non-degC input and the accelerometer the degC ones.')
    node.temperature_timeout = p.declare(
        'temperature_timeout', DEFAULTS.max_gap_s,
        'Seconds (header stamps) a reading may be interpolated over or held; IMU samples '
        'without a temperature that fresh are not collected (calibrate\'s --max-gap, the '
        'same default).', lo=0.001, hi=3600.0, **ro)
    node.model = p.declare('model', DEFAULTS.model,
                           'Model to estimate: auto chooses held out, as the command line '
                           'does (the standard static fit unless a richer model predicts '
                           'held-out holds better); whole_unit (seed 002) also fits gyro '
                           'scale and misalignment from the pose changes between holds.',
                           choices=model_choices())
    node.order = p.declare('order', DEFAULTS.order, 'Highest polynomial order in '
                           'temperature (reduced automatically when the span is small).',
                           lo=0, hi=2)
    node.out_of_range = p.declare('out_of_range', DEFAULTS.out_of_range,
                                  'Written into the calibration: what the compensator does '
                                  'outside the collected temperature range.',
                                  choices=OUT_OF_RANGE_POLICIES)
    node.gravity = p.declare('gravity', 0.0, 'Local gravity in m/s^2 (9.7..9.9); 0 derives '
                             'it from latitude/altitude (use_latitude) or uses standard '
                             'gravity.', lo=0.0, hi=9.9, validator=check_gravity)
    node.use_latitude = p.declare('use_latitude', False,
                                  'Derive gravity from latitude and altitude (WGS84 normal '
                                  'gravity) when gravity is 0.')
    node.latitude = p.declare('latitude', 45.0, 'Geodetic latitude, degrees.',
                              lo=-90.0, hi=90.0)
    node.altitude = p.declare('altitude', DEFAULTS.altitude, 'Ellipsoidal height, metres.',
                              lo=-1000.0, hi=10000.0)
    p.declare('range_margin', DEFAULTS.range_margin, 'Valid range = collected '
              'temperature range widened by this (degC).', lo=0.0, hi=50.0)
    p.declare('high_order_margin', _margin_param(DEFAULTS.high_order_margin),
              'Margin (degC) of a model above first order in temperature (quadratic, cubic, '
              'rvm) instead of range_margin: 0 holds it at its last hold rather than '
              'continuing the curve; -1: off (range_margin for every model).',
              lo=-1.0, hi=50.0, validator=_check_margin)
    p.declare('high_order_sensors', DEFAULTS.high_order_sensors,
              'The sensors high_order_margin applies to.', choices=tuple(HIGH_ORDER_SENSORS))
    node.frame_id = p.declare('frame_id', '', 'IMU frame written into the calibration; '
                              'empty: the header frame_id of the first IMU message.')
    node.prior_file = p.declare('prior_file', '', 'Optional lab calibration (k0, b0, S at '
                                'T0) the field estimate refines; empty: none.')
    det = {name: p.declare(name, d, desc, lo=lo, hi=hi, **ro)
           for name, (d, lo, hi, desc) in DETECTOR_PARAMS.items()}
    # 0 (-1 for the guard) means: derived by the detector from the first samples
    det = {k: (None if v == (-1.0 if k == 'guard_s' else 0.0) else v)
           for k, v in det.items()}
    node.detector_config = DetectorConfig(**det)
    node.detector_config.validate()
    node.max_transitions = p.declare(
        'max_transitions', DEFAULTS.max_transitions, 'Most pose changes between holds '
        'kept (raw samples, ~70 kB each at 200 Hz) for the gyro scale/misalignment fit; '
        'further ones are counted as dropped; 0: keep none.', lo=0, hi=10000, **ro)
    node.max_transition_s = p.declare(
        'max_transition_s', DEFAULTS.max_transition_s, 'Longest pose change kept (s, end '
        'of one hold to the start of the next); longer ones are dropped and counted.',
        lo=1.0, hi=600.0, **ro)
    p.declare(
        'report', True, 'After each successful ~/calibrate also write an HTML report '
        '(<calibration_file>.report.html, figures embedded) next to the calibration file, '
        'on a background thread.')
    in_depth = p.declare('input_depth', 1000, 'QoS history depth (best effort) of the '
                         'input subscriptions.', lo=1, hi=100000, **ro)
    period = p.declare('progress_period', 1.0, 'Seconds between ~/progress and '
                       '/diagnostics messages.', lo=0.05, hi=60.0, **ro)
    node.lifelong = lifelong_mode.declare(node, p)   # None unless lifelong: true
    node.k = len(node.temperature_topics)
    node.inputs = [TemperatureInput(app.input_name(t, i), t, u) for i, (t, u) in
                   enumerate(zip(node.temperature_topics, node.temperature_units))]
    return in_depth, period, scalar_types


def settings(node):
    """Return the CalibrateSettings of the parameters (the CLI's defaults where unset)."""
    def value(name):
        return node.get_parameter(name).value
    g = value('gravity')
    use_latitude = value('use_latitude')
    return CalibrateSettings(
        model=value('model'), order=value('order'), out_of_range=value('out_of_range'),
        range_margin=value('range_margin'), gravity=g if g > 0 else None,
        high_order_margin=None if value('high_order_margin') < 0 else value('high_order_margin'),
        high_order_sensors=value('high_order_sensors'),
        latitude=value('latitude') if use_latitude else None,
        altitude=value('altitude') if use_latitude else DEFAULTS.altitude,
        prior=value('prior_file') or None, frame_id=value('frame_id'),
        input_units=[f'{t}={u}' for t, u in
                     zip(node.temperature_topics, node.temperature_units)],
        detector=DetectorConfig(**vars(node.detector_config)),
        max_transitions=node.max_transitions, max_transition_s=node.max_transition_s,
        max_gap_s=node.temperature_timeout)


def model_choices():
    """Return the estimator names the core accepts (older cores: a constant tuple)."""
    if hasattr(estimation, 'model_choices'):
        return tuple(estimation.model_choices())
    return tuple(getattr(estimation, 'MODEL_CHOICES', ('auto', 'field', 'offset')))


def check_gravity(value):
    """Return why a gravity parameter value is refused (None: accepted; 0: derived)."""
    if value == 0.0:
        return None
    try:
        resolve_gravity(value)
    except ValueError as e:
        return str(e)
    return None


def _margin_param(value):
    """Return a high-order margin as a parameter value (None, off, becomes -1)."""
    return -1.0 if value is None else float(value)


def _check_margin(value):
    """Return why a high_order_margin value is refused (None: accepted; -1: off)."""
    if value == -1.0 or 0.0 <= value <= 50.0:
        return None
    return f'{value:g} degC is neither -1 (off) nor in [0, 50]'
