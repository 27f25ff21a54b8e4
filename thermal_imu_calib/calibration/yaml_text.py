"""A calibration's YAML text before its schema: file, size, encoding, nesting, aliases.

Everything here runs before anything walks the document, so a hostile file (an alias
bomb, 100,000 nested ``[``, 5 MB of text, Latin-1 bytes) is refused in milliseconds.
"""

import os

import yaml

from .base import CalibrationError, MAX_DEPTH, MAX_FILE_BYTES, MAX_NODES, type_name

_SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def read_file(path):
    """Return the bytes of a calibration file; CalibrationError naming it otherwise."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise CalibrationError(f'calibration file {path!r} is a directory; pass the '
                               'calibration YAML file')
    if not os.path.isfile(path):
        raise CalibrationError(f'calibration file {path!r} does not exist; create one with '
                               '`thermal-imu-calib calibrate ... -o FILE`')
    try:
        size = os.path.getsize(path)
        if size > MAX_FILE_BYTES:
            raise CalibrationError(f'{path}: {size} bytes is too large for a calibration '
                                   f'file (limit {MAX_FILE_BYTES}); is it the right file?')
        with open(path, 'rb') as f:
            return f.read(MAX_FILE_BYTES + 1)
    except OSError as e:
        raise CalibrationError(f'cannot read calibration file {path!r}: '
                               f'{e.strerror or e}') from None


def parse_yaml(text, source):
    """Return the document of YAML text (str or UTF-8 bytes) within the limits."""
    text = decode_text(text, source)
    check_yaml_shape(text, source)
    try:
        return yaml.load(text, Loader=_SAFE_LOADER)
    except yaml.YAMLError as e:
        raise CalibrationError(f'{source}: not valid YAML ({e.__class__.__name__}: '
                               f'{str(e).splitlines()[0]})') from None
    except Exception as e:  # noqa: B902 - e.g. an unhashable key: still a bad file
        raise CalibrationError(f'{source}: not a usable YAML document '
                               f'({e.__class__.__name__}: {e})') from None


def decode_text(text, source):
    """Return ``text`` as str: UTF-8 bytes decoded, size checked; CalibrationError otherwise."""
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = bytes(text)
        if len(text) > MAX_FILE_BYTES:
            raise CalibrationError(f'{source}: {len(text)} bytes is too large for a '
                                   f'calibration (limit {MAX_FILE_BYTES})')
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as e:
            raise CalibrationError(f'{source}: not UTF-8 text (invalid byte 0x{text[e.start]:02x} '
                                   f'at offset {e.start}); a calibration is a YAML text file: '
                                   'is it the right file?') from None
    if not isinstance(text, str):
        raise CalibrationError(f'{source}: expected YAML text, got {type_name(text)}')
    if len(text) > MAX_FILE_BYTES:
        raise CalibrationError(f'{source}: {len(text)} characters is too large for a '
                               f'calibration (limit {MAX_FILE_BYTES})')
    return text


def check_yaml_shape(text, source):
    """Refuse YAML nested deeper than MAX_DEPTH or expanding to more than MAX_NODES nodes.

    Walks the parser's event stream (no recursion, no objects built), so a deeply nested
    or alias-bomb document costs time linear in its text.
    """
    stack, sizes = [], {}

    def done(anchor, n):
        if anchor is not None:
            sizes[anchor] = n
        if stack:
            stack[-1][1] += n
        if n > MAX_NODES or (stack and stack[-1][1] > MAX_NODES):
            raise CalibrationError(f'{source}: the YAML expands to more than {MAX_NODES} '
                                   'values (aliases/anchors repeating content?); a calibration '
                                   'file is a few kB: is it the right file?')
    try:
        for ev in yaml.parse(text, Loader=_SAFE_LOADER):
            if isinstance(ev, yaml.CollectionStartEvent):
                stack.append([ev.anchor, 1])
                if len(stack) > MAX_DEPTH:
                    raise CalibrationError(f'{source}: YAML nested deeper than {MAX_DEPTH} '
                                           'levels; a calibration file nests a few levels: is '
                                           'it the right file?')
            elif isinstance(ev, yaml.CollectionEndEvent):
                anchor, n = stack.pop()
                done(anchor, n)
            elif isinstance(ev, yaml.ScalarEvent):
                done(ev.anchor, 1)
            elif isinstance(ev, yaml.AliasEvent):
                done(None, sizes.get(ev.anchor, 1))
    except yaml.YAMLError as e:
        if 'flow level' in str(e) or 'nesting' in str(e):   # libyaml's own depth limit
            raise CalibrationError(f'{source}: YAML nested deeper than libyaml accepts; a '
                                   'calibration file nests a few levels: is it the right '
                                   'file?') from None
        raise CalibrationError(f'{source}: not valid YAML ({e.__class__.__name__}: '
                               f'{str(e).splitlines()[0]})') from None
