"""The ``report`` options and the ``noise`` subcommand of ``thermal-imu-calib``."""

import os
import sys

from ..calibration import Calibration


def add_report_args(p):
    """Add the plotting options to the existing ``report`` parser."""
    p.add_argument('--log', action='append', default=[], metavar='LOG',
                   help='calibration log(s) to draw the windows from (repeat); default: '
                        '--windows, else the calibration file alone')
    p.add_argument('--windows', metavar='FILE',
                   help='window statistics written by calibrate --save-windows')
    p.add_argument('--imu-topic', default=None)
    p.add_argument('--html', metavar='OUT.html', help='write a self-contained HTML report')
    p.add_argument('--png-dir', metavar='DIR', help='write the report figures as PNG files')


def cmd_report(args, format_calibration, user_error):
    """Run ``report``: text as before, plus the HTML page / PNG figures when asked."""
    cal = Calibration.load(args.calibration)
    if not (args.html or args.png_dir):
        print(format_calibration(cal))
        return 0
    windows, series, source = load_windows(args, cal, user_error)
    paths = write_report(cal, args.html, args.png_dir, windows, series, source)
    pngs = [p for p in paths if p.endswith('.png')]
    print('wrote ' + ', '.join(([args.html] if args.html else [])
                               + ([f'{len(pngs)} PNG files in {args.png_dir}'] if pngs else [])))
    return 0


def load_windows(args, cal, user_error):
    """Return (Windows or None, temperature series or None, source text)."""
    from ..collection.segments import Windows
    if args.log:
        from ..pipeline import collect_windows, merge_windows
        topics = cal.temperature_topics or None
        collected = [collect_windows(p, args.imu_topic, topics) for p in args.log]
        return (merge_windows(collected), _series(args.log[0], topics),
                ', '.join(args.log))
    if args.windows:
        if not os.path.isfile(args.windows):
            raise user_error(f'--windows {args.windows!r} does not exist; write it with '
                             'calibrate --save-windows FILE')
        with open(args.windows) as f:
            w = Windows.from_jsonl(f.read(), len(cal.inputs))
        if len(w) and w.n_inputs != len(cal.inputs):
            raise user_error(f'{args.windows} has {w.n_inputs} thermal inputs, the '
                             f'calibration {len(cal.inputs)}; pass the windows of this '
                             'calibration')
        return w, None, args.windows
    return None, None, ''


def _series(path, topics):
    """Return [(t [s], value)] per temperature topic of the first log (None on failure)."""
    import numpy as np
    from ..io.bag import open_log
    from ..io.topics import resolve_topics
    with open_log(path) as reader:
        imu, topics = resolve_topics(reader, None, topics)
        parts = {t: ([], []) for t in topics}
        for raw in reader.stream(imu, topics):
            for t, col in raw.temps.items():
                parts[t][0].append(col.stamp_ns)
                parts[t][1].append(col.temperature)
    return [(np.concatenate(parts[t][0]) * 1e-9 if parts[t][0] else np.zeros(0),
             np.concatenate(parts[t][1]) if parts[t][1] else np.zeros(0)) for t in topics]


def write_report(cal, html_path=None, png_dir=None, windows=None, series=None, source=''):
    """Build the calibration report and write it; returns the paths written."""
    from .build import calibration_page
    return calibration_page(cal, windows, series, source).write(html_path, png_dir)


def add_noise_parser(sub):
    """Register the ``noise`` subcommand."""
    p = sub.add_parser('noise', help='Allan-deviation noise model (N, K, B) from still data; '
                                     'Kalibr imu.yaml')
    p.add_argument('input', metavar='LOG', help='a long still recording, or a calibration log '
                                                '(its stationary holds are used)')
    p.add_argument('--imu-topic', default=None)
    p.add_argument('-o', '--output', metavar='noise.yaml', help='write a Kalibr imu.yaml')
    p.add_argument('--html', nargs='?', const='', default=None, metavar='OUT.html',
                   help='write an HTML page with the Allan plots (default name: '
                        'LOG.noise.html)')
    p.add_argument('--png-dir', metavar='DIR', help='write the Allan plots as PNG files')
    return p


def cmd_noise(args, user_error):
    """Run ``noise``."""
    from ..noise import format_noise, kalibr_yaml, noise_from_log
    if (args.output and os.path.exists(args.output)
            and os.path.samefile(args.output, args.input)):
        raise user_error('-o would overwrite the input log; choose another file')
    topic, result = noise_from_log(args.input, args.imu_topic)
    print(format_noise(result, topic))
    if args.output:
        tmp = args.output + '.tmp'
        with open(tmp, 'w') as f:
            f.write(kalibr_yaml(result, topic))
        os.replace(tmp, args.output)
        print(f'wrote {args.output} (Kalibr imu.yaml, worst axis)', file=sys.stderr)
    if args.html is not None or args.png_dir:
        from .build import noise_page
        html = None
        if args.html is not None:
            html = args.html or os.path.normpath(args.input) + '.noise.html'
        for p in noise_page(result, topic, args.input).write(html, args.png_dir):
            print(f'wrote {p}', file=sys.stderr)
    return 0
