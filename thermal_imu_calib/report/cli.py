"""The ``report`` options and the ``noise`` subcommand of ``thermal-imu-calib``.

Adapters: the windows a report draws come from ``app.report.report_windows``, the noise
figures from ``app.noise.noise_from_log``; this module checks the outputs first, then
formats and writes.
"""

import os
import sys

from ..app.report import report_windows
from ..calibration import Calibration
from ..io.output import containing, HTML, Outputs, PNG, write_atomic


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
    _add_force(p)


def _add_force(p):
    p.add_argument('--force', action='store_true',
                   help='replace an existing output that is not of its kind (never an input, '
                        'never a special file)')


def _outputs(args, inputs, html):
    """Check --html/--png-dir (and -o) before anything is computed; returns the Outputs."""
    out = Outputs(inputs, args.force)
    if getattr(args, 'output', None):
        out.file(args.output, '-o', 'Kalibr imu.yaml', containing(b'accelerometer_noise_density'))
    if html:
        out.file(html, '--html', 'HTML page', HTML)
    if args.png_dir:
        out.directory(args.png_dir, '--png-dir', 'PNG figures')
    return out


def _write_page(page, out, html, png_dir):
    """Check the PNG files of ``page`` (known once built), then write; returns the paths."""
    if png_dir:
        for p in page.png_paths(png_dir):
            out.file(p, '--png-dir', 'PNG image', PNG)
    return page.write(html, png_dir)


def cmd_report(args, format_calibration, user_error):
    """Run ``report``: text as before, plus the HTML page / PNG figures when asked."""
    out = _outputs(args, [args.calibration, args.windows] + list(args.log), args.html)
    cal = Calibration.load(args.calibration)
    if not (args.html or args.png_dir):
        print(format_calibration(cal))
        return 0
    try:
        windows, series, source = report_windows(cal, args.log, args.windows, args.imu_topic)
    except ValueError as e:
        raise user_error(str(e)) from None
    from .build import calibration_page
    paths = _write_page(calibration_page(cal, windows, series, source), out, args.html,
                        args.png_dir)
    pngs = [p for p in paths if p.endswith('.png')]
    print('wrote ' + ', '.join(([args.html] if args.html else [])
                               + ([f'{len(pngs)} PNG files in {args.png_dir}'] if pngs else [])))
    return 0


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
    _add_force(p)
    return p


def cmd_noise(args, user_error):
    """Run ``noise``."""
    from ..estimation.noise_model import format_noise, kalibr_yaml
    from ..app.noise import noise_from_log
    html = None
    if args.html is not None:
        html = args.html or os.path.normpath(args.input) + '.noise.html'
    out = _outputs(args, [args.input], html)    # before the (long) Allan computation
    topic, result = noise_from_log(args.input, args.imu_topic)
    print(format_noise(result, topic))
    if args.output:
        write_atomic(args.output, kalibr_yaml(result, topic))
        print(f'wrote {args.output} (Kalibr imu.yaml, worst axis)', file=sys.stderr)
    if html or args.png_dir:
        from .build import noise_page
        for p in _write_page(noise_page(result, topic, args.input), out, html, args.png_dir):
            print(f'wrote {p}', file=sys.stderr)
    return 0
