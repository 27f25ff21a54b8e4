"""The command-line adapter: ``thermal-imu-calib`` and its subcommands.

Modules: ``entry`` (the console script), ``commands`` (the parser and the subcommands that
work on one log), ``calibrate`` (the calibrate options and their checks), ``checks`` (input,
output and option checks shared by every subcommand), ``export``, ``fleet`` and ``format``
(the text a person reads). Each subcommand parses, calls one use case of ``app`` and
formats the answer; ``python -m thermal_imu_calib.cli`` runs it as the console script does.

Importing this package loads nothing else, so the console script can limit BLAS threads
before numpy is imported (``entry``); ``main`` and the other names load ``commands`` on use.
"""

_LAZY = ('build_parser', 'cmd_calibrate', 'COMMANDS', 'EXIT_USAGE')


def main(argv=None):
    """Run ``thermal-imu-calib`` on ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    from .commands import main as run
    return run(argv)


def __getattr__(name):
    if name in _LAZY:
        from . import commands
        return getattr(commands, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
