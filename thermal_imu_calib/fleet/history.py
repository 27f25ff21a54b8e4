"""Render a registry's history: each unit's parameters over time with +-1 sigma, alarms.

Text for the terminal and a self-contained HTML page (tables plus inline SVG error-bar
plots; no plotting library needed). Values come from ``registry.read_index`` rows.
"""

import html

import numpy as np

from ..estimation.field_estimator import S_TERM_NAMES
from ..io.output import write_atomic
from . import pooled_s
from .alarms import _f, accel_family, AXES, untested_accel

#: (index column, label, scale to display, display unit); the accelerometer's bias and
#: scale factor at T0 that the alarms test (``accel.alarm_*``: any family's, or the field
#: model's on the same holds, the alarm yardstick), then the field model's own parameters
SHOWN = (('accel.alarm_b0', 'b0 at T0', 1e3, 'mm/s^2'),
         ('accel.alarm_k0', 'k0 - 1 at T0', 1e6, 'ppm'),
         ('accel.alarm_b1', 'b1', 1e3, 'mm/s^2/degC'), ('accel.alarm_k1', 'k1', 1e6, 'ppm/degC'),
         ('accel.db0', 'db0', 1e3, 'mm/s^2'), ('accel.dk0', 'dk0', 1e6, 'ppm'),
         ('accel.b1', 'b1', 1e3, 'mm/s^2/degC'), ('accel.k1', 'k1', 1e6, 'ppm/degC'),
         ('gyro.c0', 'gyro c0', 1e3, 'mrad/s'), ('gyro.c1', 'gyro c1', 1e3, 'mrad/s/degC'),
         ('gyro.alarm_b0', 'gyro b0 at T0', 1e3, 'mrad/s'))
#: shown values less this (the scale factor's 1), per column
OFFSET = {'accel.alarm_k0': 1.0}
#: columns the alarm terms make redundant (the field model's db0, dk0, b1, k1 are its
#: alarm terms b0, k0 - 1, b1, k1; ``models.alarm_terms``)
SAME_AS_ALARM = ('accel.db0', 'accel.dk0', 'accel.b1', 'accel.k1')


def _by_sensor(rows):
    out = {}
    for r in rows:
        out.setdefault(r['sensor'], []).append(r)
    return out


def _cell(row, col, scale):
    v, s = _f(row, col), _f(row, col + '_std')
    if not np.isfinite(v):
        return '-'
    v -= OFFSET.get(col.rsplit('.', 1)[0], 0.0)
    return f'{v * scale:.3g}' + (f'+-{s * scale:.2g}' if np.isfinite(s) else '')


def _columns(rs):
    """Return the SHOWN columns with a value in any of ``rs``.

    The field model's own db0, dk0, b1, k1 are left out beside the alarm terms, which are
    the same numbers for it, unless a row has them without alarm terms (a registry written
    before 2026-11-27).
    """
    cols = [c for c in SHOWN if any(np.isfinite(_f(r, f'{c[0]}.x')) for r in rs)]
    if not any(np.isfinite(_f(r, 'accel.db0.x')) and not np.isfinite(_f(r, 'accel.alarm_k0.x'))
               for r in rs):
        cols = [c for c in cols if c[0] not in SAME_AS_ALARM]
    return cols


def pooled_line(rs):
    """Return [the line stating a unit's pooled S], or [] when none of ``rs`` has it.

    The alarms compare the latest family's terms at S pooled over its calibrations
    (``pooled_s``) while the table shows each calibration's terms at its own S, with its
    own stds; this says which S the z's are at (S's terms in 1e-4, +- 1 sigma). Pooled
    over the rows the alarms test (``alarms.untested_accel`` left out, as ``unit_tests``
    does), each row's terms read once.
    """
    rs = [r for r in rs if not untested_accel(r)]
    if not rs:
        return []
    family, memo = accel_family(rs[-1]), {}
    got = pooled_s.unit_pools(rs, accel_family, memo).get(family)
    if got is None:
        return []
    n = sum(accel_family(r) == family and pooled_s.row_s_memo(r, memo) is not None
            for r in rs)
    s_star, cov = got
    terms = ', '.join(f'{t} {v * 1e4:.1f}+-{np.sqrt(cov[i, i]) * 1e4:.1f}'
                      for i, (t, v) in enumerate(zip(S_TERM_NAMES, s_star)))
    return [f'  accelerometer non-orthogonality S pooled over {n} calibration(s): {terms} '
            '(1e-4); the alarms compare the terms at it, the table shows each calibration '
            'at its own S']


def format_history(rows, alarms, info=None):
    """Return the text report: one block per unit, one line per calibration.

    ``info`` is ``registry.assess``'s second result: the rule (stated first), the notes.
    """
    info = info or {}
    out = [info['rule']] if 'rule' in info else []
    for sensor, rs in _by_sensor(rows).items():
        flag = alarms.get(sensor) or []
        zmax = info.get('max_abs_z', {}).get(sensor, np.nan)
        out.append(f'{sensor}: {len(rs)} calibrations' + ('  ALARM' if flag else '  ok') + (
            f' (largest |z| {zmax:.2f}, threshold {info["threshold_sigma"]:.2f})'
            if np.isfinite(zmax) else ''))
        cols = _columns(rs)
        out.append('  ' + f'{"time":17s} {"model":17s} {"resid":>8s}  ' + '  '.join(
            f'{lbl} x/y/z [{u}]' for _, lbl, _, u in cols))
        for r in rs:
            res = _f(r, 'residual_rms_mps2')
            out.append(f'  {r["time"]:17s} {r["accel_model"][:17]:17s} {res:8.2e}  ' + '  '.join(
                '/'.join(_cell(r, f'{c}.{a}', sc) for a in AXES) for c, _, sc, _ in cols))
        out.extend(pooled_line(rs))
        out.extend(f'  ALARM {a}' for a in flag)
        out.extend(f'  note: {n}' for n in info.get('notes', {}).get(sensor, []))
    n = sum(bool(v) for s, v in alarms.items() if s in _by_sensor(rows))
    out.append(f'{n} of {len(_by_sensor(rows))} units flagged')
    return '\n'.join(out)


def _svg(rs, col, scale, unit, w=360, h=120):
    """Return an inline SVG: change since the first calibration +-1 sigma, per axis."""
    colors = ('#d62728', '#2ca02c', '#1f77b4')
    v = np.array([[_f(r, f'{col}.{a}') for a in AXES] for r in rs]) * scale
    s = np.array([[_f(r, f'{col}.{a}_std') for a in AXES] for r in rs]) * scale
    s = np.where(np.isfinite(s), s, 0.0)
    first = np.array([col_v[np.isfinite(col_v)][0] if np.any(np.isfinite(col_v)) else 0.0
                      for col_v in v.T])
    v = v - first   # change since the unit's first calibration: drifts and steps show
    lo, hi = np.nanmin(v - s), np.nanmax(v + s)
    if not np.isfinite(lo) or hi <= lo:
        lo, hi = (lo if np.isfinite(lo) else 0) - 1, (hi if np.isfinite(hi) else 0) + 1
    n = len(rs)

    def xy(i, val):
        x = 40 + (w - 50) * ((i + 0.5) / n)
        y = 10 + (h - 30) * (1 - (val - lo) / (hi - lo))
        return x, y
    parts = [f'<svg width="{w}" height="{h}" xmlns="http://www.w3.org/2000/svg">',
             f'<text x="2" y="12" font-size="10">{html.escape(col)}: change since the first '
             f'[{unit}]</text>',
             f'<text x="2" y="{h - 4}" font-size="9">{lo:.3g} .. {hi:.3g}</text>']
    for a in range(3):
        for i in range(n):
            if not np.isfinite(v[i, a]):
                continue
            x, y = xy(i, v[i, a])
            x += (a - 1) * 4
            _, y0 = xy(i, v[i, a] - s[i, a])
            _, y1 = xy(i, v[i, a] + s[i, a])
            parts.append(f'<line x1="{x:.1f}" y1="{y0:.1f}" x2="{x:.1f}" y2="{y1:.1f}" '
                         f'stroke="{colors[a]}"/><circle cx="{x:.1f}" cy="{y:.1f}" r="2" '
                         f'fill="{colors[a]}"/>')
    parts.append('</svg>')
    return ''.join(parts)


def write_html(path, rows, alarms, info=None):
    """Write the HTML history report (tables, +-1 sigma plots x red, y green, z blue)."""
    info = info or {}
    body = ['<h1>thermal_imu_calib fleet history</h1>',
            '<p>Per unit: parameters of each calibration with +-1 sigma (x red, y green, '
            'z blue), oldest left.</p>',
            f'<p><b>{html.escape(info.get("rule", "alarms"))}</b></p>']
    for sensor, rs in _by_sensor(rows).items():
        flag = alarms.get(sensor) or []
        body.append(f'<h2>{html.escape(sensor)} ' + ('<span style="color:#c00">ALARM</span>'
                                                     if flag else 'ok') + '</h2>')
        body.extend(f'<p style="color:#c00">{html.escape(a)}</p>' for a in flag)
        body.extend(f'<p>note: {html.escape(n)}</p>'
                    for n in info.get('notes', {}).get(sensor, []))
        body.extend(f'<p>{html.escape(line.strip())}</p>' for line in pooled_line(rs))
        cols = _columns(rs)
        body.append('<div>' + ''.join(_svg(rs, c, sc, u) for c, _, sc, u in cols)
                    + '</div>')
        body.append('<table border="1" cellspacing="0"><tr><th>time</th><th>valid from'
                    '</th><th>model</th><th>holds</th><th>residual m/s^2</th>' + ''.join(
                        f'<th>{html.escape(lbl)} [{u}]</th>' for _, lbl, _, u in cols)
                    + '</tr>')
        for r in rs:
            body.append(f'<tr><td>{r["time"]}</td><td>{r["valid_from"]}</td>'
                        f'<td>{html.escape(r["accel_model"])}</td><td>{r["holds"]}</td>'
                        f'<td>{_f(r, "residual_rms_mps2"):.3g}</td>' + ''.join(
                            '<td>' + '<br>'.join(_cell(r, f'{c}.{a}', sc) for a in AXES)
                            + '</td>' for c, _, sc, _ in cols) + '</tr>')
        body.append('</table>')
    return write_atomic(path, '<!DOCTYPE html><html><head><meta charset="utf-8"><title>fleet '
                        'history</title></head><body style="font-family:sans-serif">'
                        + '\n'.join(body) + '</body></html>\n')
