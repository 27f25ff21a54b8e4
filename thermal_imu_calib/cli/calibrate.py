"""The options ``calibrate`` and ``fleet calibrate`` share, parsed into one CalibrateSettings.

``settings_from_args`` turns the parsed options into the ``app.calibrate.CalibrateSettings``
the use case runs with (the calibrator node builds the same from its parameters), so a
fleet calibration is the one ``calibrate`` gives on the same logs. Units: gravity m/s^2,
--max-gap and detector lengths in s, --rotation-dps in deg/s.
"""

import argparse

from ..app import calibrate as app
from ..app.calibrate import CalibrateSettings
from ..calibration import OUT_OF_RANGE_POLICIES
from .checks import UserError
from ..collection.stationary import DetectorConfig
from ..estimation.calibrate import model_choices
from ..estimation.options import HIGH_ORDER_SENSORS

#: the defaults of ``calibrate`` (the node's and the fleet's too)
DEFAULTS = CalibrateSettings()


def add_calibrate_parser(sub):
    """Add the ``calibrate`` subcommand's parser to ``sub`` and return it."""
    p = sub.add_parser('calibrate', help='estimate a thermal calibration from logs')
    p.add_argument('inputs', nargs='+', metavar='INPUT', help='rosbag2 dir, .mcap or .db3')
    _add_topics(p)
    grav = p.add_mutually_exclusive_group()
    grav.add_argument('--gravity', type=float, help='local gravity (m/s^2)')
    grav.add_argument('--latitude', type=float, help='latitude (deg) for WGS84 normal gravity')
    p.add_argument('--altitude', type=float, default=DEFAULTS.altitude,
                   help='height (m) with --latitude')
    p.add_argument('--model', default=DEFAULTS.model, choices=model_choices(),
                   help='auto: chosen from the data (see the summary); field: seed 000; '
                        'offset: single-orientation drift only; whole_unit: seed 002, gyro '
                        'scale and misalignment from the pose changes between holds')
    p.add_argument('--prior', help='lab calibration (k0, b0, S at T0) the field model refines: a '
                   'thermal_imu_calib YAML, imu_tk *_acc.calib, imucal .json, PX4 .params, '
                   'ArduPilot .parm or Kalibr imu.yaml')
    p.add_argument('--order', type=int, default=DEFAULTS.order, choices=(0, 1, 2),
                   help=f'temperature polynomial order of the field model (default '
                        f'{DEFAULTS.order})')
    p.add_argument('--no-refine', action='store_true', help='skip the joint refinement')
    p.add_argument('--out-of-range', default=DEFAULTS.out_of_range,
                   choices=OUT_OF_RANGE_POLICIES,
                   help='outside the valid temperature range: hold the edge value (clamp), '
                        'evaluate the model (extrapolate), continue it from the edge with '
                        'its slope over the last 1 degC inside, no further than the range\'s '
                        'width (linear), or that for the '
                        'gyro and clamp for the accelerometer (linear_gyro); all counted '
                        f'and flagged (default {DEFAULTS.out_of_range})')
    p.add_argument('--range-margin', type=float, default=DEFAULTS.range_margin,
                   metavar='DEGC', help='valid range = collected temperature range widened by '
                                        f'this (default {DEFAULTS.range_margin:g})')
    p.add_argument('--high-order-margin', type=margin_or_off,
                   default=DEFAULTS.high_order_margin, metavar='DEGC|off',
                   help='margin of a model above first order in temperature (quadratic, '
                        'cubic, rvm) instead of --range-margin: 0 holds it at its last hold '
                        'rather than continuing the curve; off: --range-margin for every model '
                        f'(default {_margin_text(DEFAULTS.high_order_margin)})')
    p.add_argument('--high-order-sensors', default=DEFAULTS.high_order_sensors,
                   choices=tuple(HIGH_ORDER_SENSORS),
                   help='the sensors --high-order-margin applies to (default '
                        f'{DEFAULTS.high_order_sensors})')
    p.add_argument('--input-unit', action='append', default=[], metavar='TOPIC=UNIT',
                   help='unit of a thermal input, recorded in the calibration: degC (default) '
                        'or a proxy unit such as Hz (e.g. /imu/gyro_resonance=Hz); repeat per '
                        'input. Kelvin/Fahrenheit are refused: publish degC')
    p.add_argument('--input-margin', action='append', default=[], metavar='UNIT=VALUE',
                   help='valid-range margin of the inputs in UNIT (default for a proxy: '
                        '--range-margin degC scaled by its span relative to the degC inputs)')
    p.add_argument('--accel-input', metavar='TOPIC[,TOPIC,TOPIC]',
                   help='input(s) driving the accelerometer axes (default: the degC inputs, '
                        'three per axis, else the first)')
    p.add_argument('--gyro-input', metavar='TOPIC[,TOPIC,TOPIC]',
                   help='input(s) driving the gyro axes (default: the one non-degC input, '
                        'e.g. a resonance-frequency proxy, else the first input)')
    p.add_argument('--frame-id', help='sensor frame_id to record (default: from the log)')
    p.add_argument('--save-windows', metavar='FILE',
                   help='write the window statistics (JSONL) and the pose changes between '
                        'holds (FILE.transitions.npz, gyro_fit.load_transitions)')
    p.add_argument('-o', '--output', required=True, help='calibration YAML to write')
    p.add_argument('--force', action='store_true',
                   help='overwrite an existing -o that is not a calibration file (never an '
                        'input)')
    p.add_argument('--json', action='store_true', help='print the report as JSON')
    _add_detector(p)
    return p


def calibrate_defaults():
    """Return the calibrate Namespace with every default (inputs '-', output '-')."""
    ap = argparse.ArgumentParser()
    add_calibrate_parser(ap.add_subparsers(dest='cmd'))
    return ap.parse_args(['calibrate', '-', '-o', '-'])


def _add_topics(p, imu_required=False):
    p.add_argument('--imu-topic', required=imu_required, default=None,
                   help='sensor_msgs/Imu topic (default: the only Imu topic in the log)')
    p.add_argument('--temperature-topic', action='append', default=None, metavar='TOPIC',
                   help='thermal input topic: sensor_msgs/Temperature (a temperature, or a '
                        'proxy such as a resonance frequency) or another stamped scalar '
                        '(FluidPressure, Illuminance, RelativeHumidity), or a header-less '
                        'std_msgs/Float32 or Float64 (each reading takes the stamp of the IMU '
                        'message logged before it); repeat for several inputs; \'\' for none '
                        '(default: those of the calibration, or the IMU\'s Temperature topics: '
                        'the only one, else those with the IMU\'s frame_id or namespace; with '
                        'none, a header-less temp* topic in the IMU\'s namespace)')
    p.add_argument('--max-gap', type=float, default=DEFAULTS.max_gap_s, metavar='S',
                   help='temperature samples further apart than this are a gap: the nearest '
                        f'sample is held instead of interpolating (s, default '
                        f'{DEFAULTS.max_gap_s:g})')
    p.add_argument('--chunk-size', type=int, default=20000, help=argparse.SUPPRESS)
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None,
                   help='progress bar (default: only on a terminal)')


def _add_detector(p):
    d = DEFAULTS.detector
    g = p.add_argument_group('stationary detector (default: every setting derived from the '
                             'log\'s rate, noise floor and LSB)')
    g.add_argument('--block', type=float, default=None, metavar='S',
                   help='block length of the stillness test (s; default ~0.1 s, >= 5 samples)')
    g.add_argument('--min-hold', type=float, default=None, metavar='S',
                   help='minimum stationary segment (s; default max(1 s, 8 blocks))')
    g.add_argument('--window', type=float, default=None, metavar='S',
                   help='sub-window length within a hold (s; default max(5 s, 2 blocks))')
    g.add_argument('--guard', type=float, default=None, metavar='S',
                   help='trimmed from both ends of a hold (s; default max(0.2 s, 2 blocks))')
    g.add_argument('--still-factor', type=float, default=None, metavar='X',
                   help='variance threshold as a multiple of the noise floor (default: from '
                        'the chi-square spread of a block variance)')
    g.add_argument('--rotation-dps', type=float, default=d.rotation_dps, metavar='DPS',
                   help='rotation rate still counted as held (hand tremor; deg/s, default '
                        f'{d.rotation_dps:g})')


def _detector(args):
    c = DetectorConfig(block_s=args.block, min_hold_s=args.min_hold, window_s=args.window,
                       guard_s=args.guard, accel_factor=args.still_factor,
                       gyro_factor=args.still_factor, rotation_dps=args.rotation_dps,
                       mean_sigmas=DEFAULTS.detector.mean_sigmas,
                       noise_quantile=DEFAULTS.detector.noise_quantile)
    try:
        c.validate()
    except ValueError as e:
        raise UserError(f'{e}; leave it out to derive it from the log') from None
    return c


def settings_from_args(args):
    """Return the CalibrateSettings of a ``calibrate`` (or ``fleet calibrate``) Namespace."""
    return CalibrateSettings(
        model=args.model, order=args.order, refine=not args.no_refine,
        out_of_range=args.out_of_range, range_margin=args.range_margin, max_gap_s=args.max_gap,
        high_order_margin=args.high_order_margin, high_order_sensors=args.high_order_sensors,
        gravity=args.gravity, latitude=args.latitude, altitude=args.altitude, prior=args.prior,
        frame_id=args.frame_id or '', input_units=list(args.input_unit),
        input_margins=list(args.input_margin), accel_input=args.accel_input,
        gyro_input=args.gyro_input, detector=_detector(args))


def _gravity(args):
    try:
        return app.resolve(CalibrateSettings(gravity=args.gravity, latitude=args.latitude,
                                             altitude=getattr(args, 'altitude', 0.0)))
    except app.SettingsError as e:
        raise UserError(str(e)) from None


def margin_or_off(text):
    """Parse ``--high-order-margin``: a number (degC) or ``off`` (None)."""
    if text.strip().lower() == 'off':
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is neither a number (degC) nor off') from None


def _margin_text(value):
    """Return a margin as the command line writes it (None: off)."""
    return 'off' if value is None else f'{value:g}'
