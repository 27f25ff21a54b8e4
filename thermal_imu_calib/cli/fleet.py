"""Fleet subcommands of ``thermal-imu-calib``: fleet calibrate/compensate, history, simulate-fleet.

Thin adapters: the steps are ``app.fleet``'s (map, reduce, compensate one log), run on
Dask by ``fleet.runner``; ``fleet/`` holds the inputs, the registry, the history and the
fleet simulator. Registered in ``cli.build_parser`` by ``add_fleet_parsers``.
"""

import functools
import os
import sys

from ..app import fleet as app_fleet
from ..fleet import inputs as fin
from ..fleet import registry as reg
from ..fleet.runner import _progress, check_workers, fleet_client, run_fleet
from ..io.output import HTML, Outputs

EXIT_PARTIAL = 1


def _add_cluster(p):
    p.add_argument('--by', default='frame_id', metavar='RULE',
                   help='sensor id of a log: frame_id (IMU header, default), topic (IMU '
                        'topic), metadata:KEY (rosbag2 custom_data / MCAP metadata), '
                        'path:REGEX (first group of REGEX in the path)')
    g = p.add_mutually_exclusive_group()
    g.add_argument('--scheduler', metavar='ADDRESS',
                   help='use an existing Dask cluster (e.g. tcp://host:8786) instead of a '
                        'LocalCluster on this machine')
    g.add_argument('--workers', type=int, default=None, metavar='N',
                   help='worker processes of the LocalCluster (default: one per core)')


def add_fleet_parsers(sub, commands):
    """Add the fleet subcommands to ``sub`` and their handlers to ``commands``."""
    from .calibrate import _add_detector, _add_topics
    from ..estimation.calibrate import model_choices
    fleet = sub.add_parser('fleet', help='calibrate or compensate many logs of many sensors '
                                         'on a Dask cluster')
    fsub = fleet.add_subparsers(dest='fleet_cmd', required=True)
    p = fsub.add_parser('calibrate', help='one calibration per sensor into a registry')
    p.add_argument('inputs', nargs='+', metavar='INPUT',
                   help='logs, directories (searched recursively), globs or manifest files '
                        '(one INPUT per line)')
    _add_cluster(p)
    p.add_argument('--period', type=float, default=0.0, metavar='DAYS',
                   help='one calibration per sensor and DAYS-long period from its first log '
                        '(default 0: one from all its logs)')
    p.add_argument('--model', default='auto', choices=model_choices(),
                   help='model family, as calibrate --model (default auto)')
    p.add_argument('--order', type=int, default=2, choices=(0, 1, 2))
    grav = p.add_mutually_exclusive_group()
    grav.add_argument('--gravity', type=float, help='local gravity (m/s^2)')
    grav.add_argument('--latitude', type=float, help='latitude (deg), WGS84 normal gravity')
    p.add_argument('--altitude', type=float, default=0.0, help='height (m) with --latitude')
    p.add_argument('-o', '--output', required=True, metavar='REGISTRY_DIR',
                   help='registry: REGISTRY_DIR/<sensor>/<time>.yaml + index.csv')
    _add_topics(p)
    _add_detector(p)

    p = fsub.add_parser('compensate', help='compensate every log with its unit\'s '
                                           'calibration valid at the log\'s time')
    p.add_argument('inputs', nargs='+', metavar='INPUT')
    p.add_argument('--registry', required=True, metavar='REGISTRY_DIR')
    _add_cluster(p)
    p.add_argument('--output-topic', default='/imu/data_compensated')
    p.add_argument('--on-missing-temperature', default='hold_last',
                   choices=('hold_last', 'passthrough', 'drop'))
    p.add_argument('--despike', action='store_true')
    p.add_argument('-o', '--output', required=True, metavar='OUT_DIR',
                   help='outputs mirror the input tree under OUT_DIR (written atomically)')
    _add_topics(p)

    p = sub.add_parser('history', help='calibrations of each unit over time, with alarms')
    p.add_argument('registry', metavar='REGISTRY_DIR')
    p.add_argument('--sensor', action='append', default=None, metavar='ID')
    p.add_argument('--html', metavar='FILE', help='also write an HTML report')
    p.add_argument('--force', action='store_true',
                   help='replace an existing --html file that is not an HTML page')
    p.add_argument('--family-rate', type=float, default=reg.FAMILY_RATE, metavar='P',
                   help='false-alarm probability for the whole fleet (default '
                        f'{reg.FAMILY_RATE:g}): the |z| threshold of every test follows '
                        'from it and the number of tests (Sidak); smaller flags fewer '
                        'stable units and later drift')

    p = sub.add_parser('simulate-fleet', help='write DIR/<unit>/<log>.mcap for a simulated '
                                              'fleet (some units drift, one has a step)')
    p.add_argument('output', metavar='DIR')
    p.add_argument('--units', type=int, default=20)
    p.add_argument('--logs-per-unit', type=int, default=5)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--workers', type=int, default=None, metavar='N',
                   help='simulate on a LocalCluster of N processes (default: in this process)')
    commands.update({'fleet': cmd_fleet, 'history': cmd_history,
                     'simulate-fleet': cmd_simulate_fleet})


def cmd_fleet(args):
    """Dispatch ``fleet calibrate`` / ``fleet compensate``."""
    return {'calibrate': cmd_fleet_calibrate,
            'compensate': cmd_fleet_compensate}[args.fleet_cmd](args)


def calibrate_args(args):
    """Return the ``calibrate`` Namespace (its defaults) with the fleet options applied."""
    from .calibrate import calibrate_defaults
    cargs = calibrate_defaults()
    for k, v in vars(args).items():
        if hasattr(cargs, k) and k not in ('inputs', 'output', 'cmd'):
            setattr(cargs, k, v)
    cargs.progress = False
    return cargs


def fleet_settings(args):
    """Return the CalibrateSettings of ``fleet calibrate`` (``calibrate``'s, with its options)."""
    from .calibrate import settings_from_args
    return settings_from_args(calibrate_args(args))


def _collect_kw(args):
    """Return what every map step gets: the topics, the chunk size (and gap, to compensate)."""
    kw = {'imu_topic': args.imu_topic, 'temperature_topics': args.temperature_topic,
          'chunk_size': args.chunk_size}
    if hasattr(args, 'min_hold'):    # fleet calibrate: calibrate's detector and input gate
        kw['settings'] = fleet_settings(args)
    else:
        kw['max_gap_s'] = args.max_gap
    return kw


def cmd_fleet_calibrate(args):
    """Run ``fleet calibrate``: map logs, reduce per sensor, write the registry."""
    from .calibrate import _gravity
    group = fin.GroupBy.parse(args.by)
    if args.period < 0:
        raise ValueError(f'--period {args.period}: give 0 (all logs) or a positive number '
                         'of days')
    _gravity(args)
    check_workers(args.workers)
    paths = fin.expand_inputs(args.inputs)
    _check_registry_output(args.output, list(args.inputs) + paths)
    print(f'fleet calibrate: {len(paths)} logs', file=sys.stderr)
    collect_kw = _collect_kw(args)
    reduce_fn = functools.partial(app_fleet.calibrate_unit, collect_kw['settings'],
                                  args.imu_topic)
    with fleet_client(args.scheduler, args.workers) as client:
        units, failed = run_fleet(client, paths, group, reduce_fn, collect_kw, args.period,
                                  args.progress)
    entries, bad = [], len(failed)
    for path, warning in (w for u in units for w in u.warnings):
        print(f'{path}: warning: {warning}', file=sys.stderr)
    for f in failed:
        print(f'FAILED {f.path}: {f.error} (sensor unknown; not used)')
    for u in units:
        name = reg.display_id(u.sensor)
        for path, why in u.excluded:
            print(f'FAILED {path}: {why} (sensor {name}; not used)')
            bad += 1
        if u.error:
            print(f'{name}: NOT calibrated ({len(u.logs)} logs): {u.error}')
            bad += 1
            continue
        entries.append(app_fleet.registry_entry(u))
    errors = []
    paths_out = reg.add(args.output, entries, errors) if entries else []
    for (sensor, cal, *_), out in zip(entries, paths_out):
        if out is None:
            continue
        res = (cal.fit or {}).get('residual_rms', {})
        print(f'{reg.display_id(sensor)}: {cal.accel.kind if cal.accel else "-"}/'
              f'{cal.gyro.kind if cal.gyro else "-"}, {cal.fit.get("holds")} holds, residual '
              f'{res.get("value", float("nan")):.3g} m/s^2 -> {out}')
    for sensor, why in errors:
        print(f'{reg.display_id(sensor)}: NOT written: {why}')
    written = sum(p is not None for p in paths_out)
    bad += len(errors)
    print(f'fleet calibrate: {written} calibrations written to {args.output} '
          f'(index {os.path.join(args.output, reg.INDEX)}), {bad} failures')
    if not written:
        return 2
    return EXIT_PARTIAL if bad else 0


def _check_registry_output(registry, inputs):
    """Refuse a registry -o that is an input, inside one, or a directory that is not a registry."""
    Outputs(inputs).directory(registry, '-o', 'registry')
    if os.path.isdir(registry) and os.listdir(registry) and not os.path.isfile(
            os.path.join(registry, reg.INDEX)):
        raise ValueError(f'-o {registry} is a directory that is not empty and has no '
                         f'{reg.INDEX}, so it is not a registry; choose a new or empty '
                         'directory, or an existing registry')


def cmd_fleet_compensate(args):
    """Run ``fleet compensate``: each log with its unit's calibration valid at its time."""
    group = fin.GroupBy.parse(args.by)
    if not os.path.isfile(os.path.join(args.registry, reg.INDEX)):
        raise ValueError(f'{args.registry} has no {reg.INDEX}: not a registry written by '
                         '`thermal-imu-calib fleet calibrate`')
    check_workers(args.workers)
    paths = fin.expand_inputs(args.inputs)
    root = fin.common_root(paths)
    outs = [os.path.join(args.output, os.path.relpath(os.path.abspath(p), root))
            for p in paths]
    existing = [o for o in outs if os.path.lexists(o)]
    if existing:
        raise ValueError(f'{existing[0]} exists ({len(existing)} outputs do); remove them or '
                         'choose another -o')
    checked = Outputs(list(args.inputs) + paths + [args.registry])
    Outputs(checked.inputs).directory(args.output, '-o', 'compensated logs')
    for o in outs:
        checked.log(o, '-o')
    kw = dict(_collect_kw(args), output_topic=args.output_topic,
              on_missing=args.on_missing_temperature, despike=args.despike)
    with fleet_client(args.scheduler, args.workers) as client:
        futs = [client.submit(app_fleet.compensate_unit_log, p, o,
                              os.path.abspath(args.registry), group, kw, pure=False)
                for p, o in zip(paths, outs)]
        _progress(futs, args.progress)
        results = client.gather(futs)
    bad = 0
    for path, text, ok in results:
        print(text if ok else f'FAILED {path}: {text}')
        bad += not ok
    print(f'fleet compensate: {len(results) - bad} of {len(results)} logs written under '
          f'{args.output}')
    if bad == len(results):
        return 2
    return EXIT_PARTIAL if bad else 0


def cmd_history(args):
    """Run ``history``: parameters over time with +-1 sigma, and the alarms."""
    from ..fleet.history import format_history, write_html
    if args.html:
        Outputs([args.registry], args.force).file(args.html, '--html', 'HTML page', HTML)
    if not 0.0 < args.family_rate < 1.0:
        raise ValueError(f'--family-rate {args.family_rate:g} must lie between 0 and 1 (a '
                         f'probability, e.g. {reg.FAMILY_RATE:g} for 1 %)')
    rows = reg.read_index(args.registry)
    if not rows:
        raise ValueError(f'{args.registry}: no {reg.INDEX}; run `thermal-imu-calib fleet '
                         'calibrate ... -o REGISTRY_DIR` first')
    # the family (tests, residuals) = the whole fleet
    fleet_alarms, info = reg.assess(rows, family_rate=args.family_rate)
    if args.sensor:
        unknown = sorted(set(args.sensor) - {r['sensor'] for r in rows})
        if unknown:
            raise ValueError(f'no sensor {unknown[0]!r} in {args.registry}')
        rows = [r for r in rows if r['sensor'] in args.sensor]
    print(format_history(rows, fleet_alarms, info))
    if args.html:
        write_html(args.html, rows, fleet_alarms, info)
        print(f'wrote {args.html}')
    return 0


def cmd_simulate_fleet(args):
    """Run ``simulate-fleet``."""
    from ..fleet.simulate import FleetDesign, simulate_fleet
    if args.units < 1 or args.logs_per_unit < 1:
        raise ValueError('--units and --logs-per-unit must be >= 1')
    Outputs().directory(args.output, 'DIR', 'simulated fleet')
    if os.path.exists(args.output) and os.listdir(args.output):
        raise ValueError(f'{args.output} exists and is not empty; remove it or choose '
                         'another DIR')
    design = FleetDesign(units=args.units, logs_per_unit=args.logs_per_unit, seed=args.seed)
    if args.workers:
        with fleet_client(None, args.workers) as client:
            paths = simulate_fleet(args.output, design, client)
    else:
        paths = simulate_fleet(args.output, design)
    print(f'wrote {len(paths)} logs of {args.units} units to {args.output} (truth: '
          f'{os.path.join(args.output, "fleet_truth.csv")})')
    return 0
