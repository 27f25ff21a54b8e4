"""``thermal-imu-calib``: the library on recorded logs.

Subcommands: calibrate, compensate, evaluate, simulate, info, report, noise, export. Bad
input gets one line on stderr saying what was wrong and what to do, and exit status 2;
``--debug`` shows the traceback instead.
"""

import argparse
import json
import os
import sys

import numpy as np

from . import __version__, cli_checks, cli_export
from .calibration import Calibration, CalibrationError, TemperatureInput
from .cli_checks import UserError
from .estimation.calibrate import (CalibrateOptions, calibrate_windows, CalibrationRefused,
                                   model_choices)
from .estimation.stationary import DetectorConfig, format_holds, format_settings
from .formats import load_prior
from .gravity import resolve_gravity
from .input_units import parse_unit_map
from .io.bag import LogError
from .report import cli as report_cli

EXIT_USAGE = 2


def _add_topics(p, imu_required=False):
    p.add_argument('--imu-topic', required=imu_required, default=None,
                   help='sensor_msgs/Imu topic (default: the only Imu topic in the log)')
    p.add_argument('--temperature-topic', action='append', default=None, metavar='TOPIC',
                   help='thermal input topic: sensor_msgs/Temperature (a temperature, or a '
                        'proxy such as a resonance frequency) or another stamped scalar '
                        '(FluidPressure, Illuminance, RelativeHumidity); repeat for several '
                        'inputs (default: all Temperature topics, or those of the calibration)')
    p.add_argument('--max-gap', type=float, default=5.0, metavar='S',
                   help='temperature samples further apart than this are a gap: the nearest '
                        'sample is held instead of interpolating (s, default 5)')
    p.add_argument('--chunk-size', type=int, default=20000, help=argparse.SUPPRESS)
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None,
                   help='progress bar (default: only on a terminal)')


def _add_detector(p):
    d = DetectorConfig()
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
                       gyro_factor=args.still_factor, rotation_dps=args.rotation_dps)
    try:
        c.validate()
    except ValueError as e:
        raise UserError(f'{e}; leave it out to derive it from the log') from None
    return c


def _gravity(args):
    try:
        g, src = resolve_gravity(args.gravity, args.latitude, args.altitude)
    except ValueError as e:
        raise UserError(str(e)) from None
    if not 9.7 <= g <= 9.9:
        raise UserError(f'gravity {g:.6g} m/s^2 from --latitude/--altitude is not a '
                        'terrestrial value (9.7..9.9); check --altitude (metres)')
    return g, src


def build_parser():
    """Return the argparse parser (also used to document the CLI)."""
    ap = argparse.ArgumentParser(prog='thermal-imu-calib', description=__doc__.split('\n')[0])
    ap.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    ap.add_argument('--debug', action='store_true', help='show tracebacks')
    sub = ap.add_subparsers(dest='cmd', required=True)

    p = sub.add_parser('calibrate', help='estimate a thermal calibration from logs')
    p.add_argument('inputs', nargs='+', metavar='INPUT', help='rosbag2 dir, .mcap or .db3')
    _add_topics(p)
    grav = p.add_mutually_exclusive_group()
    grav.add_argument('--gravity', type=float, help='local gravity (m/s^2)')
    grav.add_argument('--latitude', type=float, help='latitude (deg) for WGS84 normal gravity')
    p.add_argument('--altitude', type=float, default=0.0, help='height (m) with --latitude')
    p.add_argument('--model', default='auto', choices=model_choices(),
                   help='auto: chosen from the data (see the summary); field: seed 000; '
                        'offset: single-orientation drift only; whole_unit: seed 002, gyro '
                        'scale and misalignment from the pose changes between holds')
    p.add_argument('--prior', help='lab calibration (k0, b0, S at T0) the field model refines: a '
                   'thermal_imu_calib YAML, imu_tk *_acc.calib, imucal .json, PX4 .params, '
                   'ArduPilot .parm or Kalibr imu.yaml')
    p.add_argument('--order', type=int, default=2, choices=(0, 1, 2),
                   help='temperature polynomial order of the field model (default 2)')
    p.add_argument('--no-refine', action='store_true', help='skip the joint refinement')
    p.add_argument('--out-of-range', default='clamp', choices=('clamp', 'extrapolate'),
                   help='outside the valid temperature range: hold the edge value (clamp) or '
                        'evaluate the model (extrapolate); both are counted and flagged')
    p.add_argument('--range-margin', type=float, default=1.0, metavar='DEGC',
                   help='valid range = collected temperature range widened by this (default 1)')
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

    p = sub.add_parser('compensate', help='write a log with compensated Imu messages added')
    p.add_argument('input', metavar='INPUT')
    p.add_argument('--calibration', required=True)
    _add_topics(p)
    p.add_argument('--output-topic', default='/imu/data_compensated')
    p.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'),
                   help='rosbag2 storage when OUTPUT is a directory (OUTPUT.mcap: bare MCAP)')
    p.add_argument('--temperature-timeout', type=float, default=None, metavar='S',
                   help='temperature older than this is stale (s, default: --max-gap)')
    p.add_argument('--on-missing-temperature', default='hold_last',
                   choices=('hold_last', 'passthrough', 'drop'))
    p.add_argument('--despike', action='store_true',
                   help='replace isolated spikes by the local median before compensation '
                        '(median/MAD gate, 3-sample look-ahead) and count them')
    p.add_argument('-o', '--output', required=True)

    p = sub.add_parser('evaluate', help='static errors before/after compensation')
    p.add_argument('input', metavar='INPUT')
    p.add_argument('--calibration', action='append', default=[], metavar='FILE',
                   help='calibration to apply; repeat to compare (label = file name)')
    _add_topics(p)
    grav = p.add_mutually_exclusive_group()
    grav.add_argument('--gravity', type=float)
    grav.add_argument('--latitude', type=float)
    p.add_argument('--altitude', type=float, default=0.0)
    p.add_argument('--average', type=float, default=300.0, metavar='S',
                   help='averaging window of the gravity residual (s, default 300)')
    p.add_argument('--json', action='store_true')
    _add_detector(p)

    p = sub.add_parser('simulate', help='write a realistic simulated recording and its truth')
    p.add_argument('output', metavar='OUTPUT', help='.mcap file or rosbag2 directory')
    p.add_argument('--scenario', default='demo')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--storage', default='mcap', choices=('mcap', 'sqlite3'))
    p.add_argument('--list', action='store_true', help='list the scenarios and exit')
    p.add_argument('--gyro-proxy', action='store_true',
                   help='also publish the gyro\'s drive-mode resonance frequency (Hz, f = 25 kHz '
                        '- 1.5 Hz/degC T) on /imu/gyro_resonance as a thermal proxy '
                        '(sensor_msgs/Temperature); writes OUTPUT.truth_proxy.yaml too')

    p = sub.add_parser('info', help='topics, counts, rates, span, temperature range')
    p.add_argument('input', metavar='INPUT')
    p.add_argument('--holds', action='store_true',
                   help='also run the stationary detector and list the holds it finds')
    _add_topics(p)
    _add_detector(p)

    p = sub.add_parser('report', help='print a calibration file for people; --html/--png-dir '
                                      'plot it')
    p.add_argument('calibration', metavar='CALIB.yaml')
    report_cli.add_report_args(p)
    report_cli.add_noise_parser(sub)
    cli_export.add_parser(sub)
    from .cli_fleet import add_fleet_parsers   # fleet calibrate/compensate, history, ...
    add_fleet_parsers(sub, COMMANDS)
    return ap


def cmd_calibrate(args):
    """Run the calibrate subcommand.

    The pose changes between holds (raw samples, bounded memory) are always collected: the
    seed 002 gyro fits its scale and misalignment from them, whether ``whole_unit`` (or
    ``auto``) chose it or an accelerometer-only model did (``gyro_select``); the collector
    costs ~0.09 s CPU per 375k messages, not measurable in a calibrate run.
    """
    from .pipeline import check_collected, collect_windows
    _gravity(args)   # a bad --gravity/--latitude is refused before reading any log
    cli_checks.check_distinct_inputs(args.inputs)
    cli_checks.check_calibration_output(args.output, args.inputs, args.prior, args.force,
                                        [(args.save_windows, '--save-windows')])
    if args.save_windows:
        cli_checks.check_writable_dir(args.save_windows, '--save-windows')
    if args.prior:
        load_prior(args.prior)   # a bad prior is refused before reading any log
    collected = []
    for path in args.inputs:
        c = collect_windows(path, args.imu_topic, args.temperature_topic, _detector(args),
                            args.chunk_size, args.max_gap, args.progress, motion=True,
                            input_units=args.input_unit)
        print(f'{path}: {c.imu_messages} Imu messages in {c.seconds:.1f} s '
              f'({c.imu_messages / max(c.seconds, 1e-9):,.0f} msgs/s), '
              f'{len(np.unique(c.windows.hold))} stationary holds' + _motion_text(c),
              file=sys.stderr)
        print('  ' + format_settings(c.detector), file=sys.stderr)
        if args.save_windows:
            print(format_holds(c.holds), file=sys.stderr)
        for warning in check_collected(path, c, args.max_gap):
            print(f'  warning: {warning}', file=sys.stderr)
        collected.append(c)
    result = calibrate_collected(args, collected, args.inputs)
    result.calibration.save(args.output)
    if args.json:
        print(json.dumps({'summary': result.summary, 'output': args.output,
                          'calibration': result.calibration.to_dict()}, indent=1, default=str))
    else:
        print(result.summary)
        for note in result.calibration.notes:
            print(f'  note: {note}')
        print(f'wrote {args.output}')
    return 0


def calibrate_collected(args, collected, paths):
    """Merge the Collected of several logs and estimate as ``calibrate`` does.

    ``args`` holds the calibrate options (the Namespace of its parser); ``paths`` are the
    logs (their names go to ``fit.inputs``; long holds are re-read for the random walk,
    ``noise.add_random_walk``). Returns the CalibrationResult (not saved), re-read by the
    nodes' loader first (``cli_checks.validated``: UserError if it would be refused). Shared by
    ``fleet calibrate`` (cli_fleet), whose reduce step must equal ``calibrate``.
    """
    from .estimation.gyro_fit import save_transitions
    from .pipeline import merge_transitions, merge_windows
    g, g_src = _gravity(args)
    prior = load_prior(args.prior) if args.prior else None
    topics = collected[0].temperature_topics
    for c in collected[1:]:
        if c.temperature_topics != topics:
            raise UserError(f'inputs have different temperature topics ({topics} vs '
                            f'{c.temperature_topics}); pass --temperature-topic')
    windows = merge_windows(collected)
    transitions = merge_transitions(collected)
    if args.save_windows:
        with open(args.save_windows, 'w') as f:
            f.write(windows.to_jsonl())
        with open(args.save_windows + '.transitions.npz', 'wb') as f:
            save_transitions(f, transitions)
        print(f'wrote {len(windows)} windows to {args.save_windows} and {len(transitions)} '
              f'pose changes to {args.save_windows}.transitions.npz', file=sys.stderr)
    inputs, mapping = _thermal_inputs(args, topics)
    opts = CalibrateOptions(model=args.model, gravity=g, gravity_source=g_src, prior=prior,
                            inputs=inputs, frame_id=args.frame_id or collected[0].frame_id,
                            out_of_range=args.out_of_range, order=args.order,
                            refine=not args.no_refine,
                            min_hold_s=args.min_hold or collected[0].detector["min_hold_s"]
                            if collected[0].detector else 10.0,
                            range_margin=args.range_margin, latitude=args.latitude,
                            transitions=transitions, **mapping)
    result = calibrate_windows(windows, opts)
    result.calibration.fit['inputs'] = [os.path.basename(os.path.normpath(p)) for p in paths]
    result.calibration.fit['detector'] = (collected[0].detector if len(collected) == 1
                                          else [c.detector for c in collected])
    from .noise import add_random_walk
    note = add_random_walk(result.calibration, paths, windows, args.imu_topic)
    result.calibration.notes += [note] if note else []
    # never hand on a calibration the nodes' loader would refuse (calibrate and fleet alike)
    cli_checks.validated(result.calibration, getattr(args, 'output', None) or 'the output')
    return result


def _motion_text(collected):
    """Return ', N pose changes (M too long dropped)' for a Collected ('' if not collected)."""
    if collected.motion is None:
        return ''
    dropped = ', '.join(f'{n} {why.replace("_", " ")}'
                        for why, n in collected.motion['dropped'].items() if n)
    return f', {len(collected.transitions)} pose changes' + (
        f' ({dropped} dropped)' if dropped else '')


def _thermal_inputs(args, topics):
    """Return the TemperatureInputs (with units) and the axis-mapping options of calibrate."""
    try:
        units = parse_unit_map(args.input_unit, topics)
    except ValueError as e:
        raise UserError(str(e)) from None
    inputs = [TemperatureInput(t.strip('/').replace('/', '_') or f't{i}', t, u)
              for i, (t, u) in enumerate(zip(topics, units))]
    margins = {}
    for item in args.input_margin:
        unit, sep, value = item.partition('=')
        try:
            margins[unit] = float(value)
        except ValueError:
            sep = ''
        if not sep or margins[unit] < 0:
            raise UserError(f'--input-margin {item!r} is not UNIT=VALUE with VALUE >= 0 (e.g. '
                            'Hz=1.5)')
    mapping = {'unit_margins': margins or None}
    bare = [t.lstrip('/') for t in topics]
    for sensor in ('accel', 'gyro'):
        spec = getattr(args, f'{sensor}_input')
        if not spec:
            continue
        names = [n.strip().lstrip('/') for n in spec.split(',')]
        if len(names) not in (1, 3) or any(n not in bare for n in names):
            raise UserError(f'--{sensor}-input {spec!r} must name one or three of the thermal '
                            f'inputs ({", ".join(topics) or "none"}), comma-separated')
        mapping[f'{sensor}_input'] = [bare.index(n) for n in names] * (3 // len(names))
    return inputs, mapping


def cmd_compensate(args):
    """Run the compensate subcommand."""
    from .pipeline import compensate_log
    cal = Calibration.load(args.calibration)
    if os.path.exists(args.output):
        raise UserError(f'{args.output} exists; remove it or choose another -o')
    cli_checks.check_writable_dir(args.output, '-o')
    st = compensate_log(args.input, args.output, cal, args.imu_topic, args.temperature_topic,
                        args.output_topic, args.storage, args.chunk_size, args.max_gap,
                        args.temperature_timeout, args.on_missing_temperature, args.progress,
                        args.despike)
    print(f'wrote {args.output}: {st["copied"]} messages copied, {st["imu_out"]} compensated '
          f'on {args.output_topic} ({st["out_of_range"]} outside the calibrated temperature '
          f'range, {st["passthrough"]} passed through, {st["dropped"]} dropped'
          + (f', {st["spikes"]} spike values replaced' if args.despike else '') + '), '
          f'{st["msgs_per_s"]:,.0f} msgs/s')
    return 0


def cmd_evaluate(args):
    """Run the evaluate subcommand."""
    from .pipeline import evaluate_log
    g, _ = _gravity(args)
    cals = {}
    for path in args.calibration:
        label = os.path.splitext(os.path.basename(path))[0]
        while label in cals:
            label += "'"
        cals[label] = Calibration.load(path)
    res = evaluate_log(args.input, cals, args.imu_topic, args.temperature_topic,
                       _detector(args), g, args.average, args.chunk_size, args.max_gap,
                       args.progress)
    if res['holds'] == 0:
        raise UserError(f'{args.input}: no stationary holds found, so there is nothing to '
                        'evaluate; evaluate needs a log with the IMU held still in several '
                        'poses, each for at least the minimum hold (derived from the log; '
                        f'`thermal-imu-calib info {args.input} --holds` shows it and what the '
                        'detector finds, --min-hold S overrides it)')
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(format_evaluation(res))
    print(format_settings(res['detector']))
    print(format_holds(res['hold_list']))
    return 0


def format_evaluation(res):
    """Render evaluate results as a table (micro-g, micro-g/degC, rad/s)."""
    r = res['results']
    labels = list(r)
    heads = ['recorded' if lb == 'raw' else lb for lb in labels]
    avg_s = r['raw']['averaged_residual_ug']['window_s']
    rows = [('holds', lambda m: f'{m["holds"]}'),
            ('gravity residual per hold, RMS [ug]',
             lambda m: f'{m["gravity_residual_ug"]["rms"]:.1f}'),
            ('gravity residual per hold, max [ug]',
             lambda m: f'{m["gravity_residual_ug"]["max"]:.1f}'),
            (f'{avg_s:.0f}-s averaged residual, RMS [ug]',
             lambda m: f'{m["averaged_residual_ug"]["rms"]:.1f}'),
            (f'{avg_s:.0f}-s averaged residual, max [ug]',
             lambda m: f'{m["averaged_residual_ug"]["max"]:.1f}'),
            ('drift vs temperature x,y,z RMS [ug/degC]',
             lambda m: ('/'.join(f'{v:.1f}' for v in m['drift_ug_per_degC_rms'])
                        if 'drift_ug_per_degC_rms' in m else '-')),
            ('gyro rate per hold, RMS [rad/s]', lambda m: f'{m["gyro_rate_rms"]["value"]:.2e}')]
    w0 = max(len(n) for n, _ in rows)
    cols = [max(len(lb), 14) for lb in heads]
    out = [f'{res["path"]}: {res["holds"]} stationary holds, {res["windows"]} windows',
           ' ' * w0 + '  ' + '  '.join(f'{lb:>{c}}' for lb, c in zip(heads, cols))]
    for name, fn in rows:
        cells = '  '.join(f'{fn(r[lb]):>{c}}' for lb, c in zip(labels, cols))
        out.append(f'{name:<{w0}}  {cells}')
    return '\n'.join(out)


def cmd_simulate(args):
    """Run the simulate subcommand."""
    from . import sim
    if args.list:
        for name, sc in sim.SCENARIOS.items():
            doc = (getattr(sc, 'description', '') or '').strip().splitlines()
            print(f'{name:18s} {doc[0] if doc else ""}')
        return 0
    if args.scenario not in sim.SCENARIOS:
        raise UserError(f'unknown scenario {args.scenario!r}; choose one of '
                        f'{", ".join(sim.SCENARIOS)}')
    if os.path.exists(args.output):
        raise UserError(f'{args.output} exists; remove it or choose another OUTPUT')
    cli_checks.check_writable_dir(args.output, 'OUTPUT')
    if args.gyro_proxy:
        from .sim_proxy import write_proxy_scenario
        info = write_proxy_scenario(args.output, args.scenario, args.seed, storage=args.storage)
    else:
        info = sim.write_scenario(args.output, args.scenario, args.seed, storage=args.storage)
    print(f'wrote {args.output} (scenario {args.scenario}, seed {args.seed})')
    for k, v in info.items():
        if isinstance(v, (str, int, float)):
            print(f'  {k}: {v}')
    return 0


def cmd_info(args):
    """Run the info subcommand."""
    from .io.bag import open_log
    with open_log(args.input) as reader:
        print(reader.info().format())
    if args.holds:
        from .pipeline import collect_windows
        c = collect_windows(args.input, args.imu_topic, args.temperature_topic, _detector(args),
                            args.chunk_size, args.max_gap, args.progress)
        print(f'{len(c.holds)} stationary holds')
        print(format_settings(c.detector))
        print(format_holds(c.holds))
    return 0


def cmd_report(args):
    """Run the report subcommand (text; HTML/PNG with --html/--png-dir)."""
    return report_cli.cmd_report(args, format_calibration, UserError)


def format_calibration(cal):
    """Render a calibration for people: models, parameters with units and stds, fit, notes."""
    out = [f'calibration {cal.id}  frame_id={cal.frame_id or "?"}  created {cal.created}  '
           f'software {cal.software_version}',
           f'gravity {cal.gravity:.6f} m/s^2 ({cal.gravity_source})']
    if cal.inputs:
        vr = cal.valid_range
        out.append('temperature inputs: ' + ', '.join(
            f'{i.topic} [{vr[j, 0]:.2f}..{vr[j, 1]:.2f} {i.unit}]'
            for j, i in enumerate(cal.inputs)) + f'; outside: {cal.out_of_range}')
        out.append(f'mapping: accel axes <- inputs {cal.accel_input}, gyro axes <- inputs '
                   f'{cal.gyro_input}')
    else:
        out.append('temperature inputs: none (temperature-independent)')
    for name, model in (('accel', cal.accel), ('gyro', cal.gyro)):
        if model is None:
            continue
        out.append(f'{name}: {model.kind} {model.meta()}')
        for pname, p in model.params().items():
            v = np.asarray(p.value)
            val = np.array2string(v.ravel(), max_line_width=200,
                                  formatter={'float_kind': lambda x: f'{x:.5g}'})
            sd = '' if p.std is None else '  std ' + np.array2string(
                np.asarray(p.std, float).ravel(), max_line_width=200,
                formatter={'float_kind': lambda x: f'{x:.2g}'})
            out.append(f'  {pname:4s} [{p.unit}] {val}{sd}')
    fit = cal.fit or {}
    for key in ('holds', 'windows', 'faces', 'temperature_span', 'residual_rms',
                'gravity_residual_ug'):
        if key in fit:
            out.append(f'fit.{key}: {fit[key]}')
    for n in cal.notes:
        out.append(f'note: {n}')
    return '\n'.join(out)


COMMANDS = {'calibrate': cmd_calibrate, 'compensate': cmd_compensate,
            'evaluate': cmd_evaluate, 'simulate': cmd_simulate, 'info': cmd_info,
            'report': cmd_report, 'noise': lambda a: report_cli.cmd_noise(a, UserError),
            'export': cli_export.cmd_export}


def main(argv=None):
    """Entry point of ``thermal-imu-calib``."""
    args = build_parser().parse_args(argv)
    cli_checks.install_sigterm()
    try:
        cli_checks.check_options(args)
        from threadpoolctl import threadpool_limits
        # the fits are small dense problems: BLAS threads only contend (docs/speed.md)
        with threadpool_limits(limits=1, user_api='blas'):
            return COMMANDS[args.cmd](args)
    except (UserError, LogError, CalibrationError, CalibrationRefused, FileNotFoundError,
            ValueError, OSError) as e:
        if args.debug:
            raise
        msg = _os_error_text(e) if isinstance(e, OSError) else str(e)
        msg = msg.strip().replace('\n', ' ')
        print(f'thermal-imu-calib {args.cmd}: error: {msg}', file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as e:
        print('terminated' if isinstance(e, cli_checks.Terminated) else 'interrupted',
              file=sys.stderr)
        return 143 if isinstance(e, cli_checks.Terminated) else 130


def _os_error_text(e):
    """Return 'cannot access FILE: reason; what to do' for an OSError."""
    if e.filename is None:
        return str(e)
    what = 'write' if isinstance(e, (PermissionError, IsADirectoryError)) else 'access'
    return (f'cannot {what} {e.filename}: {e.strerror or e}; check the path and its '
            'permissions')


if __name__ == '__main__':
    sys.exit(main())
