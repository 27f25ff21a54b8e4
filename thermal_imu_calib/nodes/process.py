"""How a node process starts and ends: one line on a bad start, exit 0 on SIGINT/SIGTERM.

``run_nodes`` is what every node executable's ``main`` runs (see its docstring for what a
user gets); the helpers warn about parameters given but never declared and about keys given
twice in a params file.
"""

import sys

from rclpy.executors import SingleThreadedExecutor

#: longest wait of one executor turn (s): how soon a recorded signal is acted on when
#: nothing else wakes the executor
SPIN_PERIOD_S = 0.2

#: longest middleware teardown (s) before the process ends without it. Fast DDS 2.14.5 can
#: deadlock deleting a participant while discovery traffic arrives (main thread in
#: ``DomainParticipant::set_listener``, a receive thread in ``onWriterDiscovery`` waiting
#: for the participant's mutex; once in CI, and 4 times in ~2,200 compensators signalled ten
#: at a time under load in a repro). Below ``ros2 launch``'s 5-s SIGINT -> SIGTERM escalation.
TEARDOWN_LIMIT_S = 4.0

#: how much later than ``TEARDOWN_LIMIT_S`` (s) the guard's native timers act when the
#: hanging teardown holds the Python interpreter lock (rclpy's ``destroy_node`` does: CI stop
#: 36, one compensator of 20 never exited although the Python guard was armed): first a dump
#: of every thread's Python stack (``faulthandler``), then the exit. Still below 5 s.
NATIVE_DUMP_AFTER_S, NATIVE_EXIT_AFTER_S = 0.25, 0.5


def run_nodes(factories, args=None):
    """Create nodes from ``factories`` and spin them on one SingleThreadedExecutor.

    The Jazzy idiom of ros2/demos: init, spin until Ctrl-C or external shutdown, then
    destroy every node created and shut down. Why single-threaded: see ``common.drain``. What a
    user gets (exit status 0 on SIGINT/SIGTERM, 2 on a bad start):

    * on the way out every node's ``finish`` (its own files, its workers) runs before any
      node is destroyed; a middleware teardown that outlasts ``TEARDOWN_LIMIT_S`` then ends
      the process anyway, with one warning line (``teardown_guard``);
    * a parameter that cannot be used, or any other failure to start, is one line on
      stderr and exit status 2 (``THERMAL_IMU_CALIB_DEBUG=1`` shows the traceback);
    * a parameter given for the node (params file or command line) that it does not have,
      and a key given twice in a params file, are warned about by name;
    * SIGINT or SIGTERM while data flows ends with exit status 0 and no traceback: rclpy
      shuts the context down, and a callback caught mid-publish by that (``RCLError:
      publisher's context is invalid``) is the shutdown, not a failure.
    Returns the exit status (0 or 2); ``main`` passes it to ``sys.exit``.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    nodes, status = [], 0
    argv = sys.argv if args is None else args
    signalled = _note_signals()     # no KeyboardInterrupt anywhere: rclpy's handler (which
    try:                            # chains to this one) shuts the context down instead
        rclpy.init(args=args)
    except Exception as e:  # noqa: B902 - e.g. a params file that does not parse
        return _start_failed(_factory_name(factories[0]), e)
    try:
        try:
            for make in factories:
                if signalled or not rclpy.ok():
                    return 0        # stopped while starting
                nodes.append(make())
        except Exception as e:  # noqa: B902 - bad parameters and the like: one line
            if signalled or not rclpy.ok():
                return 0            # stopped while starting
            status = _start_failed(_factory_name(make), e)    # the teardown guard keeps it
            return status
        if signalled:
            return 0
        for path, text in duplicate_keys(params_files(argv)):
            nodes[0].get_logger().warning(f'params file {path}: {text}')
        for node in nodes:
            warn_unknown_parameters(node)
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        # spin_once with a timeout, not spin(): a recorded SIGINT/SIGTERM ends the loop even
        # if rclpy's own handler has not shut the context down yet (seen once in 20 under
        # heavy load: a process signalled while compensating never left spin())
        while rclpy.ok() and not signalled:
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: B902 - re-raised unless it is the shutdown itself
        if rclpy.ok():
            status = 1             # an error on its way up: the teardown guard keeps it
            raise
    finally:
        _ignore_signals()          # a second Ctrl-C must not interrupt the cleanup
        for node in nodes:         # the nodes' own work first (state files, workers) ...
            try:
                getattr(node, 'finish', lambda: None)()
            except Exception:  # noqa: B902 - best effort on the way out
                pass
        guard = teardown_guard(' + '.join(_factory_name(f) for f in factories), status)
        for node in nodes:         # ... then the middleware's, which can hang
            try:
                node.destroy_node()
            except Exception:  # noqa: B902 - best effort on the way out
                pass
        rclpy.try_shutdown()
        guard.cancel()
    return 0


def teardown_guard(name, status, limit_s=None):
    """Arm and return the guard that ends the process if teardown outlasts ``limit_s``.

    Start it once the nodes' own work is done (``finish``): what is then left is rclpy's and
    the middleware's. On time-out a Python timer prints one warning line and ends the
    process with ``status`` (0 for a requested stop). A hang inside rclpy's C code can hold
    the interpreter lock, so that no Python thread ever runs again; for that case two native
    timers, which need no Python, follow: ``faulthandler`` dumps every thread's stack to
    stderr (where it hung, for a bug report) and ``native_exit_timer`` ends the process with
    ``status``. ``cancel()`` the guard when the teardown has finished. ``limit_s`` defaults
    to ``TEARDOWN_LIMIT_S``.
    """
    import faulthandler
    import threading
    limit = TEARDOWN_LIMIT_S if limit_s is None else float(limit_s)

    def overdue():
        print(f'{name}: warning: the middleware did not finish shutting down within '
              f'{limit:g} s (a DDS teardown hang); exiting without it', file=sys.stderr)
        exit_process(status)

    timer = threading.Timer(limit, overdue)
    timer.daemon = True
    _flush_std_streams()                        # _exit from a native thread flushes nothing
    dumping = False
    try:
        faulthandler.dump_traceback_later(limit + NATIVE_DUMP_AFTER_S, file=sys.stderr)
        dumping = True
    except (OSError, ValueError, AttributeError, RuntimeError):  # no usable stderr
        pass
    native = native_exit_timer(limit + NATIVE_EXIT_AFTER_S, status)
    timer.start()
    return _Guard(timer, native, dumping)


class _Guard:
    """The armed teardown guard: ``cancel()`` disarms its three timers."""

    def __init__(self, timer, native, dumping):
        self._timer, self._native, self._dumping = timer, native, dumping

    def cancel(self):
        """Disarm: the teardown finished in time."""
        import faulthandler
        self._timer.cancel()
        if self._native is not None:
            self._native()
        if self._dumping:
            faulthandler.cancel_dump_traceback_later()


def native_exit_timer(delay_s, status):
    """Arm a POSIX timer that calls ``_exit(status)`` after ``delay_s`` s; return its disarm.

    The timer (``timer_create`` with ``SIGEV_THREAD``) runs ``_exit`` on a new native thread,
    so it works while another thread holds the Python interpreter lock forever. Linux/glibc
    only: elsewhere (no ``timer_create``) it returns None and the Python timer is the guard.
    The disarm function deletes the timer; call it at most once.
    """
    import ctypes

    class SigEvent(ctypes.Structure):      # glibc's struct sigevent (64 bytes)
        _fields_ = [('value', ctypes.c_void_p), ('signo', ctypes.c_int),
                    ('notify', ctypes.c_int), ('function', ctypes.c_void_p),
                    ('attribute', ctypes.c_void_p), ('pad', ctypes.c_int * 8)]

    class TimeSpec(ctypes.Structure):
        _fields_ = [('sec', ctypes.c_long), ('nsec', ctypes.c_long)]

    sigev_thread, clock_monotonic = 2, 1
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        create, settime, delete = libc.timer_create, libc.timer_settime, libc.timer_delete
        exit_fn = ctypes.cast(libc._exit, ctypes.c_void_p).value
    except (OSError, AttributeError):
        return None
    if ctypes.sizeof(SigEvent) != 64:
        return None
    # the notify function gets the union sigval by value: an int in the first argument
    # register, which is what _exit(int) reads
    event = SigEvent(value=int(status) or None, notify=sigev_thread, function=exit_fn)
    timer_id = ctypes.c_void_p()
    if create(clock_monotonic, ctypes.byref(event), ctypes.byref(timer_id)) != 0:
        return None
    whole = int(delay_s)
    spec = (TimeSpec * 2)(TimeSpec(0, 0), TimeSpec(whole, int((delay_s - whole) * 1e9)))
    if settime(timer_id, 0, ctypes.byref(spec), None) != 0:
        delete(timer_id)
        return None
    return lambda: delete(timer_id)


def _factory_name(make):
    return getattr(sys.modules.get(getattr(make, '__module__', '')), 'NODE_NAME',
                   getattr(make, '__name__', 'node'))


def _start_failed(name, err):
    """Print why a node could not start, in one line; return exit status 2."""
    import os
    if os.environ.get('THERMAL_IMU_CALIB_DEBUG'):
        import traceback
        traceback.print_exception(err)
    text = ' '.join(str(err).split()) or type(err).__name__
    if type(err).__name__ not in ('ValueError',) and not text.startswith('parameter'):
        text = f'{type(err).__name__}: {text}'
    print(f'{name}: error: {text[:1000]}; fix the parameter (or argument) and start again',
          file=sys.stderr)
    return 2


def _note_signals():
    """Make SIGINT and SIGTERM only recorded (returned list), never raised; main thread only."""
    import signal
    got = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, lambda signum, frame: got.append(signum))
        except (ValueError, OSError):     # not the main thread
            pass
    return got


def _ignore_signals():
    import signal
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):     # not the main thread
            pass


def warn_unknown_parameters(node):
    """Warn, by name, about parameters given for ``node`` that it does not declare.

    rclpy silently ignores them (a misspelled ``temperature_timout`` in a params file would
    otherwise leave the default in place unnoticed); the closest declared name is offered.
    """
    import difflib
    declared = set(node._parameters)
    unknown = sorted(n for n in getattr(node, '_parameter_overrides', {})
                     if n not in declared and not n.startswith('qos_overrides.'))
    for name in unknown:
        close = difflib.get_close_matches(name, sorted(declared), 1)
        node.get_logger().warning(
            f'parameter {name!r} is not a parameter of {node.get_name()}: ignored'
            + (f' (did you mean {close[0]!r}?)' if close else
               f'; its parameters: {", ".join(sorted(declared))}'))
    return unknown


def params_files(argv):
    """Return the ``--params-file`` paths of a ROS command line (after ``--ros-args``)."""
    out, ros = [], False
    argv = list(argv or [])
    for i, a in enumerate(argv):
        if a == '--ros-args':
            ros = True
        elif a == '--':
            ros = False
        elif ros and a == '--params-file' and i + 1 < len(argv):
            out.append(argv[i + 1])
    return out


def duplicate_keys(paths):
    """Yield (path, text) for every mapping key given twice in the YAML files ``paths``.

    rcl keeps one of the two silently; a duplicated node section or parameter is almost
    always an edit gone wrong. Unreadable files are skipped (rcl reports them).
    """
    import yaml
    for path in paths:
        try:
            with open(path, encoding='utf-8') as f:
                root = yaml.compose(f, Loader=yaml.SafeLoader)
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        stack = [(root, '')]
        while stack:
            node, where = stack.pop()
            if isinstance(node, yaml.MappingNode):
                seen = {}
                for k, v in node.value:
                    name = k.value if isinstance(k, yaml.ScalarNode) else str(k.value)
                    full = f'{where}.{name}' if where else name
                    if name in seen:
                        yield path, (f'key {full!r} is given twice (lines {seen[name]} and '
                                     f'{k.start_mark.line + 1}); one of them is ignored: '
                                     'keep one')
                    seen.setdefault(name, k.start_mark.line + 1)
                    stack.append((v, full))
            elif isinstance(node, yaml.SequenceNode):
                stack.extend((v, where) for v in node.value)


def exit_process(code):
    """End the process with ``code`` after ``run_nodes``, without waiting for worker threads.

    An estimation still running on the calibrator's worker thread (or a report child) is
    abandoned, not awaited: Python would otherwise join the thread at exit, so a SIGTERM
    during ~/calibrate would hang until the estimation ended. Its outputs are written
    atomically, so nothing half-written is left at a final name.
    """
    import os
    _flush_std_streams()
    os._exit(code)


def _flush_std_streams():
    """Flush stdout and stderr (best effort: a closed or broken stream is skipped)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
