"""Calibration registry: REGISTRY_DIR/<sensor key>/<ISO time>.yaml plus index.csv, and history.

In the spirit of imucal's ``management.py``: every calibration is a file named by its
sensor and time (the end of the newest log it used, UTC, ISO 8601 basic format
``YYYYMMDDTHHMMSSZ``) and one row of ``index.csv``: sensor, time, valid_from (start of the
oldest log), model, holds, temperature span, the key parameters with their 1-sigma
standard deviations and the residual. The files are what ``calibrate`` writes.

Unit identity: the directory of a sensor is ``key(sensor)``, a reversible encoding of the
sensor id (the frame_id, by default): letters, digits, ``_`` and ``-`` stay, every other
byte of its UTF-8 text becomes ``%XX``. Two ids never share a key (``robot/imu`` is
``robot%2Fimu``, ``robot_imu`` stays), and no key contains a dot, so no id can name the
registry's own files (``index.csv``, temporary ``.*`` files). The index keeps the id as
given (``sensor``) next to the file; a row whose file is not under its sensor's key is
never used. Registries written before keys (sensor names with ``/`` etc. replaced by
``_``) are still read.

History and drift alarms: ``alarms.py`` (re-exported here). No ROS import.
"""

import csv
import io
import os

import numpy as np

from ..calibration import Calibration
from ..io.output import write_atomic
from .alarms import (ALARM_ON, ALARM_STEM, alarm_columns, alarms, assess,  # noqa: F401
                     at_temperature, AXES, by_sensor, compare, FAMILY_RATE,
                     family_threshold, GYRO_ALARM_ON, GYRO_PREFIX, GYRO_STEM, gyro_scale,
                     MIN_GYRO_TESTS, reference, RESIDUAL_MADS, rule_text, SHOWN_ALARMS,
                     scaled_tests, STD_SCALE, trend, unit_tests, untested_accel,
                     FLAT_SPAN_DEGC)
from .times import iso, parse_time, TIME_FORMAT  # noqa: F401

INDEX = 'index.csv'
#: characters a registry key keeps; every other byte of the UTF-8 sensor id is %XX
_KEY_SAFE = frozenset(b'ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-')
#: longest key (bytes of a directory name; file systems allow 255)
MAX_KEY_BYTES = 200
BASE_COLUMNS = ('sensor', 'time', 'valid_from', 'file', 'accel_model', 'gyro_model', 'logs',
                'holds', 'windows', 'temp_min', 'temp_max', 'residual_rms_mps2')


def key(sensor):
    """Return the registry directory name of ``sensor``: its reversible encoding (``unkey``).

    Raises ValueError (a short message) for an empty id, one that is not UTF-8 text, or
    one whose key would be longer than ``MAX_KEY_BYTES``.
    """
    sensor = str(sensor)
    if not sensor.strip():
        raise ValueError('the sensor id is empty')
    try:
        data = sensor.encode('utf-8')
    except UnicodeEncodeError:
        raise ValueError(f'the sensor id {display_id(sensor)} is not UTF-8 text') from None
    out = ''.join(chr(b) if b in _KEY_SAFE else f'%{b:02X}' for b in data)
    if len(out) > MAX_KEY_BYTES:
        raise ValueError(f'the sensor id {display_id(sensor)} ({len(sensor)} characters) is too '
                         f'long to name a unit (its key has {len(out)} bytes, at most '
                         f'{MAX_KEY_BYTES}); fix the driver\'s frame_id or choose the unit '
                         'with --by')
    return out


def unkey(text):
    """Return the sensor id of a registry key (inverse of ``key``)."""
    from urllib.parse import unquote_to_bytes
    return unquote_to_bytes(text).decode('utf-8')


def display_id(sensor, limit=60):
    """Return a sensor id for a one-line message: printable, at most ``limit`` characters."""
    text = sensor if sensor.isprintable() else repr(sensor)[1:-1]
    return repr(text[:limit] + '...') if len(text) > limit else repr(text)


def _legacy_key(sensor):
    """Return the directory of a sensor in a registry written before keys, or None."""
    import re
    safe = re.fullmatch(r'[A-Za-z0-9._+-]+', sensor) and sensor != INDEX \
        and not sensor.startswith('.')
    return sensor if safe else None


def _row_file(registry, row):
    """Return the calibration file of an index row, or None when it is not under its key."""
    rel = os.path.normpath(row.get('file') or '')
    top = rel.split(os.sep)[0]
    try:
        ok = top == key(row.get('sensor', ''))
    except ValueError:
        ok = False
    if not ok and top != _legacy_key(row.get('sensor', '')):
        return None
    if os.path.isabs(rel) or '..' in rel.split(os.sep) or rel.count(os.sep) != 1:
        return None
    return os.path.join(registry, rel)


def key_parameters(cal):
    """Return the index columns of a calibration's per-axis parameters with stds.

    Every (3,) parameter of the accel and gyro models that has a std, plus their T0:
    ``accel.db0.x``, ``accel.db0.x_std``, ...
    """
    out = {}
    for which in ('accel', 'gyro'):
        model = getattr(cal, which)
        if model is None:
            continue
        for name, p in model.params().items():
            v = np.asarray(p.value, float)
            if v.shape != (3,) or (p.std is None and name != 'T0'):
                continue
            for i, a in enumerate(AXES):
                out[f'{which}.{name}.{a}'] = float(v[i])
                if p.std is not None:
                    out[f'{which}.{name}.{a}_std'] = float(np.asarray(p.std, float)[i])
    out.update(alarm_columns(cal))
    return out


def index_row(sensor, cal, time_ns, valid_from_ns, file, logs):
    """Return the index.csv row (dict) of one calibration."""
    fit = cal.fit or {}
    # a calibration without a thermal input has temperature_span None: no span
    span = np.asarray(fit.get('temperature_span') or [[np.nan, np.nan]], float).reshape(-1, 2)
    res = fit.get('residual_rms', {})
    row = {'sensor': sensor, 'time': iso(time_ns), 'valid_from': iso(valid_from_ns),
           'file': file, 'accel_model': cal.accel.kind if cal.accel else '',
           'gyro_model': cal.gyro.kind if cal.gyro else '', 'logs': len(logs),
           'holds': fit.get('holds', ''), 'windows': fit.get('windows', ''),
           'temp_min': float(span[0, 0]), 'temp_max': float(span[0, 1]),
           'residual_rms_mps2': res.get('value', '') if isinstance(res, dict) else res}
    row.update(key_parameters(cal))
    return row


def read_index(registry):
    """Return the index rows (dicts of str) sorted by sensor and time; [] when none.

    Raises ValueError (one line) for a file that is not a registry index (not UTF-8 CSV,
    no ``sensor``/``time``/``valid_from``/``file`` columns); missing cells read as ''.
    """
    path = os.path.join(registry, INDEX)
    if not os.path.isfile(path):
        return []
    try:
        with open(path, newline='', encoding='utf-8') as f:
            reader = csv.DictReader(f)
            missing = [c for c in BASE_COLUMNS[:4] if c not in (reader.fieldnames or [])]
            if missing:
                raise ValueError(f'{path}: not a registry index (no {", ".join(missing)} '
                                 'column); restore it or write the registry again with '
                                 '`thermal-imu-calib fleet calibrate`')
            rows = [{k: v or '' for k, v in r.items() if k is not None} for r in reader]
    except (UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f'{path}: not a registry index ({type(e).__name__}: '
                         f'{str(e)[:100]})') from None
    rows = [dict({c: '' for c in BASE_COLUMNS}, **r) for r in rows]
    return sorted(rows, key=lambda r: (r['sensor'], r['time']))


def add(registry, entries, errors=None):
    """Save calibrations and update index.csv atomically.

    entries: (sensor, Calibration, time_ns, valid_from_ns, logs). A calibration of the
    same sensor and time replaces the old one. Returns the written YAML paths (None for an
    entry that could not be written when ``errors`` is a list: ``(sensor, reason)`` is
    appended there and the other entries are still written; else the error is raised).
    """
    rows = {(r['sensor'], r['time']): r for r in read_index(registry)}
    paths = []
    for sensor, cal, time_ns, valid_from_ns, logs in entries:
        try:
            rel = os.path.join(key(sensor), iso(time_ns) + '.yaml')
            paths.append(cal.save(os.path.join(registry, rel)))
        except (OSError, ValueError) as e:
            if errors is None:
                raise
            errors.append((sensor, str(e)))
            paths.append(None)
            continue
        row = index_row(sensor, cal, time_ns, valid_from_ns, rel, logs)
        rows[(row['sensor'], row['time'])] = row
    cols = list(BASE_COLUMNS)
    for r in rows.values():
        cols += [k for k in r if k not in cols]
    buf = io.StringIO()
    w = csv.DictWriter(buf, cols, restval='')
    w.writeheader()
    for k in sorted(rows):
        w.writerow(rows[k])
    write_atomic(os.path.join(registry, INDEX), buf.getvalue())
    return paths


def calibrations(registry, sensor):
    """Return [(time_ns, path)] of one sensor's calibrations, oldest first (from the files)."""
    out = []
    for name in {key(sensor), _legacy_key(sensor)} - {None}:
        d = os.path.join(registry, name)
        if not os.path.isdir(d):
            continue
        for f in os.listdir(d):
            try:
                out.append((parse_time(os.path.splitext(f)[0]), os.path.join(d, f)))
            except ValueError:
                continue
    return sorted(out)


def valid_at(registry, sensor, t_ns=None):
    """Return the path of the calibration of ``sensor`` valid at ``t_ns`` (None: latest).

    Valid at t: the newest calibration whose data started at or before t (index
    ``valid_from``); a log older than every calibration gets the oldest one. Only the
    sensor's own rows are used (the id exactly as recorded, its file under its key).
    Raises LookupError saying what is missing.
    """
    rows = [r for r in read_index(registry) if r['sensor'] == sensor]
    rows = [dict(r, path=_row_file(registry, r)) for r in rows]
    rows = [r for r in rows if r['path']]
    if not rows:
        files = calibrations(registry, sensor)
        if not files:
            raise LookupError(f'no calibration of sensor {display_id(sensor)} in '
                              f'{registry}; run `thermal-imu-calib fleet calibrate` on its logs '
                              'first')
        rows = [{'valid_from': iso(t), 'time': iso(t), 'path': p} for t, p in files]
    if t_ns is None:
        chosen = rows[-1]
    else:
        before = [r for r in rows if parse_time(r['valid_from']) <= t_ns]
        chosen = before[-1] if before else rows[0]
    return chosen['path']


def load_valid(registry, sensor, t_ns=None):
    """Return the Calibration of ``sensor`` valid at ``t_ns`` (see ``valid_at``)."""
    return Calibration.load(valid_at(registry, sensor, t_ns))
