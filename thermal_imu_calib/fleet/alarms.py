"""Drift alarms of a calibration registry: a unit's parameters compared over time.

History and alarms (``assess``): a unit's accelerometer bias and scale factor, read off
every model family the same way (``models/alarm_terms.py``: their value and temperature
coefficients about the model's T0, index columns ``accel.alarm_b0.x`` ..
``accel.alarm_k2.z`` with stds; registries written before them: the field model's db0,
dk0 and polynomial), are carried to a common temperature (stds propagated as independent)
and tested per axis: every change between a calibration and the unit's previous one of
the same family of alarm terms (step test) and the slope over all of the unit's
calibrations of its latest family (trend test, constant vs line), each as z = value /
sigma. A calibration of several orientations carries the field model's terms on its
holds whatever model compensates (``estimation/alarm_yardstick.py``), so a unit's
chain does not break when ``auto`` changes family. A yardstick that estimated the
non-orthogonality S (no lab prior) also stores its terms given S: a unit's bias changes
and trends are then tested at S pooled over its calibrations (``pooled_s``), so S's
uncertainty, which six-face logs leave near its prior, cancels between logs with similar
gains instead of widening every test (the scale factor, second order in S, with its
curvature on S; calibrations without it keep its own stds). All tests of the fleet form one
family: a unit is flagged when any |z| passes the Sidak threshold
that keeps the family-wise false-alarm rate of the whole fleet at ``FAMILY_RATE`` (1 %)
when the stds are honest (checked on simulated fleets, ``STD_SCALE``). A
latest residual more than ``RESIDUAL_MADS`` robust standard deviations above the fleet
median is ``out of family``.

The gyro bias (``gyro.alarm_b0.x`` .. with stds, any gyro family, a g-sensitive one at
zero g) is tested the same way, per gyro model family, compared where the difference of
the two calibrations is sharpest (``_best_common``), and in units of the registry's own
spread of its gyro tests (``gyro_scale``: the gyro fit's stds leave out the horizontal
earth rate, so they are not honest), when there are at least ``MIN_GYRO_TESTS`` of them.
A bias an offset model defines only relative to its T0 (one orientation: the pose absorbs
the accelerometer's) is not tested (``models.alarm_terms.relative_bias``). No ROS import.
"""

import numpy as np

from ..estimation.alarm_yardstick import terms_of
from ..models.alarm_terms import bias_scale_terms
from . import pooled_s
from .pooled_s import cell as _f
from .times import parse_time

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
#: the gyroscope's: its bias only (``GYRO_ALARM_ON``), tested as 'gb' (gyro db0)
GYRO_STEM = 'gyro.alarm_'
GYRO_ALARM_ON = ('gb',)
#: label prefix of the gyro tests (``unit_tests``)
GYRO_PREFIX = 'gyro '
#: fewest gyro-bias tests in a registry for its empirical null (``gyro_scale``); fewer:
#: the gyro is not tested, and the rule says so
MIN_GYRO_TESTS = 12
#: factor on the fit's std of d{name}0 (1: the fit's own). Checked on the stable units of
#: 20 simulated fleets (bench_fleet.py alarms, 8 x 3, seeds 0-19): their z with the fit's
#: std are N(0, 1) (Kolmogorov-Smirnov p 0.52-0.88; std 1.05 +- 0.03 over 477 changes, 1.02-
#: 1.09 over 237 trends; see docs/fleet.md), so no correction is applied. They are honest
#: only as far as the accelerometer's non-orthogonality S is known: with S = identity (no
#: lab prior) and a datasheet's cross-axis sensitivity (up to 2e-2), simulated stable units'
#: z had std up to 10 (``bench/alarm_truth_z.py``, docs/fleet.md). Since 2026-12-03 the
#: yardstick estimates S when no prior gives it: on unseen fleet seed 96 z std 0.77-1.07
#: for either S, at 2.3-3.8x the bias stds (``alarm_yardstick.py``).
STD_SCALE = {'b': 1.0, 'k': 1.0}
#: index column naming the model kind the accelerometer's alarm terms come from
FAMILY_COLUMN = 'accel.alarm_family'
#: degC: a calibration whose accelerometer scale factor has no temperature terms, fitted
#: over a wider span of temperatures than this (the span below which no temperature term
#: is resolved, ``selection`` ORDER_SPAN[1]), has stds that leave out the scale factor's
#: thermal change: on the stable units of 5 simulated fleets no alarm bench used (seeds
#: 20-24, ``bench/fleet_family_switch.py``) the standard fit's changes had z std 3.6 / 4.3
#: (db0 / dk0), 3.1-4.1 across a switch to ``field``; its accelerometer is not tested
FLAT_SPAN_DEGC = 1.0


def alarm_columns(cal):
    """Return the index columns of the accel bias and scale, and gyro bias, terms (any family).

    ``accel.alarm_T0.x``, ``accel.alarm_b0.x`` (m/s^2), ``accel.alarm_b1.x`` (m/s^2/degC),
    ``accel.alarm_b2.x``, ``accel.alarm_k0.x`` (1) .. with ``_std``; ``gyro.alarm_T0.x``,
    ``gyro.alarm_b0.x`` (rad/s) .. with ``_std``; none for a model without a forward model
    or stds (``models.alarm_terms.bias_scale_terms``). The accelerometer's are those of
    the calibration's alarm yardstick when it has one (``fit.alarm_yardstick``: the field
    model on the same holds, ``estimation/alarm_yardstick.py``), else its model's;
    ``accel.alarm_family`` names the model kind they come from (the chain ``unit_tests``
    follows).
    """
    out = {}
    accel = terms_of(cal.fit) if cal.accel is not None else None
    if accel is None and cal.accel is not None:
        accel = bias_scale_terms(cal.accel)
        if accel is not None:
            accel['kind'] = cal.accel.kind
    if accel is not None:
        out[FAMILY_COLUMN] = accel['kind']
        out.update(pooled_s.columns(accel))
    gyro = bias_scale_terms(cal.gyro) if cal.gyro is not None else None
    for terms, stem, names in ((accel, ALARM_STEM, ALARM_ON), (gyro, GYRO_STEM, ('b',))):
        if terms is None:
            continue
        for i, a in enumerate(AXES):
            out[f'{stem}T0.{a}'] = float(terms['T0'][i])
            for name in names:
                for j in range(3):
                    out[f'{stem}{name}{j}.{a}'] = float(terms[name][i, j])
                    out[f'{stem}{name}{j}.{a}_std'] = float(terms[f'{name}_std'][i, j])
    return out


def _has_alarm_terms(row, stem=ALARM_STEM):
    return np.isfinite(_f(row, f'{stem}T0.x'))


def untested_accel(row):
    """Return True when the row's accelerometer terms are not tested (``FLAT_SPAN_DEGC``).

    Its scale factor is fitted (k0 has a std) without temperature terms (k1, k2 zero with
    std 0 on every axis) over holds spanning more than ``FLAT_SPAN_DEGC``.
    """
    if not _has_alarm_terms(row):
        return False
    k0 = [_f(row, f'{ALARM_STEM}k0.{a}_std') for a in AXES]
    kt = [_f(row, f'{ALARM_STEM}k{j}.{a}{x}') for j in (1, 2) for a in AXES for x in ('', '_std')]
    span = _f(row, 'temp_max') - _f(row, 'temp_min')
    return bool(np.nanmax(k0) > 0 and np.allclose(kt, 0.0, rtol=0, atol=0)
                and np.isfinite(span) and span > FLAT_SPAN_DEGC)


def reference(row, axis, name='b'):
    """Return the T0 (degC) of an index row's alarm terms on ``axis`` ('x', 'y', 'z').

    ``name`` 'gb': the gyro's (NaN when the row has none).
    """
    if name == 'gb':
        return _f(row, f'{GYRO_STEM}T0.{axis}')
    if _has_alarm_terms(row):
        return _f(row, f'{ALARM_STEM}T0.{axis}')
    return _f(row, f'accel.T0.{axis}')


def at_temperature(row, name, t_ref, memo=None):
    """Return (value, std) per axis of accel bias ('b'), scale ('k') or gyro bias ('gb').

    At ``t_ref`` degC: value = c0 + c1 dT + c2 dT^2 with dT = t_ref - T0: the alarm-term
    columns of any family, or (registries written before them, accelerometer) the field
    model's d{name}0, {name}1, {name}2; std from the three stds as independent.
    ``memo``: a dict shared by calls on rows that stay alive meanwhile (``_terms_memo``).
    """
    return _evaluate(_terms_memo(row, name, memo), t_ref)


def _terms_memo(row, name, memo):
    """Return ``row_terms(row, name)``, read once per row and name into ``memo`` (None: no memo).

    The key is the row's identity, so a memo lives no longer than one call over rows that
    are alive meanwhile (``unit_tests``): parsing the index strings was most of its time.
    """
    if memo is None:
        return row_terms(row, name)
    key = (id(row), name)
    if key not in memo:
        memo[key] = row_terms(row, name)
    return memo[key]


def row_terms(row, name):
    """Return (c, s, t0) of ``at_temperature``: (3 axes, 3 orders) values and stds, (3,) T0.

    A higher-order column a lower-order model leaves empty counts as 0 with std 0; a
    missing std of a value is NaN (the std at any temperature is then NaN).
    """
    gyro = name == 'gb'
    new = gyro or _has_alarm_terms(row)
    term = 'b' if gyro else name
    cols = ([f'alarm_{term}{j}' for j in range(3)] if new
            else [f'd{name}0', f'{name}1', f'{name}2'])
    which = 'gyro' if gyro else 'accel'
    c, s = np.zeros((3, 3)), np.zeros((3, 3))
    for i, a in enumerate(AXES):
        for j, col in enumerate(cols):
            v, sd = _f(row, f'{which}.{col}.{a}'), _f(row, f'{which}.{col}.{a}_std')
            if j and not np.isfinite(v):
                continue   # lower-order models leave the column empty
            c[i, j], s[i, j] = v, (sd if np.isfinite(sd) else np.nan)
    return c, s, np.array([reference(row, a, name) for a in AXES])


def _at_pooled_s(row, part, name, t_ref, s_star, memo):
    """Return ``pooled_s.at_temperature`` of a row's ``name`` terms at S* (``compare``)."""
    c, _, t0 = _terms_memo(row, name, memo)
    return pooled_s.at_temperature(c, part, name, t_ref, t0, s_star)


def _evaluate(terms, t_ref):
    """Return (value, std) of ``row_terms`` at ``t_ref`` degC, (..., 3) (vectorised over ...)."""
    c, s, t0 = terms
    dt = np.asarray(t_ref, float) - t0
    pw = dt[..., None] ** np.arange(3)
    return np.sum(c * pw, axis=-1), np.sqrt(np.sum((s * pw) ** 2, axis=-1))


def by_sensor(rows):
    """Return sensor -> its rows, oldest first."""
    by = {}
    for r in rows:
        by.setdefault(r['sensor'], []).append(r)
    return {s: sorted(rs, key=lambda r: r['time']) for s, rs in by.items()}


def _best_common(prev, cur, name, points=41, memo=None):
    """Return per axis the temperature (degC) where the difference of two rows is sharpest.

    On the overlap of the two calibrations' temperature spans (else between their T0) the
    one with the smallest std of the difference: a calibration from a few hours of holds
    (after a knock) is known near its own data only, and its polynomial's stds grow fast
    away from them. The choice depends on the stds, not on the values.
    """
    t_prev, t_cur = _terms_memo(prev, name, memo), _terms_memo(cur, name, memo)
    t0 = np.array([t_prev[2], t_cur[2]])
    lo = max(_f(prev, 'temp_min'), _f(cur, 'temp_min'))
    hi = min(_f(prev, 'temp_max'), _f(cur, 'temp_max'))
    if not (np.isfinite(lo) and np.isfinite(hi) and hi >= lo):
        lo, hi = t0.min(0), t0.max(0)
    grid = np.linspace(np.broadcast_to(lo, 3), np.broadcast_to(hi, 3), points)   # (p, 3)
    sd = np.hypot(_evaluate(t_prev, grid)[1], _evaluate(t_cur, grid)[1])
    sd = np.where(np.isfinite(sd), sd, np.inf)
    return grid[np.argmin(sd, axis=0), np.arange(3)]


def compare(prev, cur, names=ALARM_ON, std_scale=None, memo=None, pooled=None):
    """Return {'db0': z (3,), ...}: consecutive change at a common temperature in sigmas.

    The common temperature is the mean of the two T0 per axis (the gyro bias 'gb': where
    the difference is sharpest, ``_best_common``); sigma is the std of the difference,
    each calibration's std multiplied by ``std_scale[name]`` (default ``STD_SCALE``; 1 for
    names it lacks). ``memo``: see ``at_temperature``. ``pooled``: the unit's pooled S
    (S*, Cov(S*), ``pooled_s.pool``): when both rows have their terms given S
    (``pooled_s.row_s``), the accelerometer's bias (and the scale factor with its
    curvature) is compared at S* (``pooled_s.can_pool``).
    """
    scale = STD_SCALE if std_scale is None else std_scale
    parts = [pooled_s.row_s_memo(r, memo) for r in (prev, cur)] if pooled is not None else [None]
    out = {}
    for name in names:
        t_ref = (_best_common(prev, cur, name, memo=memo) if name == 'gb' else
                 (_terms_memo(prev, name, memo)[2] + _terms_memo(cur, name, memo)[2]) / 2)
        if pooled_s.can_pool(name, parts):
            (v0, s0, g0), (v1, s1, g1) = (_at_pooled_s(r, p, name, t_ref, pooled[0], memo)
                                          for r, p in zip((prev, cur), parts))
            dg = g1 - g0
            var_s = np.einsum('am,mn,an->a', dg, pooled[1], dg)
            sd = scale.get(name, 1.0) * np.sqrt(s0 ** 2 + s1 ** 2 + var_s)
            out[f'd{name}0'] = np.divide(v1 - v0, sd, out=np.full(3, np.nan), where=sd > 0)
            continue
        v0, s0 = at_temperature(prev, name, t_ref, memo)
        v1, s1 = at_temperature(cur, name, t_ref, memo)
        sd = scale.get(name, 1.0) * np.sqrt(s0 ** 2 + s1 ** 2)
        # a term a family does not fit (an offset model's scale, std 0): no test (NaN)
        out[f'd{name}0'] = np.divide(v1 - v0, sd, out=np.full(3, np.nan), where=sd > 0)
    return out


def trend(rows, name, std_scale=None, memo=None, pooled=None):
    """Return z (3,) of the slope of d{name}0 over time (weighted least squares).

    All calibrations of one unit (>= 3, oldest first) carried to the mean of their T0 per
    axis; z = slope / std(slope) with weights 1 / (std_scale * std)^2. Under "constant"
    z is N(0, 1): z^2 is the chi-square drop from a constant to a line (1 dof).
    ``memo``: see ``at_temperature``. ``pooled``: see ``compare``; at S* (every row with
    its terms given S) the weights are the stds given S and the slope's variance also
    carries S*'s error, which the rows share (G Cov(S*) G^T).
    """
    scale = (STD_SCALE if std_scale is None else std_scale).get(name, 1.0)
    t0 = np.array([_terms_memo(r, name, memo)[2] for r in rows])            # (n, 3)
    t_ref = np.array([np.mean(t0[:, i]) for i in range(len(AXES))])
    t = np.array([parse_time(r['time']) for r in rows], float) / 86400e9   # days
    parts = [pooled_s.row_s_memo(r, memo) for r in rows] if pooled is not None else [None]
    given = pooled_s.can_pool(name, parts)
    if given:
        got = [_at_pooled_s(r, p, name, t_ref, pooled[0], memo) for r, p in zip(rows, parts)]
        vs = np.array([(v, sd) for v, sd, _ in got])                       # (n, 2, 3)
        gains = np.array([g for _, _, g in got])                           # (n, 3, 3)
    else:
        vs = np.array([at_temperature(r, name, t_ref, memo) for r in rows])
    sd = scale * vs[:, 1]
    ok = np.all(sd > 0, axis=0)      # an axis whose term has no std (not fitted): no test
    sd = np.where(ok, sd, 1.0)
    x, w = vs[:, 0], 1.0 / sd ** 2                                         # (n, 3)
    tm = (w * t[:, None]).sum(0) / w.sum(0)
    sxx = (w * (t[:, None] - tm) ** 2).sum(0)
    slope = (w * (t[:, None] - tm) * x).sum(0) / sxx
    if not given:
        return np.where(ok, slope * np.sqrt(sxx), np.nan)
    # var(slope) = a' (diag(sd^2) + G Cov G') a, a the slope's weights per row
    a = w * (t[:, None] - tm) / sxx                                         # (n, 3)
    ga = np.einsum('na,nam->am', a, gains) * scale                          # (3, 3)
    var = 1.0 / sxx + np.einsum('am,mn,an->a', ga, pooled[1], ga)
    return np.where(ok, slope / np.sqrt(var), np.nan)


def family_threshold(n_tests, family_rate=FAMILY_RATE):
    """Return the |z| a two-sided test must pass so ``n_tests`` keep ``family_rate`` overall.

    Sidak: per test p < 1 - (1 - family_rate)^(1 / n_tests). Sidak's inequality holds for
    two-sided tests of jointly normal z with any correlation, so the consecutive changes
    sharing a calibration and the trend of the same values need no independence.
    """
    from scipy.special import ndtri
    p = -np.expm1(np.log1p(-family_rate) / max(n_tests, 1))
    return float(-ndtri(p / 2))


def accel_family(row):
    """Return the family of a row's accelerometer alarm terms (its chain of changes).

    ``accel.alarm_family`` (the yardstick's or the model's kind); rows written before it:
    the accelerometer model's kind.
    """
    return row.get(FAMILY_COLUMN) or row.get('accel_model', '')


def _gyro_family(row):
    return row.get('gyro_model', '')


def unit_tests(rows, std_scale=None):
    """Return [(label, z)] of one unit's tests: every consecutive change and the trend.

    For each alarmed parameter (``ALARM_ON``) and axis: the change between a calibration
    and the unit's previous one of the same family of accelerometer alarm terms
    (``accel_family``: the field yardstick of any calibration of several orientations, so a
    change of the compensating model keeps the chain; a unit whose family changes keeps
    one chain per family), and (>= 3 calibrations of the latest
    family) the slope over all of them; the same for the gyro bias (``GYRO_ALARM_ON``,
    labels starting ``gyro``) over the gyro model families. Non-finite z (a missing std,
    a scale factor an offset model does not fit, a row without gyro terms) are left out,
    and so is the accelerometer of a row ``untested_accel`` names.
    """
    out, memo = [], {}       # each row's terms parsed once (``at_temperature``)
    accel_rows = [r for r in rows if not untested_accel(r)]
    pooled = pooled_s.unit_pools(accel_rows, accel_family, memo)
    for family, names, prefix, chain in ((accel_family, ALARM_ON, '', accel_rows),
                                         (_gyro_family, GYRO_ALARM_ON, GYRO_PREFIX, rows)):
        last = {}
        if not chain:
            continue
        for cur in chain:
            prev = last.get(family(cur))
            last[family(cur)] = cur
            if prev is None:
                continue
            z = compare(prev, cur, names, std_scale, memo,
                        pooled.get(family(cur)) if family is accel_family else None)
            out += [(f'{prefix}d{name[-1]}0 {a} changed {prev["time"]} -> {cur["time"]}',
                     z[f'd{name}0'][i]) for name in names for i, a in enumerate(AXES)]
        same = [r for r in chain if family(r) == family(chain[-1])]
        if len(same) >= 3:
            for name in names:
                z = trend(same, name, std_scale, memo,
                          pooled.get(family(chain[-1])) if family is accel_family else None)
                out += [(f'{prefix}d{name[-1]}0 {a} trend over {len(same)} '
                         f'calibrations {same[0]["time"]} .. {same[-1]["time"]}', z[i])
                        for i, a in enumerate(AXES)]
    return [(lbl, float(z)) for lbl, z in out if np.isfinite(z)]


def gyro_scale(tests, min_tests=MIN_GYRO_TESTS):
    """Return the empirical-null std of the gyro-bias z of a registry (None: too few).

    The gyro fit's own stds are not honest (on simulated fleets the stable units' gyro-
    bias z have std 1.09-1.11 and up to 1.48 in one fleet, docs/fleet.md; the horizontal
    earth rate, a per-hold nuisance without ``--latitude``, is not in them). So the gyro
    tests are put in units of their own spread: the robust std of all of them (1.4826 x
    median |z|, z centred at 0 under "no change"; never below 1), which a few real
    changes do not move (Efron's empirical null). It assumes most calibrations of the
    registry did not change. It fixes their width, not their far tail, which is heavier
    than normal (3 of 4791 stable-unit tests beyond 4 sigma on the 20 x 5 simulated
    fleets, docs/fleet.md).
    """
    z = np.abs([v for lbl, v in tests if lbl.startswith(GYRO_PREFIX)])
    if len(z) < min_tests:
        return None
    return max(1.0, 1.4826 * float(np.median(z)))


def scaled_tests(tests):
    """Return ({sensor: [(label, z)]} with the gyro z in units of ``gyro_scale``, scale).

    ``tests``: {sensor: ``unit_tests``}. Without a scale (too few gyro tests) the gyro
    tests are dropped.
    """
    g = gyro_scale([t for ts in tests.values() for t in ts])
    return {s: [(lbl, z / g) if lbl.startswith(GYRO_PREFIX) else (lbl, z)
                for lbl, z in ts if g or not lbl.startswith(GYRO_PREFIX)]
            for s, ts in tests.items()}, g


def rule_text(n_tests, z_c, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS,
              gyro=None, pooled_units=0):
    """Return the alarm rule in words, with the numbers of this fleet.

    ``gyro``: the gyro tests' empirical-null std (``gyro_scale``), 0 when there are too
    few to test the gyro, None when the registry has no gyro-bias terms; ``pooled_units``:
    units whose accelerometer terms are tested at their pooled S (``pooled_s``).
    """
    names = ', '.join(f'd{n}0' for n in ALARM_ON)
    if gyro:
        names += f' and the gyro bias (its z divided by their robust spread, {gyro:.2f})'
    text = (f'alarm rule: {names} per axis, every change between consecutive calibrations '
            f'and the linear trend over all of a unit\'s calibrations, in units of their '
            f'sigma; {n_tests} tests over the fleet, flagged when |z| > {z_c:.2f} (Sidak: '
            f'{100 * family_rate:g} % family-wise false-alarm rate for the whole fleet); or '
            f'the latest residual more than {residual_mads:g} robust sigma above the fleet '
            'median')
    if gyro == 0:
        text += (f'; the gyro bias is not tested (fewer than {MIN_GYRO_TESTS} gyro tests '
                 'to measure their spread)')
    if pooled_units:
        text += (f'; the accelerometer terms of {pooled_units} unit(s) whose calibrations '
                 'estimated the non-orthogonality S are compared at S pooled over the '
                 'unit\'s calibrations')
    return text


def assess(rows, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS, std_scale=None):
    """Return (sensor -> alarm strings, info) for index rows.

    info: the number of tests, the threshold, the rule, the notes, the gyro scale and
    ``unit_tests`` (sensor -> [(label, z)] as judged: gyro z scaled, ``scaled_tests``).
    """
    by = by_sensor(rows)
    raw = {s: unit_tests(rs, std_scale) for s, rs in by.items()}
    has_gyro = any(lbl.startswith(GYRO_PREFIX) for ts in raw.values() for lbl, _ in ts)
    tests, g_scale = scaled_tests(raw)
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
                 f'{p["time"]} -> {c["time"]}: '
                 + ('tested on the terms of the field model fitted to the same holds (the '
                    'alarm yardstick)' if accel_family(p) == accel_family(c) else
                    'that change is not tested (each family is compared with its own '
                    'previous calibration; pin the family, e.g. fleet calibrate --model '
                    'field, to test every step)')
                 for p, c in zip(rs, rs[1:]) if p['accel_model'] != c['accel_model']]
             + [f'accel alarm terms changed family {accel_family(p) or "-"} -> '
                f'{accel_family(c) or "-"} {p["time"]} -> {c["time"]} with the same model: '
                'that change is not tested (a yardstick that estimates the non-'
                'orthogonality S is compared only with others that do; calibrations '
                'before 2026-12-03 took S = identity)'
                for p, c in zip(rs, rs[1:]) if p['accel_model'] == c['accel_model']
                and accel_family(p) != accel_family(c)
                and not untested_accel(p) and not untested_accel(c)]
             + [f'accel of {r["time"]} not tested: its scale factor has no temperature '
                f'terms over {_f(r, "temp_max") - _f(r, "temp_min"):.1f} degC of holds, so '
                'its stds leave out the thermal change of the scale factor (pin a thermal '
                'family, e.g. fleet calibrate --model field)' for r in rs if untested_accel(r)]
             for s, rs in by.items()}
    info = {'tests': n, 'threshold_sigma': z_c, 'family_rate': family_rate, 'notes': notes,
            'rule': rule_text(n, z_c, family_rate, residual_mads,
                              (g_scale or 0.0) if has_gyro else None,
                              sum(any(pooled_s.has_given_s(r) for r in rs)
                                  for rs in by.values())),
            'gyro_scale': g_scale, 'unit_tests': tests,
            'max_abs_z': {s: max((abs(z) for _, z in t), default=np.nan)
                          for s, t in tests.items()}}
    return out, info


def alarms(rows, family_rate=FAMILY_RATE, residual_mads=RESIDUAL_MADS):
    """Return sensor -> list of alarm strings (empty list: no alarm); see ``assess``."""
    return assess(rows, family_rate, residual_mads)[0]
