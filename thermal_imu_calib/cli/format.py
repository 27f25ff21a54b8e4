"""Text for people: a calibration and an evaluation as ``thermal-imu-calib`` prints them.

Units: gravity residuals in micro-g, drift in micro-g/degC, gyro rates in rad/s, parameters in
the units their files carry.
"""

import numpy as np


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
