"""The one output writer: every file the package writes is checked first, then written atomically.

``Outputs`` holds the inputs and the outputs of one command and checks each output before
anything is computed (``OutputError``, a ``ValueError``: one line, exit 2 in the CLI):

* an output is never an input of the same command: not the same file, not inside an input
  directory (a rosbag2 directory, a registry), not a bag's ``metadata.yaml``;
* two outputs of one command never share a path (derived names such as
  ``FILE.transitions.npz`` included);
* a special file (named pipe, device, socket) is never written, nor a directory where a
  file goes;
* an existing file is replaced only when it is of the output's own kind (a calibration by a
  calibration, an HTML page by an HTML page: told by its first bytes), or with ``force``;
  logs (``replace=False``) are never replaced;
* the directory can be created and written.

``write_atomic`` writes a unique temporary file beside the target (``tempfile.mkstemp``:
never a fixed name such as ``OUT.tmp`` that could be someone's file) and renames it onto
the target, so the target is either the old file or the complete new one; ``staging_dir``
does the same for outputs that are directories or written by a library (rosbag2, MCAP).
Neither renames after an interruption was recorded (``note_interrupt``), even one whose
KeyboardInterrupt Python swallowed (raised inside a clean-up callback). No ROS import.
"""

from contextlib import contextmanager
import os
import shutil
import signal
import stat
import tempfile
import threading

#: bytes read from an existing file to tell its kind
SNIFF_BYTES = 65536
#: how files of a few kinds the package writes are told (``Outputs.file`` ``own``)
HTML = (b'<!doctype html', b'<html')
PNG = (b'\x89PNG\r\n\x1a\n',)
NPZ = (b'PK\x03\x04',)

_SPECIAL = ((stat.S_ISFIFO, 'a named pipe'), (stat.S_ISCHR, 'a character device'),
            (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket'))


class OutputError(ValueError):
    """An output that would destroy something or cannot be written; the text says what to do."""


class Interrupted(KeyboardInterrupt):
    """A recorded SIGINT/SIGTERM raised again before an output is committed (``signum``)."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


#: signals recorded by the process's handlers (the CLI's); never cleared but by ``reset``
_INTERRUPTS = []


def note_interrupt(signum):
    """Record that ``signum`` (SIGINT/SIGTERM) arrived: no output is committed after it."""
    _INTERRUPTS.append(signum)


def interrupt():
    """Return the first recorded signal number, or None."""
    return _INTERRUPTS[0] if _INTERRUPTS else None


def reset_interrupts():
    """Forget recorded signals (a new command in the same process)."""
    _INTERRUPTS.clear()


def _raise_if_interrupted():
    """Raise Interrupted when a signal was recorded: its KeyboardInterrupt may have been lost.

    Python delivers a signal's exception at the next bytecode; when that is inside a
    callback (a weakref callback of the import lock, a ``__del__``), the exception is
    reported as "ignored" and the program carries on. The record is what stops the commit.
    """
    if _INTERRUPTS:
        raise Interrupted(_INTERRUPTS[0])


def free_name(base, suffixes=()):
    """Return ``base``, or ``base-N`` (N = 1, 2, ...), whose name and ``name + suffix`` are free.

    For renaming files aside without replacing an earlier one of the same second
    (``os.replace`` overwrites a file silently).
    """
    name, n = base, 0
    while any(os.path.lexists(name + s) for s in ('',) + tuple(suffixes)):
        n += 1
        name = f'{base}-{n}'
    return name


def shown(path):
    """Return ``path`` printable on any terminal (bytes that are not UTF-8 escaped)."""
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    return text.encode('utf-8', 'surrogateescape').decode('utf-8', 'backslashreplace')


def special_kind(path):
    """Return 'a named pipe' etc. when ``path`` (links followed) is a special file, else None."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, what in _SPECIAL:
        if test(mode):
            return what
    return None


def _real(path):
    return os.path.realpath(os.path.abspath(os.fspath(path)))


def _head(path):
    try:
        with open(path, 'rb') as f:
            return f.read(SNIFF_BYTES)
    except OSError:
        return b''


def has_marker(path, markers):
    """Return True when file ``path`` starts with one of ``markers`` (bytes prefixes).

    Leading white space is skipped and the case ignored for text prefixes (``<!DOCTYPE``).
    """
    head = _head(path)
    low = head.lstrip().lower()
    return any(head.startswith(m) or low.startswith(m.lower()) for m in markers)


def containing(marker):
    """Return a predicate: the first ``SNIFF_BYTES`` of a file hold ``marker`` (bytes)."""
    return lambda path: marker in _head(path)


CALIBRATION = containing(b'format: thermal_imu_calib/')


def check_writable_dir(path, what):
    """Refuse an output whose directory cannot be created or written (before computing)."""
    d = os.path.dirname(os.path.abspath(path))
    probe = d
    while not os.path.lexists(probe):
        parent = os.path.dirname(probe)
        if parent == probe:
            break
        probe = parent
    if not os.path.isdir(probe):
        raise OutputError(f'{what} {shown(path)}: {shown(probe)} is not a directory; choose '
                          'another path')
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as e:
        raise OutputError(f'{what} {shown(path)}: directory {shown(probe)} is not writable '
                          f'({e.strerror or e}); choose another path or fix its '
                          'permissions') from None


class Outputs:
    """The inputs and outputs of one command; ``file``/``log``/``directory`` check each output.

    ``inputs`` are paths the command reads (files or directories; a bag's metadata.yaml or
    storage file stands for its directory too). ``force`` allows replacing an existing file
    of another kind. Checks cost O(path depth) per output, so thousands of fleet outputs
    against thousands of inputs stay cheap.
    """

    def __init__(self, inputs=(), force=False):
        self.inputs = []
        self.force = force
        self._ids = {}              # (st_dev, st_ino) -> input path
        self._reals = {}            # resolved path -> input path
        self._outputs = {}          # resolved path -> (option, path as given)
        self.add_inputs(*inputs)

    def add_inputs(self, *paths):
        """Add paths the command reads (None and '' are skipped)."""
        for p in paths:
            if p is None or p == '':
                continue
            p = os.fspath(p)
            self._add_input(p)
            parent = os.path.dirname(os.path.abspath(p))
            if os.path.isfile(os.path.join(parent, 'metadata.yaml')) and not os.path.isdir(p):
                self._add_input(parent)   # a bag's metadata.yaml or storage file: the bag

    def _add_input(self, p):
        self.inputs.append(p)
        self._reals.setdefault(_real(p), p)
        try:
            st = os.stat(p)
            self._ids.setdefault((st.st_dev, st.st_ino), p)
        except OSError:
            pass

    def _input_hit(self, path):
        """Return (input, True when it is the same file) for an output that hits an input."""
        try:
            st = os.stat(path)
            if (st.st_dev, st.st_ino) in self._ids:
                return self._ids[(st.st_dev, st.st_ino)], True
        except OSError:
            pass
        real = _real(path)
        if real in self._reals:
            return self._reals[real], True
        parent = os.path.dirname(real)
        while True:
            if parent in self._reals and os.path.isdir(parent):
                return self._reals[parent], False
            up = os.path.dirname(parent)
            if up == parent:
                return None, False
            parent = up

    def _check_common(self, path, option):
        if path is None or os.fspath(path) == '':
            raise OutputError(f'{option}: empty path; give a file name')
        path = os.fspath(path)
        what = special_kind(path)
        if what:
            raise OutputError(f'{option} {shown(path)} is {what}, not a regular file; '
                              'nothing is written to special files: choose a file name')
        src, same = self._input_hit(path)
        if src is not None:
            where = 'one of the inputs' if same else f'inside {shown(src)}, one of the inputs'
            raise OutputError(f'{option} {shown(path)} is {where}'
                              + (f' ({shown(src)})' if same else '')
                              + '; writing it would destroy the input: choose an output '
                              'outside every input')
        real = _real(path)
        if real in self._outputs:
            other_option, other_path = self._outputs[real]
            raise OutputError(f'{option} {shown(path)} is also where {other_option} '
                              f'writes ({shown(other_path)}); one would replace the '
                              'other: give each output its own path')
        self._outputs[real] = (option, path)
        return path

    def file(self, path, option, kind, own=(), replace=True):
        """Check a file output and return it.

        ``kind`` names it in messages ('calibration file', 'HTML page'); ``own`` are the
        prefixes (see ``has_marker``) or a predicate ``path -> bool`` telling an existing
        file of this kind, which is replaced; another existing file needs ``force``.
        ``replace=False`` (logs): an existing output is always refused.
        """
        path = self._check_common(path, option)
        if os.path.isdir(path):
            raise OutputError(f'{option} {shown(path)} is a directory; give a file name (e.g. '
                              f'{shown(os.path.join(path, "out"))})')
        if os.path.lexists(path):
            if not replace:
                raise OutputError(f'{option} {shown(path)} exists; remove it or choose another '
                                  'output')
            mine = own(path) if callable(own) else has_marker(path, own)
            if not mine and not self.force:
                raise OutputError(f'{option} {shown(path)} exists and is not a {kind}; refusing '
                                  'to overwrite it: choose another output, or pass --force')
        check_writable_dir(path, option)
        return path

    def log(self, path, option):
        """Check a log output (a .mcap file or a rosbag2 directory): never replaces anything."""
        path = self._check_common(path, option)
        if os.path.lexists(path):
            raise OutputError(f'{option} {shown(path)} exists; remove it or choose another '
                              'output')
        check_writable_dir(path, option)
        return path

    def directory(self, path, option, kind):
        """Check a directory the command writes files into (its files get ``file``)."""
        path = self._check_common(path, option)
        if os.path.lexists(path) and not os.path.isdir(path):
            raise OutputError(f'{option} {shown(path)} exists and is not a directory; choose '
                              f'a directory for the {kind}')
        check_writable_dir(os.path.join(path, 'x'), option)
        return path


def _mode():
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def _final_target(path):
    """Return where ``path`` writes: a symlink's target (the link stays), else ``path``."""
    return os.path.realpath(path) if os.path.islink(path) else path


def write_atomic(path, data):
    """Write str/bytes ``data`` (or ``data(fileobj)`` writing bytes) to ``path`` atomically.

    A unique temporary file beside the target is written and renamed onto it; a special
    file or a directory at ``path`` is refused (OutputError), never replaced. Returns path.
    """
    path = os.fspath(path)
    target = _final_target(path)
    what = special_kind(target)
    if what or os.path.isdir(target):
        raise OutputError(f'{shown(path)} is {what or "a directory"}; nothing was written: '
                          'choose a regular file name')
    d = os.path.dirname(os.path.abspath(target))
    os.makedirs(d, exist_ok=True)
    tmp = None
    try:
        with _signals_held():
            fd, tmp = tempfile.mkstemp(prefix=f'.{os.path.basename(target)[:80]}.',
                                       suffix='.partial', dir=d)
        with os.fdopen(fd, 'wb') as f:
            if callable(data):
                data(f)
            else:
                f.write(data.encode('utf-8') if isinstance(data, str) else bytes(data))
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _mode())       # mkstemp makes 0600; outputs are not secret
        _raise_if_interrupted()
        os.replace(tmp, target)
    except BaseException:
        if tmp is not None:
            remove_quietly(tmp)
        raise
    return path


@contextmanager
def staging_dir(path):
    """Yield a temporary path beside ``path`` to write a file or directory at; rename on success.

    The temporary lives in a unique hidden directory (``.NAME.partial-XXXX``) next to the
    target, under the target's own name (rosbag2 names its storage files after the bag
    directory). On success it is renamed onto ``path`` (refused if ``path`` appeared
    meanwhile); on any error or interruption it is removed, so ``path`` is complete or
    absent.
    """
    path = os.path.abspath(os.fspath(path).rstrip(os.sep) or os.sep)
    d = os.path.dirname(path)
    os.makedirs(d, exist_ok=True)
    holder = None
    try:
        with _signals_held():
            holder = tempfile.mkdtemp(prefix=f'.{os.path.basename(path)[:80]}.partial-',
                                      dir=d)
        tmp = os.path.join(holder, os.path.basename(path))
        yield tmp
        _raise_if_interrupted()
        if os.path.lexists(path):
            raise OutputError(f'{shown(path)} appeared while it was being written; nothing '
                              'was replaced: remove it or choose another output')
        os.rename(tmp, path)
    finally:
        if holder is not None:
            remove_quietly(holder)


@contextmanager
def _signals_held():
    """Hold SIGINT and SIGTERM while a temporary is created and its name is taken.

    An interruption between the ``mkdtemp``/``mkstemp`` system call and the assignment of
    its result (the moment a watcher sees the temporary appear) would leave it behind; held
    there, the signal is delivered once the name is assigned, inside the caller's ``try``
    whose clean-up removes it.
    """
    held = (signal.SIGINT, signal.SIGTERM)
    main = threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held) if main else None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def remove_quietly(path):
    """Remove a temporary file or directory; errors are ignored (best effort on the way out)."""
    try:
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        elif os.path.lexists(path):
            os.unlink(path)
    except OSError:
        pass
