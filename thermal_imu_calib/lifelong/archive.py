"""Resetting a lifelong collection without losing data: move it into ``archive/<UTC time>/``.

Nothing is copied or deleted (``os.replace``); at most ``MAX_ARCHIVES`` archives. No ROS
import.
"""

import os
import time

#: archives a reset may leave in ``<lifelong_dir>/archive`` (each at most the store's bound,
#: ~12 MB): one more reset is refused until one is moved away or deleted
MAX_ARCHIVES = 5
ARCHIVE = 'archive'


class ArchiveFull(Exception):
    """A reset would make more than ``MAX_ARCHIVES`` archives (the message says what to do)."""


def archive_collection(directory, when=None, max_archives=MAX_ARCHIVES):
    """Move the hold store and the candidate of a lifelong directory aside; return the path.

    ``<directory>/holds/`` and ``candidate.yaml`` move (``os.replace``: nothing is copied or
    deleted) into ``<directory>/archive/<UTC time of when (s), default now>/``; the active
    calibration, ``state.json``, ``decisions.jsonl`` and the registry stay. Returns '' when
    there is nothing to move (no hold stored, no candidate). Raises ``ArchiveFull`` when
    ``max_archives`` archives exist already, ``OSError`` when the files cannot be moved.
    """
    directory = os.path.expanduser(directory)
    holds = os.path.join(directory, 'holds')
    stored = os.path.isdir(holds) and any(                # an empty store has empty files
        os.path.getsize(os.path.join(holds, n)) for n in os.listdir(holds))
    names = (['holds'] if stored else []) + (
        ['candidate.yaml'] if os.path.exists(os.path.join(directory, 'candidate.yaml')) else [])
    if not names:
        return ''
    root = os.path.join(directory, ARCHIVE)
    old = sorted(os.listdir(root)) if os.path.isdir(root) else []
    if len(old) >= max_archives:
        raise ArchiveFull(f'{root} holds {len(old)} archives of earlier resets already (at most '
                          f'{max_archives}, oldest {old[0]}): move or delete the ones no longer '
                          'needed, then reset again')
    when = time.time() if when is None else when
    label = time.strftime('%Y%m%dT%H%M%SZ', time.gmtime(when))
    dest, i = os.path.join(root, label), 1
    while os.path.exists(dest):                  # two resets within a second
        dest, i = os.path.join(root, f'{label}-{i}'), i + 1
    os.makedirs(dest)
    for n in names:
        os.replace(os.path.join(directory, n), os.path.join(dest, n))
    return dest
