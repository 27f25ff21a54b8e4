r"""Are the accelerometer alarm terms' stds honest? Each calibration against its simulated truth.

The fleet alarms (``fleet/alarms.py``) divide a change of a unit's bias / scale factor by
the stds of the two calibrations. The alarm bench (``bench_fleet.py alarms``) can only see
the changes; this bench looks at each calibration: stable units of the simulated fleet
(``fleet/simulate.py``, the ``demo`` scenario, one unit of the ``mems`` design per device
seed), each log calibrated with default options (``calibrate``, the fleet's defaults; only
``--gravity`` set to the simulation's, so the scale factors carry no gravity mismatch), and
per axis z = (term - truth) / std of the alarm terms (``alarms.alarm_columns``: what the
registry stores) at the calibration's own T0: bias and scale factor, orders 0-2. Also the
change z of consecutive logs with the truth removed, (e1 - e0) / hypot(s0, s1): what a
stable unit's step test sees.

Variant ``no-nonorthogonality`` draws the same devices with S = identity (the ``mems``
devices have 2e-4 - 8e-4 below-diagonal terms); ``datasheet-cross-axis`` with 1e-3 - 2e-2
(a consumer datasheet's cross-axis sensitivity, ``VARIANTS``). Before 2026-12-03 a
calibration without a lab prior took S = identity for its alarm terms; since, its alarm
yardstick estimates S (``estimation/alarm_yardstick.py``; results ``*_s_identity`` and
``*_s_estimated``, docs/fleet.md). ``summary_pooled_s``: the same at each unit's S pooled
over its logs, as ``history`` tests them since 2026-12-03 (``fleet/pooled_s.py``).

    .venv/bin/python bench/alarm_truth_z.py --units 30 --out bench/results/alarm_truth_z_base.json
    .venv/bin/python bench/alarm_truth_z.py --units 30 --variant no-nonorthogonality \\
        --out bench/results/alarm_truth_z_s0.json

Fleet seed 90 (the alarm bench uses 0-29): devices 90000 + unit. SI units; z unitless.
"""

import argparse
import concurrent.futures
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np

AXES = 'xyz'
#: the accelerometer's below-diagonal non-orthogonality per variant (``sim.devices``
#: distributions; 'base': the ``mems`` design's own, 2e-4 - 8e-4): none, or up to the
#: +-2 % cross-axis sensitivity a consumer datasheet allows (MPU-6050, PS-MPU-6000A-00
#: rev. 3.4 sect. 6.2)
VARIANTS = {'no-nonorthogonality': ('const', 0.0),
            'datasheet-cross-axis': ('uniform+-', 1e-3, 2e-2)}


def use_variant(variant):
    """Draw this process's ``mems`` devices with ``variant``'s S (``VARIANTS``; 'base': as is)."""
    from thermal_imu_calib.sim import devices as dv
    if variant in VARIANTS:
        dv.DEVICES['mems'] = dataclasses.replace(dv.DEVICES['mems'],
                                                 s_offdiag=VARIANTS[variant])


def _one(variant, fleet_seed, unit, logs, work):
    """Return the per-log truth z of one stable unit (runs in a worker process)."""
    use_variant(variant)
    from thermal_imu_calib.cli import main
    from thermal_imu_calib.fleet import alarms as al
    from thermal_imu_calib.fleet import pooled_s
    from thermal_imu_calib.fleet.simulate import FleetDesign, write_log
    from thermal_imu_calib.formats import read_calibration
    from thermal_imu_calib.gravity import normal_gravity
    from thermal_imu_calib.models.alarm_terms import coefficients
    design = FleetDesign(units=unit + 1, logs_per_unit=logs, seed=fleet_seed)
    plan = {'unit': f'u{unit:02d}', 'device_seed': fleet_seed * 1000 + unit, 'kind': 'stable',
            'axis': 0, 'step_log': logs}
    out = []
    for k in range(logs):
        path = write_log(work, plan, k, design)
        cal_path = path + '.calib.yaml'
        try:
            main(['calibrate', path, '-o', cal_path, '--gravity', repr(normal_gravity(45.0)),
                  '--no-progress'])
        except SystemExit as e:
            if e.code:
                out.append({'log': k, 'error': f'calibrate exited {e.code}'})
                continue
        cal = read_calibration(cal_path)
        truth = read_calibration(path + '.truth.yaml')
        row = al.alarm_columns(cal)
        rec = {'log': k, 'family': row.get(al.FAMILY_COLUMN), 'model': cal.accel.kind}
        part = pooled_s.row_s(row)
        for name in ('b', 'k'):
            c, s, t0 = al.row_terms(row, name)
            tb, tk = coefficients(truth.accel, t0)
            err = c - (tb if name == 'b' else tk)
            rec[f'err_{name}'], rec[f'std_{name}'] = err.tolist(), s.tolist()
            if part is not None:      # the terms given S (fleet/pooled_s.py)
                rec[f'std_s_{name}'] = part[f'{name}_std_s'].tolist()
                rec[f'ds_{name}'] = part[f'{name}_ds'].tolist()
        if part is not None:
            rec.update(s=part['q'].tolist(), s_info=part['info'].tolist(),
                       s_eta=part['eta'].tolist())
            if 'k_dss' in part:       # the scale factor's curvature on S (at T0)
                rec['dss_k'] = part['k_dss'].tolist()
        out.append(rec)
        for f in (path, cal_path):
            os.remove(f)
    return unit, out


def _summary(v):
    from scipy.stats import kstest
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {'n': 0}
    return {'n': int(v.size), 'mean': round(float(v.mean()), 3), 'std': round(float(v.std()), 3),
            'frac_abs_gt_3': round(float(np.mean(np.abs(v) > 3)), 4),
            'max_abs': round(float(np.abs(v).max()), 2),
            'ks_p_vs_normal_0_1': round(float(kstest(v, 'norm').pvalue), 4)}


def at_pooled_s(recs, linear_k=False):
    """Return the unit's records with 'err_*', 'std_*' at S pooled over them, or None.

    As ``history`` tests them (``fleet/pooled_s.py``): each log's error carried to S* by its
    gains, its std given S; 'ds_*' the gains (for the change z's shared part) and 'cov_s'.
    The scale factor at T0 also with its curvature on S ('dss_k', when stored) unless
    ``linear_k`` (the gains alone, as before it). None when a log has no terms given S.
    """
    from thermal_imu_calib.fleet import pooled_s
    ok = [r for r in recs if 'error' not in r]
    if not ok or any('s' not in r for r in ok):
        return None
    parts = [{'info': np.array(r['s_info']), 'eta': np.array(r['s_eta'])} for r in ok]
    s_star, cov = pooled_s.pool(parts)
    out = []
    for r in ok:
        rec = {'log': r['log'], 'cov_s': cov}
        ds = s_star - np.array(r['s'])
        for name in ('b', 'k'):
            g = np.array(r[f'ds_{name}'])                          # (3 axes, 3 orders, 3)
            rec[f'err_{name}'] = np.array(r[f'err_{name}']) + g @ ds
            if name == 'k' and 'dss_k' in r and not linear_k:      # T0's second order
                curv = np.array(r['dss_k'])
                rec['err_k'][:, 0] += 0.5 * np.einsum('amn,m,n->a', curv, ds, ds)
                g = g.copy()
                g[:, 0] += curv @ ds
            own = np.array(r[f'std_s_{name}']) ** 2 + np.einsum('ajm,mn,ajn->aj', g, cov, g)
            rec[f'std_{name}'] = np.sqrt(own)
            rec[f'ds_{name}'] = g
        out.append(rec)
    return out


def summarise(units, pooled=False, linear_k=False):
    """Return {term: {axis: summary}} of the truth z and of the truth-removed change z.

    ``pooled``: at each unit's pooled S (``at_pooled_s``; units without terms given S are
    left out); a change's std then has the shared S part removed, as ``history`` has.
    """
    if pooled:
        units = {u: p for u, p in ((u, at_pooled_s(r, linear_k)) for u, r in units.items())
                 if p is not None}
        if not units:
            return {}
    out = {}
    for name in ('b', 'k'):
        for j in range(3):
            z = [np.array(r[f'err_{name}'])[:, j] / np.array(r[f'std_{name}'])[:, j]
                 for recs in units.values() for r in recs if 'error' not in r]
            z = np.array(z)
            out[f'd{name}{j} truth z'] = {a: _summary(z[:, i]) for i, a in enumerate(AXES)}
            out[f'd{name}{j} truth z']['all'] = _summary(z.ravel())
        ch = []
        for recs in units.values():
            ok = [r for r in recs if 'error' not in r]
            for r0, r1 in zip(ok, ok[1:]):
                e0, e1 = (np.array(r[f'err_{name}'])[:, 0] for r in (r0, r1))
                s0, s1 = (np.array(r[f'std_{name}'])[:, 0] for r in (r0, r1))
                var = s0 ** 2 + s1 ** 2
                if pooled:       # S*'s error: only the part the two do not share
                    g0, g1 = (r[f'ds_{name}'][:, 0] for r in (r0, r1))
                    cov = r0['cov_s']
                    var = (var - np.einsum('am,mn,an->a', g0, cov, g0)
                           - np.einsum('am,mn,an->a', g1, cov, g1)
                           + np.einsum('am,mn,an->a', g1 - g0, cov, g1 - g0))
                ch.append((e1 - e0) / np.sqrt(var))
        ch = np.array(ch)
        out[f'd{name}0 change z (truth removed)'] = {a: _summary(ch[:, i])
                                                     for i, a in enumerate(AXES)}
        out[f'd{name}0 change z (truth removed)']['all'] = _summary(ch.ravel())
    return out


def compact(x):
    """Return ``x`` with every float to 6 significant digits (the per-log values)."""
    if isinstance(x, float):
        return float(f'{x:.6g}')
    if isinstance(x, dict):
        return {k: compact(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [compact(v) for v in x]
    return x


def main():
    """Run one variant over ``--units`` stable units and write the JSON (``--out``)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--units', type=int, default=30)
    ap.add_argument('--logs-per-unit', type=int, default=5)
    ap.add_argument('--fleet-seed', type=int, default=90)
    ap.add_argument('--variant', choices=('base', *VARIANTS), default='base')
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--out', required=True)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix='alarm_truth_z_')
    t = time.perf_counter()
    units = {}
    try:
        with concurrent.futures.ProcessPoolExecutor(args.workers) as ex:
            futs = [ex.submit(_one, args.variant, args.fleet_seed, u, args.logs_per_unit, work)
                    for u in range(args.units)]
            for f in concurrent.futures.as_completed(futs):
                u, recs = f.result()
                units[f'u{u:02d}'] = recs
                print(f'u{u:02d}: {len(recs)} logs', flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    units = dict(sorted(units.items()))
    res = {'command': ' '.join([os.path.basename(sys.executable), *sys.argv]),
           'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime()),
           'variant': args.variant, 'fleet_seed': args.fleet_seed,
           'seconds': round(time.perf_counter() - t, 1),
           'families': sorted({r.get('family') or '-' for rs in units.values() for r in rs}),
           'failed': [(u, r['log'], r['error']) for u, rs in units.items() for r in rs
                      if 'error' in r],
           'summary': summarise(units),
           'summary_pooled_s': summarise(units, pooled=True),
           'summary_pooled_s_linear_k': summarise(units, pooled=True, linear_k=True),
           'units': units}
    with open(args.out, 'w') as f:
        json.dump(compact(res), f)
    for which in ('summary', 'summary_pooled_s', 'summary_pooled_s_linear_k'):
        print(which)
        for k, v in res[which].items():
            print(' ', k, {a: (s.get('std'), s.get('max_abs')) for a, s in v.items()})


if __name__ == '__main__':
    main()
