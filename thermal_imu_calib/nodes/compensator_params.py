"""The compensator node's parameters: declared on the node, changed at run time.

``declare`` declares every parameter of ``nodes/compensator.py`` (descriptions, ranges,
read-only ones) and sets the node's attributes the compensation reads (``temperature_topics``,
``temperature_units``, ``temperature_timeout``, ``on_missing``, ...); the read-only ones the
node only needs while it starts (QoS, diagnostics period, ``state_file``) come back as a
``StartSettings``. ``on_change`` applies a successful runtime change of the tunable ones
(``common.Parameters``). ``test/test_defaults.py`` checks the defaults against
``config/compensator.yaml``. Units: seconds (header stamps unless said otherwise).
"""

from dataclasses import dataclass
import functools

from . import common
from ..app.compensate import MISSING_POLICIES
from ..collection.feed import DEFAULT_MAX_GAP_S


@dataclass(frozen=True)
class StartSettings:
    """The read-only parameters the node uses while it starts (see ``declare``)."""

    output_reliability: str
    output_depth: int
    input_depth: int
    diagnostics_period: float
    state_file: str
    state_save_period: float
    state_max_gap: float
    #: per thermal input: (message class, value field), ``common.declare_thermal_inputs``
    scalar_types: list


def declare(node):
    """Declare the parameters on ``node`` and set its attributes from them.

    Returns the ``StartSettings``.
    """
    p = common.Parameters(node, apply=functools.partial(on_change, node))
    node.calibration_file = p.declare(
        'calibration_file', '~/.ros/thermal_imu_calib/calibration.yaml',
        'Calibration YAML loaded at start and on ~/reload (~ is expanded; empty: none).')
    node.registry_dir = p.declare(
        'registry_dir', '',
        'Fleet registry (thermal-imu-calib fleet calibrate -o DIR); when set, '
        'calibration_file is ignored: the latest calibration of the IMU header frame_id '
        'is loaded at the first message of each frame_id and on ~/reload.', read_only=True)
    node.temperature_topics = common.topic_list(p.declare(
        'temperature_topics', ['imu/temperature'],
        'Thermal input topics to subscribe (sensor_msgs/Temperature unless '
        'temperature_types says otherwise); the calibration file maps its inputs to them '
        'by name (relative names follow namespaces and remaps); empty ([] or [\'\']): '
        'no thermal input.', read_only=True))
    node.temperature_timeout = p.declare(
        'temperature_timeout', DEFAULT_MAX_GAP_S,
        'Seconds (by header stamp) after which a temperature reading is stale; readings '
        'closer than this are interpolated (compensate\'s --temperature-timeout and '
        'the calibrator\'s temperature_timeout, the same default).', lo=0.001, hi=3600.0)
    node.on_missing = p.declare(
        'on_missing_temperature', 'hold_last',
        'What to do when a temperature is stale or absent: hold_last compensates with the '
        'nearest reading (passthrough if none was ever received), passthrough publishes '
        'the raw sample, drop publishes nothing.', choices=MISSING_POLICIES)
    node.passthrough_uncalibrated = p.declare(
        'passthrough_without_calibration', True,
        'With no calibration loaded: true publishes raw samples, false publishes nothing.')
    out_rel = p.declare('output_reliability', 'reliable',
                        'QoS reliability of imu/data_compensated.',
                        choices=('reliable', 'best_effort'), read_only=True)
    out_depth = p.declare('output_depth', 1000, 'QoS history depth of imu/data_compensated.',
                          lo=1, hi=100000, read_only=True)
    in_depth = p.declare('input_depth', 1000,
                         'QoS history depth (best effort) of the IMU and temperature '
                         'subscriptions; 1000 holds one second of a 1 kHz stream.',
                         lo=1, hi=100000, read_only=True)
    node.batch_limit = p.declare('max_batch', 200,
                                 'Most queued IMU messages compensated together in one '
                                 'callback under load.', lo=1, hi=10000)
    node.fill_covariance = p.declare(
        'fill_covariance', True,
        'Write the calibration\'s 1-sigma (white noise + model predictive std, squared) '
        'into the linear_acceleration/angular_velocity covariance diagonals; false keeps '
        'the covariances as received.')
    node.despike = p.declare(
        'despike', False,
        'Replace isolated spikes by the local median before compensation (median/MAD '
        'gate, seed 002 sect. 3.2); delays the output by 3 samples.')
    period = p.declare('diagnostics_period', 1.0, 'Seconds between /diagnostics messages.',
                       lo=0.05, hi=60.0, read_only=True)
    state_file = p.declare(
        'state_file', '',
        'JSON file the thermal-history state (lag filters, hysteresis terms) is saved to '
        'and resumed from after a restart of this node (~ is expanded, {node} is the node '
        'name, e.g. imu_left.thermal_imu_compensator; empty: none, a restart starts the '
        'history in equilibrium with a widened 1-sigma). Not used with registry_dir.',
        read_only=True)
    state_period = p.declare('state_save_period', 5.0,
                             'Seconds (wall time) between writes of state_file.',
                             lo=0.1, hi=3600.0, read_only=True)
    state_gap = p.declare(
        'state_max_gap', 600.0,
        'Most seconds (header stamps) between the saved state and the first sample after '
        'a restart for the state to be resumed; the gap is run through with the reading '
        'interpolated.', lo=0.0, hi=86400.0, read_only=True)
    if len(set(node.temperature_topics)) != len(node.temperature_topics):
        raise ValueError(f'temperature_topics has duplicates: {node.temperature_topics}')
    node.temperature_units, scalar_types = common.declare_thermal_inputs(
        p, node.temperature_topics, ' A calibration whose inputs are in other units is '
        'refused.')
    return StartSettings(out_rel, out_depth, in_depth, period, state_file, state_period,
                         state_gap, scalar_types)


def on_change(node, changed):
    """Set ``node``'s attributes of the tunable parameters in ``changed`` ({name: value})."""
    for name, value in changed.items():
        if name == 'temperature_timeout':
            node.temperature_timeout = value
        elif name == 'on_missing_temperature':
            node.on_missing = value
        elif name == 'passthrough_without_calibration':
            node.passthrough_uncalibrated = value
        elif name == 'max_batch':
            node.batch_limit = value
        elif name == 'fill_covariance':
            node.fill_covariance = value
