"""Fleet inputs: expand globs, directories and manifests into logs; name each log's sensor.

A log is a bare ``.mcap`` / ``.db3`` file or a rosbag2 directory (one with
``metadata.yaml``). A directory INPUT is searched recursively; a regular file that is not
a log is a manifest: one INPUT per line (glob, directory or log; ``#`` starts a comment;
relative paths are relative to the manifest). No ROS import.
"""

from dataclasses import dataclass
import glob
import os
import re

import yaml

LOG_SUFFIXES = ('.mcap', '.db3')
GROUP_KINDS = ('frame_id', 'topic', 'metadata', 'path')


class FleetInputError(ValueError):
    """An INPUT or a --by rule that cannot be used; the message says what to do."""


def _is_bag_dir(path):
    return os.path.isdir(path) and os.path.isfile(os.path.join(path, 'metadata.yaml'))


def _walk(root):
    """Yield the logs under directory ``root`` (rosbag2 dirs are not entered)."""
    if _is_bag_dir(root):
        yield root
        return
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        bags = [d for d in dirnames if _is_bag_dir(os.path.join(dirpath, d))]
        for d in bags:
            yield os.path.join(dirpath, d)
        dirnames[:] = [d for d in dirnames if d not in bags and not d.startswith('.')]
        for name in sorted(filenames):
            if name.endswith(LOG_SUFFIXES) and not name.startswith('.'):
                yield os.path.join(dirpath, name)


def _expand(item, base, seen_manifests):
    path = item if os.path.isabs(item) else os.path.join(base, item)
    if glob.has_magic(path):
        matches = sorted(glob.glob(path, recursive=True))
        if not matches:
            raise FleetInputError(f'{item}: the pattern matches nothing; check the path '
                                  '(quote it so the shell does not expand it)')
        for m in matches:
            yield from _expand(m, base, seen_manifests)
        return
    if os.path.isdir(path):
        yield from _walk(path)
    elif path.endswith(LOG_SUFFIXES):
        if not os.path.isfile(path):
            raise FleetInputError(f'{item}: no such log')
        yield path
    elif os.path.basename(path) == 'metadata.yaml':
        yield os.path.dirname(path) or '.'
    elif os.path.isfile(path):
        yield from read_manifest(path, seen_manifests)
    else:
        raise FleetInputError(f'{item}: no such file, directory or pattern')


def read_manifest(path, seen=None):
    """Yield the logs a manifest lists (one INPUT per line, ``#`` comments)."""
    seen = set() if seen is None else seen
    real = os.path.realpath(path)
    if real in seen:
        raise FleetInputError(f'{path}: the manifest includes itself')
    seen.add(real)
    try:
        with open(path, encoding='utf-8') as f:
            lines = f.read().splitlines()
    except UnicodeDecodeError:
        raise FleetInputError(f'{path}: neither a log (.mcap, .db3, rosbag2 directory) nor a '
                              'text manifest (one path or glob per line)') from None
    base = os.path.dirname(os.path.abspath(path))
    for line in lines:
        item = line.split('#', 1)[0].strip()
        if item:
            yield from _expand(item, base, seen)


def expand_inputs(inputs):
    """Return the sorted, de-duplicated log paths named by INPUT globs, dirs and manifests."""
    out, seen = [], set()
    for item in inputs:
        for p in _expand(item, os.getcwd(), set()):
            key = os.path.realpath(p)
            if key not in seen:
                seen.add(key)
                out.append(os.path.normpath(p))
    if not out:
        raise FleetInputError(f'no logs found in {" ".join(inputs)}; pass .mcap/.db3 files, '
                              'rosbag2 directories, directories holding them, or a manifest')
    return sorted(out)


def common_root(paths):
    """Return the directory the outputs mirror: the deepest common parent of ``paths``."""
    parents = [os.path.dirname(os.path.abspath(p)) for p in paths]
    return os.path.commonpath(parents) if parents else os.getcwd()


@dataclass(frozen=True)
class GroupBy:
    """How a log's sensor id is found: ``frame_id``, ``topic``, ``metadata:KEY``, ``path:RE``.

    ``frame_id`` is the IMU header frame_id, ``topic`` the IMU topic, ``metadata:KEY`` the
    value of KEY in the rosbag2 ``custom_data`` (metadata.yaml) or an MCAP metadata record,
    ``path:REGEX`` the first group (else the whole match) of REGEX searched in the path.
    """

    kind: str
    arg: str = ''

    @staticmethod
    def parse(text):
        """Parse a --by value; raises FleetInputError saying the accepted forms."""
        kind, _, arg = text.partition(':')
        if kind not in GROUP_KINDS or (kind in ('metadata', 'path')) != bool(arg):
            raise FleetInputError(f'--by {text!r}: use frame_id, topic, metadata:KEY or '
                                  'path:REGEX')
        if kind == 'path':
            try:
                re.compile(arg)
            except re.error as e:
                raise FleetInputError(f'--by {text!r}: bad regular expression ({e})') from None
        return GroupBy(kind, arg)

    def __str__(self):
        return self.kind + (f':{self.arg}' if self.arg else '')

    def sensor_id(self, path, frame_id='', imu_topic=''):
        """Return the sensor id of a log, exactly as found (ValueError with the reason if none).

        Ids are kept as they are (``robot/imu`` and ``robot_imu`` are two units); the
        registry stores each under its reversible key (``registry.key``), which also bounds
        the length: a longer id is refused for its log only.
        """
        if self.kind == 'frame_id':
            value = frame_id
        elif self.kind == 'topic':
            value = imu_topic
        elif self.kind == 'path':
            m = re.search(self.arg, os.fspath(path))
            value = (m.group(1) if m and m.groups() else m.group(0)) if m else ''
        else:
            value = log_metadata(path).get(self.arg, '')
        value = str(value or '')
        if not value.strip():
            raise ValueError(f'no sensor id from --by {self}: the log has an empty or no '
                             f'{self.kind}{" " + self.arg if self.arg else ""}')
        from .registry import key
        key(value)      # a unit id must have a registry key (length, UTF-8): else refused
        return value


def log_metadata(path):
    """Return the custom metadata of a log as a str -> str dict (empty when none)."""
    path = os.fspath(path)
    if os.path.isdir(path):
        with open(os.path.join(path, 'metadata.yaml')) as f:
            info = (yaml.safe_load(f) or {}).get('rosbag2_bagfile_information', {})
        return {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    if path.endswith('.mcap'):
        from mcap.reader import make_reader
        out = {}
        with open(path, 'rb') as f:
            for record in make_reader(f).iter_metadata():
                out.update({str(k): str(v) for k, v in record.metadata.items()})
        return out
    return {}
