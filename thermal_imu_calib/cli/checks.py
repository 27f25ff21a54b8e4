"""What the CLI checks before it computes or writes: options, outputs, inputs, signals.

Every refusal raises ``UserError`` (one line on stderr, exit 2) saying what was wrong and
what to do. Outputs are checked BEFORE the computation (an existing directory, a file that
is one of the inputs, an unwritable directory), and a calibration is re-read by the same
loader the nodes use before it is written, so ``calibrate`` never exits 0 with a file
``compensate`` or a node would refuse.
"""

import math
import os
import re
import signal
import sys

from ..app.calibrate import TRANSITIONS_SUFFIX
from ..calibration import Calibration, CalibrationError
from ..io import output

#: a ROS 2 topic name: absolute or relative tokens of [A-Za-z0-9_], not starting with a digit
_TOPIC_RE = re.compile(r'^~?/?([A-Za-z_][A-Za-z0-9_]*)(/[A-Za-z_][A-Za-z0-9_]*)*$')
#: --altitude accepted by calibrate/evaluate (m), as by calibrator_node
ALTITUDE_RANGE = (-1000.0, 10000.0)
#: --range-margin and --high-order-margin accepted (degC)
RANGE_MARGIN_RANGE = (0.0, 50.0)


class UserError(Exception):
    """Bad input from the command line; printed as one line."""


def check_number(value, option, lo=None, hi=None, lo_open=False):
    """Refuse a non-finite option value or one outside [lo, hi] (``lo_open``: > lo)."""
    if value is None:
        return
    if not math.isfinite(value):
        raise UserError(f'{option} {value} is not a finite number')
    low_bad = lo is not None and (value <= lo if lo_open else value < lo)
    if low_bad or (hi is not None and value > hi):
        rng = (f'> {lo:g}' if hi is None else f'in ({lo:g}, {hi:g}]') if lo_open else (
            f'>= {lo:g}' if hi is None else f'in [{lo:g}, {hi:g}]')
        raise UserError(f'{option} {value:g} is out of range; it must be {rng}')


def check_options(args):
    """Refuse option values no command can use (before any file is read)."""
    for opt in ('max_gap', 'min_hold', 'window', 'still_factor', 'average',
                'temperature_timeout'):
        if getattr(args, opt, None) is not None:
            check_number(getattr(args, opt), '--' + opt.replace('_', '-'), 0.0, lo_open=True)
    if getattr(args, 'guard', None) is not None:
        check_number(args.guard, '--guard', 0.0)
    if getattr(args, 'chunk_size', None) is not None and args.chunk_size < 1:
        raise UserError(f'--chunk-size {args.chunk_size} must be >= 1')
    if getattr(args, 'range_margin', None) is not None:
        check_number(args.range_margin, '--range-margin (degC)', *RANGE_MARGIN_RANGE)
    if getattr(args, 'high_order_margin', None) is not None:
        check_number(args.high_order_margin, '--high-order-margin (degC)', *RANGE_MARGIN_RANGE)
    if getattr(args, 'latitude', None) is not None:
        check_number(args.latitude, '--latitude (deg)', -90.0, 90.0)
    if getattr(args, 'altitude', None) is not None:
        check_number(args.altitude, '--altitude (m)', *ALTITUDE_RANGE)
    if getattr(args, 'gravity', None) is not None:
        check_number(args.gravity, '--gravity (m/s^2)')
    topic = getattr(args, 'output_topic', None)
    if topic is not None and not _TOPIC_RE.match(topic):
        raise UserError(f'--output-topic {topic!r} is not a valid ROS 2 topic name (letters, '
                        'digits and _ in /-separated tokens, not starting with a digit), e.g. '
                        '/imu/data_compensated')
    for opt in ('imu_topic',):
        t = getattr(args, opt, None)
        if t is not None and not t.strip():
            raise UserError(f'--{opt.replace("_", "-")} is empty; name a topic')


def same_file(a, b):
    """Return True when paths ``a`` and ``b`` are the same existing file or directory."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def check_distinct_inputs(paths):
    """Refuse the same log given twice (its windows would be merged twice)."""
    for i, a in enumerate(paths):
        for b in paths[:i]:
            if os.path.exists(a) and same_file(a, b) or (
                    os.path.basename(a) == 'metadata.yaml' and same_file(os.path.dirname(a), b)):
                raise UserError(f'{a} is given twice (same log as {b}); its data would be '
                                'counted twice: give each log once')


def check_writable_dir(path, what):
    """Refuse an output whose directory cannot be created or written (before computing)."""
    output.check_writable_dir(path, what)


def calibrate_outputs(args):
    """Check every output of ``calibrate`` (-o, --save-windows and its .transitions.npz).

    Refused: any input log (a file, a bag directory or a file inside one), the --prior
    file, a directory, a special file, two outputs on one path, and an existing file that
    is not a calibration (or a window file) unless --force. Returns the ``Outputs``.
    """
    out = output.Outputs(list(args.inputs) + [args.prior], args.force)
    out.file(args.output, '-o', 'calibration file', output.CALIBRATION)
    if args.save_windows:
        out.file(args.save_windows, '--save-windows', 'window file (JSON lines)',
                 WINDOW_MARKERS)
        out.file(args.save_windows + TRANSITIONS_SUFFIX, '--save-windows', 'transitions file',
                 output.NPZ)
    return out


#: first bytes of the files ``calibrate --save-windows`` writes
WINDOW_MARKERS = (b'{"hold"',)


def validated(cal, output):
    """Return ``cal`` re-read by the loader the nodes use; UserError when it would be refused."""
    try:
        Calibration.from_yaml(cal.to_yaml(), 'the new calibration')
    except CalibrationError as e:
        raise UserError(f'{e}; nothing was written to {output}: the input data cannot '
                        'support a usable calibration (see the warnings above)') from None
    return cal


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so partial outputs are removed on the way out."""


def install_signals():
    """Make SIGINT and SIGTERM recorded, then raised; main thread only.

    SIGTERM unwinds like Ctrl-C (Terminated), so temporary outputs are removed. The record
    (``output.note_interrupt``) keeps an interruption whose exception Python swallowed
    (raised inside a clean-up callback) from committing an output or exiting 0; such a
    swallowed interruption prints no "Exception ignored" traceback.
    """
    output.reset_interrupts()

    def handler(signum, frame):
        output.note_interrupt(signum)
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN or sig == signal.SIGTERM:
                signal.signal(sig, handler)
    except ValueError:      # not the main thread (e.g. called from a test thread)
        return
    if not getattr(sys.unraisablehook, 'quiet_on_interrupt', False):
        default = sys.unraisablehook

        def unraisable(info):
            if not (isinstance(info.exc_value, KeyboardInterrupt) and output.interrupt()):
                default(info)
        unraisable.quiet_on_interrupt = True
        sys.unraisablehook = unraisable


def interrupted_status(exc=None):
    """Return (word, exit status) for a recorded interruption, or None.

    Without a record, ``exc`` (a KeyboardInterrupt that reached ``main``) says which signal
    it was: Terminated is SIGTERM, anything else SIGINT.
    """
    sig = output.interrupt()
    if sig is None and exc is not None:
        sig = signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT
    if sig is None:
        return None
    return ('terminated', 143) if sig == signal.SIGTERM else ('interrupted', 130)
