"""``thermal-imu-calib``: the library on recorded logs.

Subcommands: calibrate, compensate, evaluate, simulate, info, report, noise, export. Bad
input gets one line on stderr saying what was wrong and what to do, and exit status 2;
``--debug`` shows the traceback instead.
"""

import argparse
import json
import sys

from .. import __version__
from . import checks as cli_checks, export as cli_export
from ..calibration import Calibration, CalibrationError
from ..app import calibrate as app_calibrate
from .calibrate import (_add_detector, _add_topics, _detector, _gravity,
                        add_calibrate_parser, settings_from_args)
from .checks import UserError
from .format import (format_calibrate_run, format_calibration, format_evaluation,
                     format_log_read, format_saved_windows)
from ..collection.stationary import format_holds, format_settings
from ..estimation.calibrate import CalibrationRefused
from ..io.gate import JUMP_S
from ..io.log_info import LogError
from ..io.output import Outputs
from ..report import cli as report_cli

EXIT_USAGE = 2


def build_parser():
    """Return the argparse parser (also used to document the CLI)."""
    ap = argparse.ArgumentParser(prog='thermal-imu-calib', description=__doc__.split('\n')[0])
    ap.add_argument('--version', action='version', version=f'%(prog)s {__version__}')
    ap.add_argument('--debug', action='store_true', help='show tracebacks')
    sub = ap.add_subparsers(dest='cmd', required=True)

    add_calibrate_parser(sub)

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
    from .fleet import add_fleet_parsers   # fleet calibrate/compensate, history, ...
    add_fleet_parsers(sub, COMMANDS)
    return ap


def cmd_calibrate(args):
    """Run the calibrate subcommand: one ``app.calibrate.calibrate_logs`` over the logs."""
    cli_checks.check_distinct_inputs(args.inputs)
    cli_checks.calibrate_outputs(args)   # every output checked before any log is read
    run = app_calibrate.calibrate_logs(
        settings_from_args(args), args.inputs, args.output, args.imu_topic,
        args.temperature_topic, args.chunk_size, args.progress, args.save_windows,
        on_log=lambda read: print(format_log_read(read, args.save_windows), file=sys.stderr))
    if run.saved:
        print(format_saved_windows(run.saved, args.save_windows), file=sys.stderr)
    print(format_calibrate_run(run, args.output, args.json))
    return 0


def cmd_compensate(args):
    """Run the compensate subcommand."""
    from ..app.compensate import compensate_log
    Outputs([args.input, args.calibration]).log(args.output, '-o')
    cal = Calibration.load(args.calibration)
    st = compensate_log(args.input, args.output, cal, args.imu_topic, args.temperature_topic,
                        args.output_topic, args.storage, args.chunk_size, args.max_gap,
                        args.temperature_timeout, args.on_missing_temperature, args.progress,
                        args.despike)
    print(f'wrote {args.output}: {st["copied"]} messages copied, {st["imu_out"]} written '
          f'on {args.output_topic} ({st["compensated"]} compensated, {st["out_of_range"]} '
          f'outside the calibrated temperature range, {st["passthrough"]} passed through, '
          f'{st["dropped"]} dropped'
          + (f', {st["stamp_jumped_back"]} after IMU stamps jumped back by more than '
             f'{JUMP_S:.0f} s passed through' if st['stamp_jumped_back'] else '')
          + (f', {st["stamp_jumps"] - st["stamp_jumped_back"]} with a repeated or earlier '
             'stamp compensated at that stamp'
             if st['stamp_jumps'] > st['stamp_jumped_back'] else '')
          + (f', {st["spikes"]} spike values replaced' if args.despike else '') + '), '
          f'{st["msgs_per_s"]:,.0f} msgs/s')
    for note in st['notes']:
        print(f'note: {note}')
    return 0


def cmd_evaluate(args):
    """Run the evaluate subcommand (``app.evaluate.evaluate_files``)."""
    from ..app.evaluate import evaluate_files
    g, _ = _gravity(args)
    res = evaluate_files(args.input, args.calibration, args.imu_topic, args.temperature_topic,
                         _detector(args), g, args.average, args.chunk_size, args.max_gap,
                         args.progress)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(format_evaluation(res))
    print(format_settings(res['detector']))
    print(format_holds(res['hold_list']))
    return 0


def cmd_simulate(args):
    """Run the simulate subcommand."""
    from .. import sim
    from ..sim import robot_month
    if args.list:
        for name, sc in {**sim.SCENARIOS, **robot_month.SCENARIOS}.items():
            doc = (getattr(sc, 'description', '') or '').strip().splitlines()
            print(f'{name:18s} {doc[0] if doc else ""}')
        return 0
    if args.scenario in robot_month.SCENARIOS:      # stops only, with cmd_vel hints
        out = Outputs()
        out.log(args.output, 'OUTPUT')
        info = robot_month.write_robot_month(args.output, args.seed, storage=args.storage)
        print(f'wrote {args.output} and {info["side"]} (scenario {args.scenario}, seed '
              f'{args.seed}): {info["summary"]["stops"]} stops, '
              f'{info["summary"]["imu_samples"]} IMU samples')
        return 0
    if args.scenario not in sim.SCENARIOS:
        raise UserError(f'unknown scenario {args.scenario!r}; choose one of '
                        f'{", ".join(list(sim.SCENARIOS) + list(robot_month.SCENARIOS))}')
    out = Outputs()
    out.log(args.output, 'OUTPUT')
    from ..sim import sidecar_outputs
    for path, kind, own in sidecar_outputs(args.output, args.gyro_proxy):
        out.file(path, 'OUTPUT', kind, own)
    if args.gyro_proxy:
        from ..sim.proxy import write_proxy_scenario
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
    from ..io.bag import open_log
    from ..io.headerless import clock_notes
    from ..io.topics import resolve_topics
    with open_log(args.input) as reader:
        info = reader.info()
        print(info.format())
        notes = []
        try:
            imu, temps = resolve_topics(reader, args.imu_topic, args.temperature_topic, notes)
            notes += clock_notes(info, imu, temps)
        except LogError as e:
            print(f'calibrate would refuse: {e}')
        else:
            print(f'calibrate would use: IMU {imu}, temperature '
                  f'{", ".join(temps) or "none"}' + ''.join(f'\n  note: {n}' for n in notes))
    if args.holds:
        from ..app.collect import collect_windows
        c = collect_windows(args.input, args.imu_topic, args.temperature_topic, _detector(args),
                            args.chunk_size, args.max_gap, args.progress)
        print(f'{len(c.holds)} stationary holds')
        print(format_settings(c.detector))
        print(format_holds(c.holds))
    return 0


def cmd_report(args):
    """Run the report subcommand (text; HTML/PNG with --html/--png-dir)."""
    return report_cli.cmd_report(args, format_calibration, UserError)


COMMANDS = {'calibrate': cmd_calibrate, 'compensate': cmd_compensate,
            'evaluate': cmd_evaluate, 'simulate': cmd_simulate, 'info': cmd_info,
            'report': cmd_report, 'noise': lambda a: report_cli.cmd_noise(a, UserError),
            'export': cli_export.cmd_export}


def main(argv=None):
    """Entry point of ``thermal-imu-calib``."""
    args = build_parser().parse_args(argv)
    cli_checks.install_signals()
    try:
        cli_checks.check_options(args)
        from threadpoolctl import threadpool_limits
        # the fits are small dense problems: BLAS threads only contend (docs/speed.md)
        with threadpool_limits(limits=1, user_api='blas'):
            status = COMMANDS[args.cmd](args)
        # a signal whose KeyboardInterrupt Python swallowed (inside a clean-up callback)
        # still ends the command as interrupted: no exit 0 after Ctrl-C
        late = cli_checks.interrupted_status()
        if late is not None:
            print(late[0], file=sys.stderr)
            return late[1]
        return status
    except (UserError, LogError, CalibrationError, CalibrationRefused, FileNotFoundError,
            ValueError, OSError) as e:
        if args.debug:
            raise
        msg = _os_error_text(e) if isinstance(e, OSError) else str(e)
        msg = msg.strip().replace('\n', ' ')
        print(f'thermal-imu-calib {args.cmd}: error: {msg}', file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as e:
        word, status = cli_checks.interrupted_status(e)
        print(word, file=sys.stderr)
        return status


def _os_error_text(e):
    """Return 'cannot access FILE: reason; what to do' for an OSError."""
    if e.filename is None:
        return str(e)
    what = 'write' if isinstance(e, (PermissionError, IsADirectoryError)) else 'access'
    return (f'cannot {what} {e.filename}: {e.strerror or e}; check the path and its '
            'permissions')


if __name__ == '__main__':
    sys.exit(main())
