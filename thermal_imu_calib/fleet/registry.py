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

History and alarms (``assess``): a unit's accelerometer bias and scale factor, read off
every model family the same way (``models/alarm_terms.py``: their value and temperature
coefficients about the model's T0, index columns ``accel.alarm_b0.x`` ..
``accel.alarm_k2.z`` with stds; registries written before them: the field model's db0,
dk0 and polynomial), are carried to a common temperature (stds propagated as independent)
and tested per axis: every change between a calibration and the unit's previous one of
the same model family (step test) and the slope over all of the unit's calibrations of
its latest family (trend test, constant vs line), each as z = value / sigma. All tests
of the fleet form one family: a unit is flagged when any |z| passes the Sidak threshold
that keeps the family-wise false-alarm rate of the whole fleet at ``FAMILY_RATE`` (1 %)
when the stds are honest (checked on simulated fleets, ``STD_SCALE``). A
latest residual more than ``RESIDUAL_MADS`` robust standard deviations above the fleet
median is ``out of family``. No ROS import.
"""

import csv
from datetime import datetime, timezone
import io
import os

import numpy as np

from ..calibration import Calibration
from ..io.output import write_atomic
from ..models.alarm_terms import bias_scale_terms

INDEX = 'index.csv'
#: characters a registry key keeps; every other byte of the UTF-8 sensor id is %XX
_KEY_SAFE = frozenset(b'ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-')
#: longest key (bytes of a directory name; file systems allow 255)
MAX_KEY_BYTES = 200
TIME_FORMAT = '%Y%m%dT%H%M%SZ'
AXES = 'xyz'
#: family-wise false-alarm rate of the parameter tests over the whole fleet (all units,
#: axes, parameters, comparisons and trends together)
FAMILY_RATE = 0.01
RESIDUAL_MADS = 5.0
#: alarm lines listed per unit (the strongest tests; the others are counted)
SHOWN_ALARMS = 4
#: parameters tested: the accelerometer bias and scale factor at a common temperature
#: ('b' -> db0, 'k' -> dk0 in the alarm texts)
ALARM_ON = ('b', 'k')
#: index column stem of the family-independent alarm terms (``alarm_columns``)
ALARM_STEM = 'accel.alarm_'
#: factor on the fit's std of d{name}0 (1: the fit's own). Checked on the stable units of
#: 20 simulated fleets (bench_fleet.py alarms, 8 x 3, seeds 0-19): their z with the fit's
#: std are N(0, 1) (Kolmogorov-Smirnov p 0.52-0.88; std 1.05 +- 0.03 over 477 changes, 1.02-
#: 1.09 over 237 trends; see docs/fleet.md), so no correction is applied.
STD_SCALE = {'b': 1.0, 'k': 1.0}
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


def iso(ns):
    """Return the registry time string of an int ns UTC stamp."""
    return datetime.fromtimestamp(ns // 10 ** 9, timezone.utc).strftime(TIME_FORMAT)


def parse_time(text):
    """Return int ns of a registry time string (raises ValueError when malformed)."""
    dt = datetime.strptime(text, TIME_FORMAT).replace(tzinfo=timezone.utc)
    return int(dt.timestamp()) * 10 ** 9


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


def alarm_columns(cal):
    """Return the index columns of the accelerometer's bias and scale terms (any family).

    ``accel.alarm_T0.x``, ``accel.alarm_b0.x`` (m/s^2), ``accel.alarm_b1.x`` (m/s^2/degC),
    ``accel.alarm_b2.x``, ``accel.alarm_k0.x`` (1) .. with ``_std``; {} when the model has
    no forward model or no stds (``models.alarm_terms.bias_scale_terms``).
    """
    terms = bias_scale_terms(cal.accel) if cal.accel is not None else None
    if terms is None:
        return {}
    out = {}
    for i, a in enumerate(AXES):
        out[f'{ALARM_STEM}T0.{a}'] = float(terms['T0'][i])
        for name in ALARM_ON:
            for j in range(3):
                out[f'{ALARM_STEM}{name}{j}.{a}'] = float(terms[name][i, j])
                out[f'{ALARM_STEM}{name}{j}.{a}_std'] = float(terms[f'{name}_std'][i, j])
    return out


def index_row(sensor, cal, time_ns, valid_from_ns, file, logs):
    """Return the index.csv row (dict) of one calibration."""
    fit = cal.fit or {}
    span = np.asarray(fit.get('temperature_span', [[np.nan, np.nan]]), float).reshape(-1, 2)
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


def _f(row, key):
    try:
        return float(row.get(key, ''))
    except ValueError:
        return np.nan


def _has_alarm_terms(row):
    return np.isfinite(_f(row, f'{ALARM_STEM}T0.x'))


def reference(row, axis):
    """Return the T0 (degC) of an index row's alarm terms on ``axis`` ('x', 'y', 'z')."""
    if _has_alarm_terms(row):
        return _f(row, f'{ALARM_STEM}T0.{axis}')
    return _f(row, f'accel.T0.{axis}')


def at_temperature(row, name, t_ref):
    """Return (value, std) per axis of accel bias ('b') or scale ('k') at ``t_ref`` degC.

    value = c0 + c1 dT + c2 dT^2 with dT = t_ref - T0: the alarm-term columns of any
    family, or (registries written before them) the field model's d{name}0, {name}1,
    {name}2; std from the three stds as independent.
    """
    new = _has_alarm_terms(row)
    cols = ([f'alarm_{name}{j}' for j in range(3)] if new
            else [f'd{name}0', f'{name}1', f'{name}2'])
    val, var = np.zeros(3), np.zeros(3)
    for i, a in enumerate(AXES):
        dt = t_ref[i] - reference(row, a)
        for j, c in enumerate(cols):
            v, s = _f(row, f'accel.{c}.{a}'), _f(row, f'accel.{c}.{a}_std')
            if j and not np.isfinite(v):
                continue   # lower-order models leave the column empty
            val[i] += v * dt ** j
            var[i] += (s * dt ** j) ** 2 if np.isfinite(s) else np.nan
    return val, np.sqrt(var)


def by_sensor(rows):
    """Return sensor -> its rows, oldest first."""
    by = {}
    for r in rows:
        by.setdefault(r['sensor'], []).append(r)
    return {s: sorted(rs, key=lambda r: r['time']) for s, rs in by.items()}


def compare(prev, cur, names=ALARM_ON, std_scale=None):
    """Return {'db0': z (3,), ...}: consecutive change at a common temperature in sigmas.

    The common temperature is the mean of the two T0 per axis; sigma is the std of the
    difference, each calibration's std multiplied by ``std_scale[name]`` (default
    ``STD_SCALE``; 1 for names it lacks).
    """
    scale = STD_SCALE if std_scale is None else std_scale
    t_ref = np.array([(reference(prev, a) + reference(cur, a)) / 2 for a in AXES])
    out = {}
    for name in names:
        v0, s0 = at_temperature(prev, name, t_ref)
        v1, s1 = at_temperature(cur, name, t_ref)
        sd = scale.get(name, 1.0) * np.sqrt(s0 ** 2 + s1 ** 2)
        # a term a family does not fit (an offset model's scale, std 0): no test (NaN)
        out[f'd{name}0'] = np.divide(v1 - v0, sd, out=np.full(3, np.nan), where=sd > 0)
    return out


def trend(rows, name, std_scale=None):
    """Return z (3,) of the slope of d{name}0 over time (weighted least squares).

    All calibrations of one unit (>= 3, oldest first) carried to the mean of their T0 per
    axis; z = slope / std(slope) with weights 1 / (std_scale * std)^2. Under "constant"
    z is N(0, 1): z^2 is the chi-square drop from a constant to a line (1 dof).
    """
    scale = (STD_SCALE if std_scale is None else std_scale).get(name, 1.0)
    t_ref = np.array([np.mean([reference(r, a) for r in rows]) for a in AXES])
    t = np.array([parse_time(r['time']) for r in rows], float) / 86400e9   # days
    vs = np.array([at_temperature(r, name, t_ref) for r in rows])          # (n, 2, 3)
    sd = scale * vs[:, 1]
    ok = np.all(sd > 0, axis=0)      # an axis whose term has no std (not fitted): no test
    sd = np.where(ok, sd, 1.0)
    x, w = vs[:, 0], 1.0 / sd ** 2                                         # (n, 3)
    tm = (w * t[:, None]).sum(0) / w.sum(0)
    sxx = (w * (t[:, None] - tm) ** 2).sum(0)
    slope = (w * (t[:, None] - tm) * x).sum(0) / sxx
    return np.where(ok, slope * np.sqrt(sxx), np.nan)


def family_threshold(n_tests, family_rate=FAMILY_RATE):
    """Return the |z| a two-sided test must pass so ``n_tests`` keep ``family_rate`` overall.

    Sidak: per test p < 1 - (1 - family_rate)^(1 / n_tests). Sidak's inequality holds for
    two-sided tests of jointly normal z with any correlation, so the consecutive changes
    sharing a calibration and the trend of the same values need no independence.
    """
    from scipy.special import ndtri
    p = -np.expm1(np.log1p(-family_rate) / max(n_tests, 1))
    return float(-ndtri(p / 2))


def unit_tests(rows, std_scale=None):
    """Return [(label, z)] of one unit's tests: every consecutive change and the trend.

    For each alarmed parameter (``ALARM_ON``) and axis: the change between a calibration
    and the unit's previous one of the same accelerometer model family (a unit whose
    family changes keeps one chain per family), and (>= 3 calibrations of the latest
    family) the slope over all of them. Non-finite z (a missing std, a scale factor an
    offset model does not fit) are left out.
    """
    out = []
    last = {}
    for cur in rows:
        prev = last.get(cur['accel_model'])
        last[cur['accel_model']] = cur
        if prev is None:
            continue
        for name, z in compare(prev, cur, ALARM_ON, std_scale).items():
            out += [(f'{name} {a} changed {prev["time"]} -> {cur["time"]}', z[i])
                    for i, a in enumerate(AXES)]
    same = [r for r in rows if r['accel_model'] == rows[-1]['accel_model']]
    if len(same) >= 3:
        for name in ALARM_ON:
            z = trend(same, name, std_scale)
            out += [(f'd{name}0 {a} trend over {len(same)} calibrations '
                     f'{same[0]["time"]} .. {same[-1]["time"]}', z[i])
                    for i, a in enumerate(AXES)]
    return [(lbl, float(z)) for lbl, z in out if np.isfinite(z)]


def rule_text(n_tests, z_c, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS):
    """Return the alarm rule in words, with the numbers of this fleet."""
    names = ', '.join(f'd{n}0' for n in ALARM_ON)
    return (f'alarm rule: {names} per axis, every change between consecutive calibrations '
            f'and the linear trend over all of a unit\'s calibrations, in units of their '
            f'sigma; {n_tests} tests over the fleet, flagged when |z| > {z_c:.2f} (Sidak: '
            f'{100 * family_rate:g} % family-wise false-alarm rate for the whole fleet); or '
            f'the latest residual more than {residual_mads:g} robust sigma above the fleet '
            'median')


def assess(rows, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS, std_scale=None):
    """Return (sensor -> alarm strings, info) for index rows (info: tests, threshold, rule)."""
    by = by_sensor(rows)
    tests = {s: unit_tests(rs, std_scale) for s, rs in by.items()}
    n = sum(len(t) for t in tests.values())
    z_c = family_threshold(n, family_rate)
    out = {}
    for s, t in tests.items():   # the strongest SHOWN_ALARMS tests over the threshold
        over = sorted(((lbl, z) for lbl, z in t if abs(z) > z_c), key=lambda x: -abs(x[1]))
        out[s] = [f'{lbl}: {z:+.1f} sigma' for lbl, z in over[:SHOWN_ALARMS]]
        if len(over) > SHOWN_ALARMS:
            out[s].append(f'... and {len(over) - SHOWN_ALARMS} more tests over '
                          f'{z_c:.2f} sigma')
    latest = {s: _f(rs[-1], 'residual_rms_mps2') for s, rs in by.items()}
    vals = np.array([v for v in latest.values() if np.isfinite(v)])
    if len(vals) >= 3:
        med = np.median(vals)
        mad = 1.4826 * np.median(np.abs(vals - med))
        for s, v in latest.items():
            if np.isfinite(v) and mad > 0 and v > med + residual_mads * mad:
                out[s].append(f'latest residual {v:.3g} m/s^2 out of family (fleet median '
                              f'{med:.3g}, {(v - med) / mad:.1f} robust sigma above)')
    notes = {s: [f'accel model changed {p["accel_model"] or "-"} -> {c["accel_model"] or "-"} '
                 f'{p["time"]} -> {c["time"]}: that change is not tested (each family is '
                 'compared with its own previous calibration; pin the family, e.g. fleet '
                 'calibrate --model field, to test every step)'
                 for p, c in zip(rs, rs[1:]) if p['accel_model'] != c['accel_model']]
             for s, rs in by.items()}
    info = {'tests': n, 'threshold_sigma': z_c, 'family_rate': family_rate, 'notes': notes,
            'rule': rule_text(n, z_c, family_rate, residual_mads),
            'max_abs_z': {s: max((abs(z) for _, z in t), default=np.nan)
                          for s, t in tests.items()}}
    return out, info


def alarms(rows, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS):
    """Return sensor -> list of alarm strings (empty list: no alarm); see ``assess``."""
    return assess(rows, family_rate, residual_mads)[0]
