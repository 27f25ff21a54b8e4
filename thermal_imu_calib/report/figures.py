"""Report figures (matplotlib ``Figure`` objects, no pyplot: thread-safe, no display needed).

Data in, ``Figure`` out; SI units on the axes (accelerometer errors in micro-g, gyro in deg/h).

Calibration figures work on a ``Calibration`` and, when available, the stationary windows
(``Windows``: from ``--log``, ``calibrate --save-windows`` or the calibrator node); the
Allan figure on an ``estimation.allan`` result.
"""

from matplotlib.figure import Figure
import numpy as np

from ..collection.segments import face_of
from ..thermal_input import history_windows, parse_history_key

UG = 1e6 / 9.80665          # micro-g per m/s^2
AXES = 'xyz'
COLORS = ('tab:red', 'tab:green', 'tab:blue')


def _subplots(nrows=1, ncols=1, figsize=(8, 4), **kw):
    """Return (fig, axes) like ``pyplot.subplots`` without pyplot's global state."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def _hold_table(windows):
    """Return per hold: id, t0, t1, mean accel (3,), face label."""
    ids, means = windows.hold_means()
    rows = []
    for h, m in zip(ids, means):
        sel = windows.hold == h
        rows.append((h, float(windows.t0[sel].min()), float(windows.t1[sel].max()), m,
                     face_of(m)))
    return rows


def timeline(windows, series=None, units=None):
    """Temperature against time with the holds shaded and labelled by face or 'tilted'.

    ``series``: optional list of (t [s], value) per input over the whole log; else the
    window means are drawn.
    """
    fig, ax = _subplots(figsize=(11, 3.8))
    t_ref = float(windows.t0.min())
    k = windows.n_inputs
    units = units or ['degC'] * k
    for j in range(k):
        if series is not None and len(series[j][0]):
            ax.plot((series[j][0] - t_ref) / 60, series[j][1], lw=1, label=f'input {j}')
        else:
            ax.plot((0.5 * (windows.t0 + windows.t1) - t_ref) / 60, windows.temp[:, j], '.',
                    ms=3, label=f'input {j} (window means)')
    top = ax.get_xaxis_transform()       # x in data, y in axes fraction
    for i, (_, a, b, _, face) in enumerate(_hold_table(windows)):
        ax.axvspan((a - t_ref) / 60, (b - t_ref) / 60, color='tab:orange' if face == 'tilted'
                   else 'tab:blue', alpha=0.15, lw=0)
        ax.text((0.5 * (a + b) - t_ref) / 60, 1.01, face, ha='center', va='bottom',
                fontsize=7, rotation=90 if len(windows.hold_ids) > 16 else 0, transform=top)
    ax.set_xlabel('time since the first hold [min]')
    ax.set_ylabel(f'thermal input [{"/".join(sorted(set(units)))}]')
    ax.set_title('Temperature timeline (shaded: stationary holds; blue face, orange tilted)',
                 fontsize=10, pad=18)
    ax.grid(alpha=0.3)
    if k > 1:
        ax.legend(fontsize=7, loc='lower right')
    return fig


def stream_windows(cal, windows):
    """Return (accel, gyro) corrected window means with the history over the windows."""
    hist = {}
    for m in (cal.accel, cal.gyro):
        for k in getattr(m, 'history_keys', ()):
            hist[k] = history_windows(windows.t0, windows.t1, windows.temp,
                                      parse_history_key(k))
    temps = windows.temp
    f = cal.temperature_filter
    if f is not None and not f.is_identity:
        temps = f.window_temperatures(windows)
    res = cal.apply(windows.accel, windows.gyro, temps, history=hist or None)
    return res.accel, res.gyro


def _compensate(cal, windows):
    if any(getattr(m, 'history_keys', ()) for m in (cal.accel, cal.gyro)):
        return stream_windows(cal, windows)       # the history over the windows
    temps = windows.temp if cal.inputs else None
    res = cal.apply(windows.accel, windows.gyro, temps)
    return res.accel, res.gyro


def _grid(cal, which, n=120):
    """Return (n, 3) per-axis inputs across the valid range of each axis's input."""
    idx = cal.accel_input if which == 'accel' else cal.gyro_input
    vr = cal.valid_range
    return np.stack([np.linspace(vr[i, 0], vr[i, 1], n) for i in idx], 1)


def sensor_vs_temperature(cal, windows, which):
    """Per axis error against temperature, raw and compensated, with the fitted curve.

    Accelerometer error per window = output - g u (u: the compensated gravity direction
    of the window); curves: what the model removes for that axis held up (+g) and down
    (-g), +-1 sigma band from ``predict_std``. Gyro error = output (still: ~0 after
    compensation, up to earth rate); curve: the model's correction at zero rate.
    The valid range is the white band between the grey hatched regions.
    """
    model = cal.accel if which == 'accel' else cal.gyro
    a_c, g_c = _compensate(cal, windows)
    idx = cal.accel_input if which == 'accel' else cal.gyro_input
    fig, grid = _subplots(2, 3, figsize=(11, 5.6), sharex='col')
    scale, unit = (UG, 'ug') if which == 'accel' else (180 / np.pi * 3600, 'deg/h')
    if which == 'accel':
        u = a_c / np.linalg.norm(a_c, axis=1, keepdims=True)
        raw_err = windows.accel - cal.gravity * u
        comp_err = a_c - cal.gravity * u
    else:
        raw_err, comp_err = windows.gyro, g_c
    tg = _grid(cal, which) if cal.inputs else None
    std = model.predict_std(tg) if tg is not None else None
    for i in range(3):
        ax, axc = grid[0, i], grid[1, i]
        temp = windows.temp[:, idx[i]] if cal.inputs else np.zeros(len(windows))
        ax.plot(temp, raw_err[:, i] * scale, 'o', ms=3, color='0.45', label='raw, per window')
        axc.plot(temp, comp_err[:, i] * scale, 'o', ms=3, color=COLORS[i],
                 label='compensated, per window')
        if tg is not None:
            signs = (((+1, '-', 'model, axis up'), (0, ':', 'model, axis level'),
                      (-1, '--', 'model, axis down')) if which == 'accel'
                     else ((0, '-', 'model (zero rate)'),))
            for sign, ls, lab in signs:
                true = np.zeros_like(tg)
                if which == 'accel':
                    true[:, i] = sign * cal.gravity
                    removed = _forward(model, true, tg) - true
                else:
                    aux = {'accel': np.tile([0, 0, cal.gravity], (len(tg), 1))}
                    removed = true - model.correct(true, tg, aux=aux)
                ax.plot(tg[:, i], removed[:, i] * scale, ls, color='k', lw=1, label=lab)
                if std is not None:
                    ax.fill_between(tg[:, i], (removed[:, i] - std[:, i]) * scale,
                                    (removed[:, i] + std[:, i]) * scale, color='k',
                                    alpha=0.15, lw=0,
                                    label='+-1 sigma' if sign == signs[0][0] else None)
            if std is not None:
                axc.fill_between(tg[:, i], -std[:, i] * scale, std[:, i] * scale,
                                 color=COLORS[i], alpha=0.2, lw=0, label='model +-1 sigma')
            lo, hi = tg[0, i], tg[-1, i]
            pad = 0.05 * max(hi - lo, 1e-6)
            for a in (ax, axc):
                a.axvspan(lo - 3 * pad, lo, color='0.85', hatch='//', lw=0)
                a.axvspan(hi, hi + 3 * pad, color='0.85', hatch='//', lw=0)
                a.set_xlim(lo - 3 * pad, hi + 3 * pad)
        axc.axhline(0, color='k', lw=0.5)
        ax.set_title(f'{which} {AXES[i]}', fontsize=10)
        axc.set_xlabel(f'input [{cal.inputs[idx[i]].unit if cal.inputs else "-"}]')
        for a in (ax, axc):
            a.grid(alpha=0.3)
        if i == 0:
            ax.set_ylabel(f'raw error [{unit}]')
            axc.set_ylabel(f'compensated error [{unit}]')
            ax.legend(fontsize=6)
            axc.legend(fontsize=6)
    fig.suptitle(f'{which}: output error against temperature, every hold window; top raw '
                 'with the fitted model, bottom compensated (hatched: outside the valid '
                 'range)', fontsize=10)
    return fig


def _forward(model, true, temps):
    """Return the raw output the model predicts (its inverse by fixed point if needed)."""
    try:
        return model.forward(true, temps)
    except NotImplementedError:
        raw = true.copy()
        for _ in range(20):
            raw = raw + (true - model.correct(raw, temps))
        return raw


def gravity_residual(cal, windows):
    """Per hold |mean f| - g before and after compensation (micro-g), two panels."""
    a_c, _ = _compensate(cal, windows)
    rows = _hold_table(windows)
    before, after = [], []
    for h, *_ in rows:
        sel = windows.hold == h
        w = windows.n[sel]
        before.append(np.linalg.norm(np.average(windows.accel[sel], axis=0, weights=w)))
        after.append(np.linalg.norm(np.average(a_c[sel], axis=0, weights=w)))
    before = (np.array(before) - cal.gravity) * UG
    after = (np.array(after) - cal.gravity) * UG
    x = np.arange(len(rows))
    labels = [f'{i}\n{r[4]}' for i, r in enumerate(rows)]
    fig, axs = _subplots(2, 1, figsize=(11, 4.6), sharex=True)
    panels = ((axs[0], before, 'raw', '0.5'), (axs[1], after, 'compensated', 'tab:blue'))
    for ax, v, name, c in panels:
        ax.bar(x, v, color=c)
        ax.axhline(0, color='k', lw=0.6)
        ax.set_ylabel(f'{name} [ug]')
        ax.grid(alpha=0.3, axis='y')
        ax.set_title(f'{name}: RMS {np.sqrt(np.mean(v ** 2)):.1f} ug, max |.| '
                     f'{np.abs(v).max():.1f} ug', fontsize=9)
    axs[1].set_xticks(x, labels, fontsize=7 if len(x) < 30 else 5)
    axs[1].set_xlabel('hold (index, face)')
    fig.suptitle('Gravity residual |mean specific force| - g per hold', fontsize=10)
    return fig


def coverage_map(windows):
    """Gravity directions of the holds on an azimuth/elevation map, faces marked."""
    rows = _hold_table(windows)
    fig, ax = _subplots(figsize=(8, 4.2))
    for name, az in (('+x', 0), ('-x', 180), ('-x', -180), ('+y', 90), ('-y', -90)):
        ax.plot(az, 0, 's', ms=14, mfc='none', mec='0.6')
        ax.annotate(name, (az, 0), textcoords='offset points', xytext=(9, 7), fontsize=8,
                    color='0.4')
    for name, el in (('+z (any azimuth)', 90), ('-z (any azimuth)', -90)):
        ax.axhline(el, color='0.6', ls='--', lw=0.8)
        ax.annotate(name, (-178, el), textcoords='offset points', fontsize=8, color='0.4',
                    xytext=(0, -11 if el > 0 else 4))
    if rows:
        dirs = np.array([r[3] / np.linalg.norm(r[3]) for r in rows])
        az, el = (np.atleast_1d(v) for v in _azel(dirs))
        temps = [float(windows.temp[windows.hold == r[0]].mean()) if windows.n_inputs
                 else 0.0 for r in rows]
        tilted = np.array([r[4] == 'tilted' for r in rows])
        sc = ax.scatter(az[~tilted], el[~tilted], c=np.array(temps)[~tilted], marker='o',
                        s=40, cmap='coolwarm', label='face hold', vmin=min(temps),
                        vmax=max(temps))
        if tilted.any():
            ax.scatter(az[tilted], el[tilted], c=np.array(temps)[tilted], marker='^', s=50,
                       cmap='coolwarm', label='tilted hold', vmin=min(temps), vmax=max(temps))
        if windows.n_inputs:
            fig.colorbar(sc, ax=ax, label='mean temperature of the hold')
        ax.legend(fontsize=8, loc='lower center')
    ax.set_xlim(-185, 185)
    ax.set_ylim(-95, 95)
    ax.set_xlabel('azimuth of gravity-up in the sensor frame [deg] (atan2(y, x))')
    ax.set_ylabel('elevation [deg] (asin z)')
    ax.set_title('Pose coverage: measured gravity directions (squares: the six faces)',
                 fontsize=10)
    ax.grid(alpha=0.3)
    return fig


def _azel(u):
    u = np.atleast_2d(u)
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    el = np.degrees(np.arcsin(np.clip(u[:, 2], -1, 1)))
    return (az[0], el[0]) if len(u) == 1 else (az, el)


def model_curves(cal, which):
    """Without windows: the fitted curve and +-1 sigma band over the valid range per axis."""
    model = cal.accel if which == 'accel' else cal.gyro
    tg = _grid(cal, which)
    std = model.predict_std(tg)
    true = np.zeros_like(tg)
    if which == 'accel':
        removed = _forward(model, true, tg) - true
        scale, unit = UG, 'ug'
    else:
        aux = {'accel': np.tile([0, 0, cal.gravity], (len(tg), 1))}
        removed = true - model.correct(true, tg, aux=aux)
        scale, unit = 180 / np.pi * 3600, 'deg/h'
    fig, axs = _subplots(1, 3, figsize=(11, 3.0))
    idx = cal.accel_input if which == 'accel' else cal.gyro_input
    for i, ax in enumerate(axs):
        ax.plot(tg[:, i], removed[:, i] * scale, color=COLORS[i], label='model (zero input)')
        if std is not None:
            ax.fill_between(tg[:, i], (removed[:, i] - std[:, i]) * scale,
                            (removed[:, i] + std[:, i]) * scale, color=COLORS[i], alpha=0.2,
                            lw=0, label='+-1 sigma')
        ax.set_title(f'{which} {AXES[i]}', fontsize=10)
        ax.set_xlabel(f'input [{cal.inputs[idx[i]].unit}] (plotted = valid range)')
        ax.grid(alpha=0.3)
        if i == 0:
            ax.set_ylabel(f'removed error [{unit}]')
            ax.legend(fontsize=7)
    fig.suptitle(f'{which}: fitted thermal error over the valid range (no windows: pass '
                 '--log or --windows for the data)', fontsize=10)
    return fig


def allan_figure(result, sensor):
    """Allan deviation per axis of one sensor with the fitted -1/2 and +1/2 lines."""
    from ..estimation.allan import UNITS
    axes = result['axes'][sensor]
    fig, ax = _subplots(figsize=(9, 5))
    for i, a in enumerate(axes):
        c = a.curve
        ax.loglog(c.tau, c.adev, 'o-', ms=3, lw=1, color=COLORS[i], label=f'{AXES[i]}')
        ax.loglog(c.tau, a.line_n(c.tau), ':', color=COLORS[i], lw=1)
        if a.k_observable:
            ax.loglog(c.tau, a.line_k(c.tau), '--', color=COLORS[i], lw=1)
            ax.loglog([3.0], [a.K], '*', ms=12, color=COLORS[i])
        ax.loglog([1.0], [a.N], 'o', ms=9, mfc='none', color=COLORS[i])
        ax.loglog([a.tau_B], [a.B * 0.664], 'v', ms=9, color=COLORS[i])
    lo = min(a.curve.adev.min() for a in axes)
    hi = max(a.curve.adev.max() for a in axes)
    ax.set_ylim(lo / 3, hi * 3)
    ax.plot([], [], 'k:', label='fitted slope -1/2 (N at tau = 1 s, circle)')
    ax.plot([], [], 'k--', label='fitted slope +1/2 (K at tau = 3 s, star)')
    ax.plot([], [], 'kv', label='flat minimum (B = min / 0.664)')
    ax.set_xlabel('tau [s]')
    ax.set_ylabel(f'overlapping Allan deviation [{UNITS[sensor]["adev"]}]')
    ax.set_title(f'{sensor}: Allan deviation ({result["kind"]}, {result["still_seconds"]:.0f} s '
                 f'at {result["rate_hz"]:.1f} Hz)', fontsize=10)
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    return fig
