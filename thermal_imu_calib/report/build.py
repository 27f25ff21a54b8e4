"""Assemble the calibration and noise pages from the figures and the calibration's numbers.

Section ids (stable, the tests look for them): ``summary``, ``timeline``, ``accel``,
``gyro``, ``gravity``, ``coverage``, ``parameters``, ``notes`` (and ``validation`` for a
model chosen on held-out blocks of the thermal history); the noise page has
``noise``, ``allan-accel``, ``allan-gyro``.
"""

import numpy as np

from . import figures, validation
from .html import Page

SECTIONS = ('summary', 'timeline', 'accel', 'gyro', 'gravity', 'coverage', 'parameters',
            'notes')


def _fmt(v):
    v = np.asarray(v, float).ravel()
    return ', '.join(f'{x:.4g}' for x in v)


def parameter_rows(cal):
    """Return rows (sensor, name, value, std, unit, status, reason) of every parameter."""
    rows = []
    for which in ('accel', 'gyro'):
        model = cal.accel if which == 'accel' else cal.gyro
        if model is None:
            continue
        est = getattr(model, 'estimated', None) or {}
        fixed = getattr(model, 'fixed', None) or {}
        for name, p in model.params().items():
            if name in est:
                m = np.asarray(est[name], bool).ravel()
                status = ('estimated' if m.all() else 'fixed' if not m.any()
                          else f'estimated {int(m.sum())}/{m.size}')
            else:
                status = 'estimated' if p.std is not None else 'fixed'
            reason = fixed.get(name, '')
            if not reason and status == 'fixed':
                reason = p.description or 'not estimated (reference or prior value)'
            elif not reason:
                reason = p.description
            std = '-' if p.std is None else _fmt(p.std)
            rows.append((which, name, _fmt(p.value), std, p.unit, status, str(reason)))
    return rows


def calibration_page(cal, windows=None, series=None, source=''):
    """Return the ``Page`` of a calibration; ``windows`` (Windows) enable the data figures.

    ``series``: optional [(t [s], value)] per thermal input over the whole log.
    """
    pg = Page(f'Thermal IMU calibration {cal.id}')
    pg.h2('Summary', 'summary')
    pg.p(f'frame_id {cal.frame_id or "?"}, created {cal.created}, software '
         f'{cal.software_version}; gravity {cal.gravity:.6f} m/s^2 ({cal.gravity_source}).',
         'meta')
    models = [f'{w}: {m.kind}' for w, m in (('accel', cal.accel), ('gyro', cal.gyro)) if m]
    pg.p('models: ' + '; '.join(models))
    if cal.inputs:
        vr = cal.valid_range
        pg.table(['input', 'topic', 'unit', 'valid from', 'valid to'],
                 [(i.name, i.topic, i.unit, f'{vr[j, 0]:.2f}', f'{vr[j, 1]:.2f}')
                  for j, i in enumerate(cal.inputs)], num_cols=(3, 4))
        pg.p(f'outside the valid range: {cal.out_of_range}')
    if source:
        pg.p(f'data: {source}', 'meta')
    has = windows is not None and len(windows) > 0
    pg.h2('Temperature timeline', 'timeline')
    if has:
        pg.figure('timeline', figures.timeline(windows, series, cal.input_units),
                  'temperature timeline with holds')
    else:
        pg.p('No windows: pass --log LOG (or --windows FILE written by calibrate '
             '--save-windows) to draw the timeline, the per-window data, the residuals and '
             'the coverage.', 'warn')
    for which in ('accel', 'gyro'):
        model = cal.accel if which == 'accel' else cal.gyro
        pg.h2(f'{"Accelerometer" if which == "accel" else "Gyroscope"} against temperature',
              which)
        if model is None:
            pg.p(f'no {which} model in this calibration')
        elif not cal.inputs:
            pg.p('temperature-independent calibration: nothing to plot against temperature')
        elif has:
            pg.figure(which, figures.sensor_vs_temperature(cal, windows, which),
                      f'{which} error against temperature')
        else:
            pg.figure(which, figures.model_curves(cal, which), f'{which} fitted curve')
    if has and validation.has_validation(cal):
        pg.h2('Validation on held-out blocks of the thermal history', 'validation')
        sel = cal.fit['selection']
        pg.p(sel.get('reason', ''), 'meta')
        pg.figure('validation', validation.heldout_residuals(cal, windows),
                  'held-out residual over time of each candidate family')
        pg.figure('side_by_side', validation.side_by_side(cal, windows),
                  'raw, compensated and the flight-stack cubic')
    pg.h2('Gravity residual per hold', 'gravity')
    gr = (cal.fit or {}).get('gravity_residual_ug')
    if gr:
        pg.table(['', 'RMS [ug]', 'max [ug]'],
                 [('before (raw)', f'{gr.get("before_rms", float("nan")):.1f}',
                   f'{gr.get("before_max", float("nan")):.1f}'),
                  ('after (compensated)', f'{gr.get("after_rms", float("nan")):.1f}',
                   f'{gr.get("after_max", float("nan")):.1f}')], num_cols=(1, 2))
    if has and cal.accel is not None:
        pg.figure('gravity_residual', figures.gravity_residual(cal, windows),
                  'gravity residual per hold')
    pg.h2('Pose coverage', 'coverage')
    faces = (cal.fit or {}).get('faces')
    if faces:
        pg.table(['face', 'holds'], sorted(faces.items()), num_cols=(1,))
    if has:
        pg.figure('coverage', figures.coverage_map(windows), 'pose coverage map')
    pg.h2('Parameters', 'parameters')
    pg.table(['sensor', 'name', 'value (x, y, z ...)', '1-sigma std', 'unit', 'status',
              'reason / description'], parameter_rows(cal))
    noise = _noise_rows(cal)
    if noise:
        pg.table(['noise', 'x', 'y', 'z', 'unit'], noise, num_cols=(1, 2, 3))
    pg.h2('Notes and warnings', 'notes')
    if not cal.notes:
        pg.p('none')
    for n in cal.notes:
        warn = any(w in n for w in ('extrapolated', 'not determined', 'refused', 'warning',
                                    'only between', 'not supported', 'do not support'))
        pg.p(n, 'warn' if warn else 'note')
    return pg


def _noise_rows(cal):
    rows = []
    for name, v, unit in (('accel white noise std', cal.accel_noise_std, 'm/s^2'),
                          ('gyro white noise std', cal.gyro_noise_std, 'rad/s')):
        if v is not None:
            rows.append((name, *(f'{x:.3g}' for x in v), unit))
    for name, v in (getattr(cal, 'noise_model', None) or {}).items():
        val = v.get('value') if isinstance(v, dict) else v
        if val is not None:
            rows.append((name, *(f'{x:.3g}' for x in np.asarray(val, float).ravel()),
                         v.get('unit', '') if isinstance(v, dict) else ''))
    return rows


def noise_page(result, topic, source=''):
    """Return the ``Page`` of a noise analysis (``noise.analyse`` result)."""
    from ..estimation.noise_model import per_axis
    pg = Page(f'IMU noise model: {topic}')
    pg.h2('Noise figures (Allan deviation)', 'noise')
    pg.p(f'{source}: {result["kind"]}, {result["segments"]} still segment(s), '
         f'{result["still_seconds"]:.0f} s at {result["rate_hz"]:.2f} Hz. Overlapping Allan '
         'deviation (allantools oadev), log-spaced tau. N: fitted -1/2 line at tau = 1 s; '
         'K: fitted +1/2 line at tau = 3 s; B: flat minimum / 0.664.', 'meta')
    pa = per_axis(result)
    for sensor, sec in pa.items():
        u = sec['units']
        pg.table([sensor, f'N [{u["noise_density"]}]', f'K [{u["random_walk"]}]',
                  f'B [{u["bias_instability"]}]', 'tau of B [s]'],
                 [(ax, f'{r["noise_density"]:.3g}',
                   ('< ' if r['random_walk_is_upper_bound'] else '')
                   + f'{r["random_walk"]:.3g}', f'{r["bias_instability"]:.3g}',
                   f'{r["bias_instability_tau_s"]:.3g}') for ax, r in sec['axes'].items()],
                 num_cols=(1, 2, 3, 4))
    if any(r['random_walk_is_upper_bound'] for s in pa.values() for r in s['axes'].values()):
        pg.p('"<": the record is too short to show the +1/2 slope; K is an upper bound.',
             'warn')
    for sensor in ('accel', 'gyro'):
        pg.h2(f'{sensor} Allan deviation', f'allan-{sensor}')
        pg.figure(f'allan_{sensor}', figures.allan_figure(result, sensor),
                  f'{sensor} Allan deviation')
    return pg
