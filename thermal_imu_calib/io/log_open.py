"""What a log path is, before it is read and when reading it fails.

``locate_log`` finds the format from the path (a rosbag2 directory with metadata.yaml, a
bare ``.mcap`` or ``.db3`` file) and refuses anything else with what to do; ``_with_wal``
makes a checkpointed private copy of a ``.db3`` whose last messages are still in its
write-ahead log; ``_explain_unreadable`` names the cause when a back end cannot open a log
for a known reason (metadata.yaml not UTF-8, an MCAP file cut short).
"""

from __future__ import annotations

import os
from pathlib import Path

from .log_info import _STORAGE_SUFFIXES, LogError


_MCAP_MAGIC = b'\x89MCAP0\r\n'


def _explain_unreadable(p: Path, kind: str, err: Exception) -> None:
    """Raise a LogError naming the cause when a log is unreadable for a known reason.

    Known: a non-UTF-8 metadata.yaml, and an MCAP file cut short (no end magic). Returns
    without raising otherwise.
    """
    if isinstance(err, UnicodeDecodeError) or 'codec can\'t decode' in str(err):
        name = p / 'metadata.yaml' if p.is_dir() else p
        raise LogError(f'{name}: cannot read it: not UTF-8 text ({err}); the {kind} is '
                       'damaged: restore metadata.yaml, or regenerate it with '
                       '`ros2 bag reindex`.') from None
    mcaps = ([p] if p.suffix == '.mcap' else
             sorted(p.glob('*.mcap')) if p.is_dir() else [])
    for f in mcaps:
        try:
            with open(f, 'rb') as fh:
                head = fh.read(8)
                size = fh.seek(0, 2)
                fh.seek(max(size - 8, 0))
                tail = fh.read(8)
        except OSError:
            continue
        if head != _MCAP_MAGIC:
            raise LogError(f'{f}: cannot read it: not an MCAP file (it does not start with the '
                           'MCAP magic bytes); is it the right file?') from None
        if tail != _MCAP_MAGIC:
            raise LogError(f'{f}: cannot read it: the MCAP file is truncated ({size} bytes, '
                           'no end magic: the recording was cut short or the copy is '
                           'incomplete); recover '
                           f'the complete messages with `mcap recover {f} -o recovered.mcap` '
                           '(mcap CLI) and use recovered.mcap.') from None


def _check_name(p: Path) -> None:
    """Refuse a path that is not UTF-8 text: the bag libraries cannot open it (not the data)."""
    try:
        str(p).encode('utf-8')
    except UnicodeEncodeError as e:
        bad = os.fsencode(str(p))[len(str(p)[:e.start].encode('utf-8', 'surrogateescape'))]
        shown = str(p).encode('utf-8', 'surrogateescape').decode('utf-8', 'backslashreplace')
        raise LogError(f'{shown}: the path is not UTF-8 text (byte 0x{bad:02x} at character '
                       f'{e.start}), which the log readers cannot open; the data was not read: '
                       'rename the file or directory to a UTF-8 name and try again') from None


def _with_wal(p: Path) -> tuple[Path, str]:
    """Return (path to read, note): a checkpointed private copy when a .db3 has a -wal part.

    rosbags opens SQLite ``immutable``, which ignores the write-ahead log, so a .db3 whose
    last messages are still in ``NAME.db3-wal`` (a recorder still running, or one that
    stopped without a checkpoint) would be read without them. The log (a bare .db3 or the
    whole bag directory) is copied with its WAL to a temporary directory, checkpointed
    there with sqlite3, and read from the copy; the original is never written. A log whose
    files change while they are copied is still being recorded: refused (LogError).
    """
    dbs = [p] if p.suffix == '.db3' else sorted(p.glob('*.db3')) if p.is_dir() else []
    wals = [Path(f'{d}-wal') for d in dbs if Path(f'{d}-wal').is_file()
            and Path(f'{d}-wal').stat().st_size > 0]
    if not wals:
        return p, ''
    import shutil
    import sqlite3
    import tempfile

    def state():
        return [(f.stat().st_size, f.stat().st_mtime_ns) for f in dbs + wals]
    before = state()
    tmp = Path(tempfile.mkdtemp(prefix='thermal-imu-calib-wal-'))
    try:
        dst = tmp / p.name
        if p.is_dir():
            shutil.copytree(p, dst, ignore=shutil.ignore_patterns('*-shm'))
        else:
            for f in [p] + [w for w in wals]:
                shutil.copy2(f, tmp / f.name)
        if state() != before:
            raise LogError(f'{p}: its SQLite files changed while being read: the log is still '
                           'being recorded; wait until the recording has stopped, then try '
                           'again')
        for d in ([dst] if not p.is_dir() else sorted(dst.glob('*.db3'))):
            con = sqlite3.connect(str(d))
            try:
                con.execute('PRAGMA wal_checkpoint(TRUNCATE)')
            finally:
                con.close()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    size = sum(w.stat().st_size for w in wals)
    names = ', '.join(w.name for w in wals)
    return dst, (f'with {size} bytes of its SQLite write-ahead log ({names}: the recorder was '
                 'still running or did not close the bag) included')


def locate_log(path) -> tuple[Path, str]:
    """Return (path to open, kind label) of a log; raise LogError when it is none.

    A ``metadata.yaml`` stands for its bag directory; a directory must hold one; a file
    must be ``.mcap`` or ``.db3``; the path must be UTF-8 text (``_check_name``).
    """
    p = Path(path).expanduser()
    if p.name == 'metadata.yaml' and p.is_file():
        p = p.parent
    _check_name(p)
    if not p.exists():
        raise LogError(f'{p}: no such file or directory; pass a rosbag2 directory, a .mcap '
                       'or a .db3 file.')
    if p.is_dir():
        if not (p / 'metadata.yaml').is_file():
            files = sorted(x.name for x in p.iterdir() if x.suffix in _STORAGE_SUFFIXES)
            hint = (f'open the storage file directly ({p / files[0]}) or run '
                    f'`ros2 bag reindex {p}`' if files else
                    'pass a rosbag2 directory, a .mcap or a .db3 file')
            raise LogError(f'{p}: directory has no metadata.yaml, so it is not a rosbag2 '
                           f'bag; {hint}.')
        kind = 'rosbag2 directory'
    elif p.suffix in _STORAGE_SUFFIXES:
        kind = f'{p.suffix[1:]} file'
    else:
        raise LogError(f'{p}: unknown log format {p.suffix or "(no suffix)"!r}; pass a '
                       'rosbag2 directory, a .mcap or a .db3 file (convert ROS 1 .bag '
                       'files with `rosbags-convert`).')
    return p, kind
