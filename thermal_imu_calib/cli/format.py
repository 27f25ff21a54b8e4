"""Text for people: a calibration and an evaluation as ``thermal-imu-calib`` prints them.

Units: gravity residuals in micro-g, drift in micro-g/degC, gyro rates in rad/s, parameters in
the units their files carry.
"""

import json

import numpy as np

from ..collection.stationary import format_holds, format_settings


def format_calibration(cal):
    """Render a calibration for people: models, parameters with units and stds, fit, notes."""
    out = [f'calibration {cal.id}  frame_id={cal.frame_id or "?"}  created {cal.created}  '
           f'software {cal.software_version}',
           f'gravity {cal.gravity:.6f} m/s^2 ({cal.gravity_source})']
    if cal.inputs:
        vr = cal.valid_range
        out.append('temperature inputs: ' + ', '.join(
            f'{i.topic} [{vr[j, 0]:.2f}..{vr[j, 1]:.2f} {i.unit}]'
            for j, i in enumerate(cal.inputs)) + f'; outside: {cal.out_of_range}')
        out.append(f'mapping: accel axes <- inputs {cal.accel_input}, gyro axes <- inputs '
                   f'{cal.gyro_input}')
    else:
        out.append('temperature inputs: none (temperature-independent)')
    for name, model in (('accel', cal.accel), ('gyro', cal.gyro)):
        if model is None:
            continue
        out.append(f'{name}: {model.kind} {model.meta()}')
        for pname, p in model.params().items():
            v = np.asarray(p.value)
            val = np.array2string(v.ravel(), max_line_width=200,
                                  formatter={'float_kind': lambda x: f'{x:.5g}'})
            sd = '' if p.std is None else '  std ' + np.array2string(
                np.asarray(p.std, float).ravel(), max_line_width=200,
                formatter={'float_kind': lambda x: f'{x:.2g}'})
            out.append(f'  {pname:4s} [{p.unit}] {val}{sd}')
    fit = cal.fit or {}
    for key in ('holds', 'windows', 'faces', 'temperature_span', 'residual_rms',
                'gravity_residual_ug'):
        if key in fit:
            out.append(f'fit.{key}: {fit[key]}')
    for n in cal.notes:
        out.append(f'note: {n}')
    return '\n'.join(out)


def format_evaluation(res):
    """Render evaluate results as a table (micro-g, micro-g/degC, rad/s)."""
    r = res['results']
    labels = list(r)
    heads = ['recorded' if lb == 'raw' else lb for lb in labels]
    avg_s = r['raw']['averaged_residual_ug']['window_s']
    rows = [('holds', lambda m: f'{m["holds"]}'),
            ('gravity residual per hold, RMS [ug]',
             lambda m: f'{m["gravity_residual_ug"]["rms"]:.1f}'),
            ('gravity residual per hold, max [ug]',
             lambda m: f'{m["gravity_residual_ug"]["max"]:.1f}'),
            (f'{avg_s:.0f}-s averaged residual, RMS [ug]',
             lambda m: f'{m["averaged_residual_ug"]["rms"]:.1f}'),
            (f'{avg_s:.0f}-s averaged residual, max [ug]',
             lambda m: f'{m["averaged_residual_ug"]["max"]:.1f}'),
            ('drift vs temperature x,y,z RMS [ug/degC]',
             lambda m: ('/'.join(f'{v:.1f}' for v in m['drift_ug_per_degC_rms'])
                        if 'drift_ug_per_degC_rms' in m else '-')),
            ('gyro rate per hold, RMS [rad/s]', lambda m: f'{m["gyro_rate_rms"]["value"]:.2e}')]
    w0 = max(len(n) for n, _ in rows)
    cols = [max(len(lb), 14) for lb in heads]
    out = [f'{res["path"]}: {res["holds"]} stationary holds, {res["windows"]} windows',
           ' ' * w0 + '  ' + '  '.join(f'{lb:>{c}}' for lb, c in zip(heads, cols))]
    for name, fn in rows:
        cells = '  '.join(f'{fn(r[lb]):>{c}}' for lb, c in zip(labels, cols))
        out.append(f'{name:<{w0}}  {cells}')
    return '\n'.join(out)


def format_log_read(read, holds=False):
    """Return the lines ``calibrate`` prints as a log has been read (an app LogRead).

    Messages, rate, holds and pose changes; the detector's settings; with ``holds`` the
    hold list; the input gate's warnings.
    """
    c = read.collected
    lines = [f'{read.path}: {c.imu_messages} Imu messages in {c.seconds:.1f} s '
             f'({c.imu_messages / max(c.seconds, 1e-9):,.0f} msgs/s), '
             f'{len(np.unique(c.windows.hold))} stationary holds' + _motion_text(c),
             '  ' + format_settings(c.detector)]
    if holds:
        lines.append(format_holds(c.holds))
    lines += [f'  warning: {w}' for w in read.warnings]
    return '\n'.join(lines)


def _motion_text(collected):
    """Return ', N pose changes (M too long dropped)' for a Collected ('' if not collected)."""
    if collected.motion is None:
        return ''
    dropped = ', '.join(f'{n} {why.replace("_", " ")}'
                        for why, n in collected.motion['dropped'].items() if n)
    return f', {len(collected.transitions)} pose changes' + (
        f' ({dropped} dropped)' if dropped else '')


def format_saved_windows(saved, path):
    """Return the line saying what ``--save-windows`` wrote ((windows, pose changes))."""
    return (f'wrote {saved[0]} windows to {path} and {saved[1]} pose changes to '
            f'{path}.transitions.npz')


def format_calibrate_run(run, output, as_json=False):
    """Return what ``calibrate`` prints on stdout: the summary and notes, or the JSON report."""
    result = run.result
    if as_json:
        return json.dumps({'summary': result.summary, 'output': output,
                           'calibration': result.calibration.to_dict()}, indent=1,
                          default=str)
    return '\n'.join([result.summary] + [f'  note: {n}' for n in result.calibration.notes]
                     + [f'wrote {output}'])
