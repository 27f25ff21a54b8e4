"""Where the first day's accelerometer drift comes from (first activated calibration).

Usage: first_day_sources.py SEED RUN_SEED_DIR FIT_PKL [LABEL]

Scores every first-day stop as bench/lifelong_first_day.py does (stop_chunks, stop_error,
registry_timeline, active_index, drift_rms); for the stops under the FIRST calibration it
prints per-stop T, T_lag, range, tilt and per-axis errors; decomposes the day's drift; and
re-scores those stops with counterfactual calibrations of the same family (quadratic in
T_lag:2000, offset-only, temperature-weighted) refitted on the captured fit windows
(capture_first_fit.py) with the truth removed (tilt-free), on T instead of T_lag, etc.
"""
import copy
import re
import os
import pickle
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from bench_lifelong import (active_index, drift_rms, registry_timeline,  # noqa: E402
                            scored_stops, stop_error)
from thermal_imu_calib.estimation.hysteresis import Features, fit_spec, Spec  # noqa: E402
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402
from thermal_imu_calib.sim.schedule import first_order_lag  # noqa: E402
from thermal_imu_calib.thermal_input import lag_windows, parse_history_key  # noqa

seed, run, pkl = int(sys.argv[1]), sys.argv[2], sys.argv[3]
label = sys.argv[4] if len(sys.argv) > 4 else run
TAU = 2000.0
m = robot_month(seed, days=30.0)
g = m.gravity
base = m.start_ns * 1e-9
starts, cals = registry_timeline(run, m.start_ns)
cal0 = cals[0]
acc0 = cal0.accel
vr = cal0.valid_range[0]
sr = cal0.sensor_range.get('accel', cal0.valid_range)[0]
print(f'== seed {seed} {label}: first calibration active {starts[0] / 3600:.2f} h .. '
      f'{starts[1] / 3600:.2f} h; accel {acc0.kind} base {getattr(acc0, "base", "T")} '
      f'T0 {acc0.t0[0]:.2f}; valid_range {vr[0]:.2f}..{vr[1]:.2f}, accel range '
      f'{sr[0]:.2f}..{sr[1]:.2f} degC')
print('   coeffs (rows c0,c1,c2; cols x,y,z) m/s^2/degC^j:\n', np.array2string(
    acc0.coeffs, precision=5))

# continuous physical lag of the true temperature (grid)
tg = np.arange(len(m.temp_grid)) * m.grid_dt
phys_lag = first_order_lag(m.temp_grid, m.grid_dt, TAU)

# ---------------------------------------------------------------- first-day stops
rows = []
for seg, ch in scored_stops(m, 0.0, DAY):
    s = seg.stop
    k = active_index(starts, s.t0)
    rows.append(dict(seg=seg, ch=ch, k=k, s=s))

# window-level lag over the day's chunks, as the fit computes T_lag (lag_windows, restart
# at gaps > 1800 s). Chunk times: stop-relative chunk spans approximated by the stop's
# still span cut in 30-s pieces (the means' mid times).
ct0, ct1, ctemp, owner = [], [], [], []
for i, r in enumerate(rows):
    seg, ch = r['seg'], r['ch']
    t = (seg.imu.stamp_ns[seg.still] - m.start_ns) * 1e-9
    cid = np.floor((t - t[0]) / 30.0).astype(int)
    for c in np.unique(cid):
        tt = t[cid == c]
        ct0.append(tt[0])
        ct1.append(tt[-1])
    ctemp.extend(ch['temp'][:, 0])
    owner.extend([i] * len(ch['n']))
ct0, ct1, ctemp, owner = map(np.asarray, (ct0, ct1, ctemp, owner))
lagw = lag_windows(ct0, ct1, ctemp[:, None], [TAU])[:, 0]
_lagc = {}


def chunk_lag(key):
    """Per stop, the window-level lag (lag_windows) of its chunks for a history key."""
    if key not in _lagc:
        taus = parse_history_key(key)
        y = ctemp[:, None]
        for tau in taus:
            y = lag_windows(ct0, ct1, y, [tau])
        _lagc[key] = [y[owner == i, 0] for i in range(len(rows))]
    return _lagc[key]


for i, r in enumerate(rows):
    r['i'] = i
    w = r['ch']['n'] / r['ch']['n'].sum()
    r['T'] = float(w @ r['ch']['temp'][:, 0])
    r['Tlag_w'] = float(w @ lagw[owner == i])
    r['Tlag_chunks'] = lagw[owner == i]
    r['Tlag_p'] = float(np.interp(0.5 * (r['s'].t0 + r['s'].t1), tg, phys_lag))
    c = r['s'].c_nb
    r['tilt'] = float(np.degrees(np.arccos(np.clip(c[2, 2], -1, 1))))
    r['fh'] = g * c[2, :2]       # true horizontal specific force (m/s^2)
    _, r['raw'] = stop_error(None, r['ch'])
    _, r['act'] = stop_error(cals[r['k']] if r['k'] >= 0 else None, r['ch'])


def err_with(cal, r, history=False):
    """Accel error vector of a stop with ``cal`` at equilibrium (bench) or with T_lag."""
    ch = r['ch']
    if not history:
        return stop_error(cal, ch)[1]
    hist = {k: chunk_lag(k)[r['i']][:, None] for k in cal.accel.history_keys}
    res = cal.apply(ch['accel'], ch['gyro'], ch['temp'], history=hist)
    w = ch['n'] / ch['n'].sum()
    return w @ (res.accel - ch['f'])


raw_all = np.array([r['raw'] for r in rows])
act_all = np.array([r['act'] for r in rows])
med_raw, med_act = np.median(raw_all, 0), np.median(act_all, 0)
k0 = [i for i, r in enumerate(rows) if r['k'] == 0]
print(f'first day: {len(rows)} scored stops, {len(k0)} under the first calibration, '
      f'{sum(r["k"] < 0 for r in rows)} raw (before), {sum(r["k"] > 0 for r in rows)} later')
print(f'drift: active {drift_rms(act_all) * 1e3:.1f}, raw {drift_rms(raw_all) * 1e3:.1f} '
      'mm/s^2')
print('\nper stop under the first calibration (mm/s^2; errors less the day median of that '
      'policy; off = compensated - raw = -model offset)')
print(f'{"#":>3} {"t0 h":>6} {"dur":>5} {"T":>6} {"Tlag_w":>6} {"Tlag_p":>6} {"in":>3} '
      f'{"tilt":>5} {"slope":>5} {"g*tilt x,y":>12} | {"raw x":>6} {"y":>6} {"z":>6} | '
      f'{"comp x":>6} {"y":>6} {"z":>6} | {"off x":>6} {"y":>6} {"z":>6}')
for i in k0:
    r = rows[i]
    inr = sr[0] <= r['T'] <= sr[1]
    e, a = (r['raw'] - med_raw) * 1e3, (r['act'] - med_act) * 1e3
    off = (r['act'] - r['raw']) * 1e3
    print(f'{r["s"].index:3d} {r["s"].t0 / 3600:6.2f} {r["s"].t1 - r["s"].t0:5.0f} '
          f'{r["T"]:6.2f} {r["Tlag_w"]:6.2f} {r["Tlag_p"]:6.2f} {"y" if inr else "N":>3} '
          f'{r["tilt"]:5.2f} {r["s"].slope_deg > 0!s:>5} '
          f'{r["fh"][0] * 1e3:6.0f}{r["fh"][1] * 1e3:6.0f} | '
          f'{e[0]:6.1f} {e[1]:6.1f} {e[2]:6.1f} | {a[0]:6.1f} {a[1]:6.1f} {a[2]:6.1f} | '
          f'{off[0]:6.1f} {off[1]:6.1f} {off[2]:6.1f}')

# ---------------------------------------------------------------- decomposition
d = act_all - med_act
tot = np.sum(d ** 2)
inr = np.array([sr[0] <= r['T'] <= sr[1] for r in rows])
ks = np.array([r['k'] for r in rows])


def share(mask, axes):
    return np.sum(d[mask][:, axes] ** 2) / tot


print(f'\nshare of the day\'s drift^2 (active, {drift_rms(act_all) * 1e3:.1f} mm/s^2):')
for name, mask in (('first cal, T in accel range', (ks == 0) & inr),
                   ('first cal, T out of range', (ks == 0) & ~inr),
                   ('raw (before first cal)', ks < 0), ('later cals', ks > 0)):
    print(f'  {name:30s} n={mask.sum():2d}: x,y {share(mask, [0, 1]) * 100:5.1f} %, '
          f'z {share(mask, [2]) * 100:5.1f} %')

# ---------------------------------------------------------------- counterfactuals
with open(pkl, 'rb') as f:
    cap = pickle.load(f)
fit = cap['fit']
_top = f'c{acc0.order}'   # the highest power the file stores
assert np.allclose(cap['active']['accel']['parameters'][_top]['value'],
                   acc0.coeffs[acc0.order]), 'captured fit is not this run\'s first calibration'
# true specific force of each fit window: the stop it lies in (still: f_b = g C[2, :])
tmid = 0.5 * (fit.t0 + fit.t1) - base
fb = np.zeros((len(fit), 3))
hold_stop = {}
for j, t in enumerate(tmid):
    s = next(s for s in m.stops if s.t0 - 1 <= t <= s.t1 + 1)
    fb[j] = g * s.c_nb[2]
    hold_stop[int(fit.hold[j])] = s
feats = Features(fit, [0, 0, 0])
t0 = acc0.t0[0]
rows_all = np.ones(len(fit), bool)
note = ' '.join(cap['active'].get('notes') or [])
wm = re.search(r"accel: [^']*?, (time|temperature)-weighted", note)
WEIGHT = wm.group(1) if wm else 'time'
BASE = tuple(parse_history_key(acc0.base)) if getattr(acc0, 'base', '') else ()
TERMS = tuple((k, tuple(parse_history_key(h))) for k, h in getattr(acc0, 'terms', []))
ORDER = acc0.order
spec_lag = Spec(ORDER, BASE, TERMS, WEIGHT)              # the file's spec
spec_T = Spec(ORDER, (), TERMS, WEIGHT)                  # same, reading as base
print(f'file spec: {spec_lag.label()}')


def refit(spec, y, per_hold=False):
    """Same family: (poly coeffs (order+1, 3), term coeffs (nt, 3)); per_hold: one free
    constant per hold, so only within-hold variation identifies the thermal terms."""
    if not per_hold:
        c, _ = fit_spec(feats, spec, y, rows_all, t0)
        c[0] = 0.0
        return c[:spec.order + 1], c[spec.order + 1:]
    a = feats.design(spec, t0)[:, :, 1:]            # powers 1..order, then the terms
    hs = np.unique(fit.hold)
    dmy = (fit.hold[:, None] == hs[None]).astype(float)
    c = np.zeros((a.shape[-1] + 1, 3))
    for i in range(3):
        from thermal_imu_calib.estimation.hysteresis import fit_weights
        w = np.sqrt(fit_weights(feats.temp[:, i], spec.weighting, rows_all))
        A = np.hstack([a[:, i], dmy]) * w[:, None]
        sol, *_ = np.linalg.lstsq(A, y[:, i] * w, rcond=None)
        c[1:, i] = sol[:a.shape[-1]]
    return c[:spec.order + 1], c[spec.order + 1:]


# the stops scored with cal0's accel model (later swaps may keep it: gyro only)
same = [i for i, r in enumerate(rows) if r['k'] >= 0 and
        cals[r['k']].accel.kind == acc0.kind and
        np.array_equal(cals[r['k']].accel.coeffs, acc0.coeffs)]
print(f'\n{len(same)} first-day stops are scored with the first calibration\'s accel model '
      f'(calibrations {sorted(set(rows[i]["k"] for i in same))}); '
      f'{sum(r["k"] < 0 for r in rows)} with the raw output before it')
c_raw = refit(spec_lag, fit.accel)
print(f'refit of the captured windows with the file spec: max |diff| to the file '
      f'{np.max(np.abs(c_raw[0][1:] - acc0.coeffs[1:])):.2e} (poly), '
      f'{np.max(np.abs(c_raw[1] - acc0.term_coeffs)) if TERMS else 0:.2e} (terms)')
y_true = fit.accel - fb                      # sensor error only (tilt removed)
variants = {
    'file (as run)': ((acc0.coeffs, getattr(acc0, 'term_coeffs', None)), True),
    'refit on truth (tilt removed)': (refit(spec_lag, y_true), True),
    'refit on tilt alone (y = g*C[2])': (refit(spec_lag, fb), True),
    'refit raw, per-hold constants': (refit(spec_lag, fit.accel, True), True),
    'no thermal terms (c1=c2=0)': ((np.zeros((ORDER + 1, 3)), np.zeros((len(TERMS), 3))),
                                   True),
}

if BASE:
    variants.update({
        'refit on raw, base T (no lag)': (refit(spec_T, fit.accel), False),
        'refit on truth, base T (no lag)': (refit(spec_T, y_true), False),
        'refit raw, per-hold consts, base T': (refit(spec_T, fit.accel, True), False)})


def c2_text(poly):
    """The quadratic coefficients in mm/s^2/degC^2 ('-' for a linear model)."""
    poly = np.asarray(poly)
    return np.array2string(poly[2] * 1e3, precision=1) if len(poly) > 2 else '-'


def make_cal(coeffs, lag, clamp=None):
    c = copy.deepcopy(cal0)
    coeffs, terms = coeffs
    c.accel.poly.coeffs = np.array(coeffs, float)
    if TERMS:
        c.accel.term_coeffs = np.array(terms, float).reshape(len(TERMS), 3)
    if not lag:
        c.accel.base = ''
    if clamp is not None:
        c.sensor_range = {'accel': np.array([clamp])}
    return c


span = fit.temp[:, 0].min(), fit.temp[:, 0].max()
print(f'fit windows reading span {span[0]:.2f}..{span[1]:.2f} degC; the file\'s accel range '
      f'{sr[0]:.2f}..{sr[1]:.2f}')
print(f'\nthe day\'s drift (mm/s^2) with those {len(same)} stops re-scored by a variant of the '
      'accel model (gyro as run, other stops as run); ranges: the file\'s (+1 degC) or the '
      'collected span; input: reading (bench, equilibrium) or window-level T_lag (stream)')
print(f'{"variant":34s} {"c1 x,y,z mm/s^2/C":>22} {"c2 x,y,z mm/s^2/C^2":>22} | '
      f'{"+1C,T":>6} {"span,T":>6} {"+1C,lag":>7} {"span,lag":>8} | step x,y at +1C')
for name, (coef, lag) in variants.items():
    out = []
    for clamp in (None, span):
        for hist in (False, True):
            if hist and not lag:
                out.append(float('nan'))
                continue
            c = make_cal(coef, lag, clamp)
            e = act_all.copy()
            for i in same:
                e[i] = err_with(c, rows[i], hist)
            out.append(drift_rms(e))
            if clamp is None and not hist:
                before = [i for i, r in enumerate(rows) if r['k'] < 0]
                step = np.median(e[same], 0) - np.median(e[before], 0)
        dtx = '' if not TERMS else (
            ' d0 ' + np.array2string(np.asarray(coef[1])[0] * 1e3, precision=0))
    print(f'{name:34s} {np.array2string(np.array(coef[0][1]) * 1e3, precision=1):>22} '
          f'{c2_text(coef[0]):>22} | {out[0] * 1e3:6.1f} '
          f'{out[2] * 1e3:6.1f} {out[1] * 1e3:7.1f} {out[3] * 1e3:8.1f} | '
          f'{step[0] * 1e3:6.1f} {step[1] * 1e3:6.1f}{dtx}')
e = act_all.copy()
for i in same:
    e[i] = rows[i]['raw']
print(f'{"raw output for those stops":34s} {"":22} {"":22} | {drift_rms(e) * 1e3:6.1f}')
# the true thermal drift relative to T0 (what a perfect offset-only model removes)
dev = m.device
fz = np.array([[0, 0, g]])


def true_rel(T):
    from thermal_imu_calib.sim.devices import accel_forward
    T = np.atleast_1d(T)
    f = np.repeat(fz, len(T), 0)
    return (accel_forward(f, np.repeat(T[:, None], 3, 1), dev.t0, dev.k0, dev.b0, dev.s,
                          dev.thermal)
            - accel_forward(f, np.full((len(T), 3), t0), dev.t0, dev.k0, dev.b0, dev.s,
                            dev.thermal))


for nm, lim in (('true thermal rel. T0, extrapolated', None),
                ('true thermal rel. T0, clamped +1C', (sr[0], sr[1]))):
    e = act_all.copy()
    for i in same:
        T = rows[i]['ch']['temp'][:, 0]
        if lim is not None:
            T = np.clip(T, *lim)
        w = rows[i]['ch']['n'] / rows[i]['ch']['n'].sum()
        e[i] = rows[i]['raw'] - w @ true_rel(T)
    print(f'{nm:34s} {"":22} {"":22} | {drift_rms(e) * 1e3:6.1f}')
print('true thermal change rel. T0 (mm/s^2) x,y,z at 9.45 / 17 / 22 degC:',
      *(np.array2string(true_rel(T)[0] * 1e3, precision=1) for T in (sr[1], 17.0, 22.0)))

# ---------------------------------------------------------------- training holds
print('\ntraining holds of the first estimate (window means, sample-weighted; mm/s^2):')
print(f'{"hold":>4} {"stop":>4} {"t0 h":>6} {"win":>3} {"T lo..hi":>12} {"Tlag lo..hi":>12} '
      f'{"tilt":>5} {"g*C x":>6} {"g*C y":>6} | {"mean a x":>8} {"y":>6} {"z":>8} | '
      f'{"a-f x":>6} {"y":>6} {"z":>6} | {"fit off x":>9} {"y":>6} {"z":>6}')
Tl = feats.lagged(BASE)[:, 0] if BASE else feats.temp[:, 0]
mod = np.einsum('map,pa->ma', feats.design(spec_lag, t0),
                np.vstack([acc0.coeffs] + ([acc0.term_coeffs] if TERMS else [])))
for h in np.unique(fit.hold):
    mk = fit.hold == h
    w = fit.n[mk] / fit.n[mk].sum()
    s = hold_stop[int(h)]
    a = w @ fit.accel[mk]
    af = w @ y_true[mk]
    of = w @ mod[mk]
    print(f'{h:4d} {s.index:4d} {s.t0 / 3600:6.2f} {mk.sum():3d} '
          f'{fit.temp[mk, 0].min():5.2f}..{fit.temp[mk, 0].max():5.2f} '
          f'{Tl[mk].min():5.2f}..{Tl[mk].max():5.2f} {np.degrees(np.arccos(s.c_nb[2, 2])):5.2f} '
          f'{g * s.c_nb[2, 0] * 1e3:6.1f} {g * s.c_nb[2, 1] * 1e3:6.1f} | '
          f'{a[0] * 1e3:8.1f} {a[1] * 1e3:6.1f} {a[2] * 1e3:8.1f} | '
          f'{af[0] * 1e3:6.1f} {af[1] * 1e3:6.1f} {af[2] * 1e3:6.1f} | '
          f'{of[0] * 1e3:9.1f} {of[1] * 1e3:6.1f} {of[2] * 1e3:6.1f}')
# how much of the per-hold level scatter the tilt explains
lv = np.array([fit.n[fit.hold == h] @ fit.accel[fit.hold == h] / fit.n[fit.hold == h].sum()
               for h in np.unique(fit.hold)])
tf = np.array([g * hold_stop[int(h)].c_nb[2] for h in np.unique(fit.hold)])
print('per-hold level scatter (std across holds, mm/s^2) x,y,z: mean accel',
      np.array2string(np.std(lv, 0) * 1e3, precision=1), '; g*tilt part',
      np.array2string(np.std(tf, 0) * 1e3, precision=1), '; a - f (sensor)',
      np.array2string(np.std(lv - tf, 0) * 1e3, precision=1))
# the truth's thermal slope over the span (x, y, z), for scale
ta = m.true_calibration(0.0).accel
Ts = np.linspace(span[0], span[1], 2)
fz = np.tile([0, 0, g], (2, 1))
tr = ta.forward(fz, np.repeat(Ts[:, None], 3, 1)) if hasattr(ta, 'forward') else None
if tr is not None:
    print('true raw change over the fit span (mm/s^2) x,y,z:',
          np.array2string((tr[1] - tr[0]) * 1e3, precision=2))

# ---------------------------------------------------------------- every first-day stop
print('\nevery first-day stop: active calibration k, T, in its accel range, tilt, error of '
      'the active less its day median and compensated - raw (mm/s^2)')
print(f'{"#":>3} {"k":>2} {"t0 h":>6} {"T":>6} {"in":>3} {"tilt":>5} | {"act-med x":>9} '
      f'{"y":>6} {"z":>6} | {"off x":>6} {"y":>6} {"z":>6}')
for r in rows:
    c = cals[r['k']] if r['k'] >= 0 else None
    if c is None:
        inr = '-'
    else:
        rr = c.sensor_range.get('accel', c.valid_range)[0]
        inr = 'y' if rr[0] <= r['T'] <= rr[1] else 'N'
    a = (r['act'] - med_act) * 1e3
    off = (r['act'] - r['raw']) * 1e3
    print(f'{r["s"].index:3d} {r["k"]:2d} {r["s"].t0 / 3600:6.2f} {r["T"]:6.2f} {inr:>3} '
          f'{r["tilt"]:5.2f} | {a[0]:9.1f} {a[1]:6.1f} {a[2]:6.1f} | {off[0]:6.1f} '
          f'{off[1]:6.1f} {off[2]:6.1f}')
for k in range(min(6, len(cals))):
    c = cals[k]
    rr = c.sensor_range.get('accel', c.valid_range)[0]
    print(f'cal {k}: from {starts[k] / 3600:6.2f} h, accel {c.accel.kind} '
          f'{getattr(c.accel, "base", "")} T0 {c.accel.t0[0]:.2f} range {rr[0]:.2f}..'
          f'{rr[1]:.2f} coeffs c1 {np.array2string(c.accel.coeffs[1] * 1e3, precision=1)}'
          + (f' c2 {np.array2string(c.accel.coeffs[2] * 1e3, precision=1)}'
             if c.accel.coeffs.shape[0] > 2 else ''))

# does the fitted polynomial interpolate the holds' levels (tilt)? per-hold, centred
hs = np.unique(fit.hold)
lvl = np.array([fit.n[fit.hold == h] @ fit.accel[fit.hold == h] / fit.n[fit.hold == h].sum()
                for h in hs])
fo = np.array([fit.n[fit.hold == h] @ mod[fit.hold == h] / fit.n[fit.hold == h].sum()
               for h in hs])
tl = np.array([g * hold_stop[int(h)].c_nb[2] for h in hs])
for ax, nm in enumerate('xyz'):
    a_, f_, t_ = (v[:, ax] - v[:, ax].mean() for v in (lvl, fo, tl))
    r2 = 1 - np.sum((a_ - f_) ** 2) / np.sum(a_ ** 2)
    print(f'axis {nm}: per-hold level (centred) {np.array2string(a_ * 1e3, precision=1)}, '
          f'g*tilt part {np.array2string(t_ * 1e3, precision=1)}, fitted offset '
          f'{np.array2string(f_ * 1e3, precision=1)}: fit explains {r2 * 100:.0f} % of the '
          'level scatter')
print('fitted offset at the clamp edges (rel. T0; mm/s^2): file range',
      *(np.array2string(acc0.poly.offset(np.full((1, 3), T))[0] * 1e3, precision=1)
        for T in (sr[0], sr[1])), '; collected span',
      *(np.array2string(acc0.poly.offset(np.full((1, 3), T))[0] * 1e3, precision=1)
        for T in span))
