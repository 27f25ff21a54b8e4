"""Leg-vs-leg validation of the thermal models on the real chamber log's training part.

``test/fixtures/real/tofupilot_chamber/imu_chamber_train.csv.gz`` (SOURCE.md there): one IMU,
one orientation, cooled 51.6 -> -17.6 degC and heated to 74 degC. Only this training part
is used; the second cooling leg is held back as the test and never read here.

Each leg is fitted alone and the other leg is the test, both directions, over the
temperatures both legs cover (-17.6..51.2 degC):

* ``default``: ``calibrate_windows`` with default options (``--model auto``) on the
  training leg's windows, exactly what ``thermal-imu-calib calibrate`` does;
* the flight stacks' cubics: ArduPilot's form (tempcal_IMU.py: cubic fit of every window
  against T - 35 degC, time-weighted) and PX4's (``--model px4``);
* ``--model offset`` / ``lag`` / ``rvm`` (the families of the previous default);
* every candidate of ``estimation.hysteresis.candidate_specs`` fitted on the leg.

Then forward in time, as a calibration is used: fitted on the history before a cut (the
cooling leg and the start of the heating leg: both directions), tested on the heating after
the cut inside the fitted range; the default, the previous default (``select_single``, the
one-orientation auto before issue 22), PX4 and ArduPilot. Last, the default's specs (chosen
on the forward folds of the whole training part) on held-out blocks the selection never
scored: the first part of the cooling leg, refitted on the rest.

Every calibration is streamed over the whole log from its start (its history terms see
the history a compensator would) and scored on the test leg as the held-out leg is scored:
drift RMS = RMS over 30-s blocks of |block mean - leg mean| (3-vector), m/s^2 and rad/s.

Usage: ``python bench/bench_chamber.py [--csv PATH] [--json FILE] [--all]``
"""

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from thermal_imu_calib.calibration import Calibration, TemperatureInput  # noqa: E402
from thermal_imu_calib.estimation.calibrate import (calibrate_windows,  # noqa: E402
                                                    CalibrateOptions, CalibrationRefused)
from thermal_imu_calib.estimation.hysteresis import (ARDUPILOT_SPEC,  # noqa: E402
                                                     ARDUPILOT_TREF, build_model,
                                                     candidate_specs, Features, fit_spec)
from thermal_imu_calib.io.csv_logs import read_tofupilot_chamber  # noqa: E402
from thermal_imu_calib.collection.feed import windows_from_columns  # noqa: E402
from thermal_imu_calib.selection import select  # noqa: E402

#: the training part as copied into the repository (test/fixtures/real/tofupilot_chamber)
CSV = os.path.join(ROOT, 'test', 'fixtures', 'real', 'tofupilot_chamber',
                   'imu_chamber_train.csv.gz')
TOPIC = '/imu/temperature'


def block_drift(t, y, block_s=30.0):
    """Return the RMS over ``block_s`` blocks of |block mean - mean of the blocks|."""
    blk = np.floor((t - t[0]) / block_s).astype(int)
    _, inv = np.unique(blk, return_inverse=True)
    cnt = np.bincount(inv)
    means = np.stack([np.bincount(inv, y[:, a]) / cnt for a in range(3)], 1)
    d = means - means.mean(0)
    return float(np.sqrt(np.mean(np.sum(d * d, 1))))


def spec_calibration(w, spec, t0):
    """Return the Calibration of one candidate spec fitted on windows ``w``."""
    models = {}
    for sig in ('accel', 'gyro'):
        ref = np.full(3, ARDUPILOT_TREF) if spec is ARDUPILOT_SPEC else t0
        coef, std = fit_spec(Features(w, [0, 0, 0]), spec, getattr(w, sig),
                             np.ones(len(w), bool), ref)
        models[sig] = build_model(spec, coef, std, ref, sig, sig == 'gyro')
    return Calibration(accel=models['accel'], gyro=models['gyro'],
                       inputs=[TemperatureInput(TOPIC)],
                       valid_range=np.array([[w.temp.min(), w.temp.max()]]))


def score(cal, imu, temp, test):
    """Stream ``cal`` over the whole log; return (accel, gyro) drift RMS on ``test`` rows."""
    t = imu.stamp_ns * 1e-9
    res = cal.stream().apply(t, imu.accel, imu.gyro, temp[:, None])
    return (block_drift(t[test], res.accel[test]), block_drift(t[test], res.gyro[test]))


def forward_table(w, imu, temp, opts, cuts=(0.6, 0.7, 0.8)):
    """Fit on the history before a cut (both legs), test after it over the covered range.

    The way the calibration is used: forward in time, fitted on both directions. Returns
    and prints {method: {cut: (accel, gyro)}}.
    """
    t = imu.stamp_ns * 1e-9
    wm = 0.5 * (w.t0 + w.t1)
    out = {}
    for f in cuts:
        cut = wm.min() + f * (wm.max() - wm.min())
        wl = w.select(wm < cut)
        test = (t >= cut) & (temp <= wl.temp.max()) & (temp >= wl.temp.min())
        key = f'{100 * f:.0f} %'
        out.setdefault('raw', {})[key] = (block_drift(t[test], imu.accel[test]),
                                          block_drift(t[test], imu.gyro[test]))
        previous = select.select_single(select.make_context(wl, opts)).model
        for name, model in (('default (auto)', 'auto'),
                            (f'previous default (select_single: {previous})', previous),
                            ('PX4-style cubic', 'px4'),
                            ('ArduPilot learner (rising T only)', 'ardupilot')):
            r = calibrate_windows(wl, CalibrateOptions(**{**opts.__dict__, 'model': model}))
            name = name.split(':')[0] + ')' if name.startswith('previous') else name
            out.setdefault(name, {})[key] = score(r.calibration, imu, temp, test)
        t0 = np.round(np.full(3, 0.5 * (wl.temp.min() + wl.temp.max())), 2)
        out.setdefault('ArduPilot-style cubic (tempcal_IMU.py form)', {})[key] = score(
            spec_calibration(wl, ARDUPILOT_SPEC, t0), imu, temp, test)
    print('\nforward in time: fitted on the history before the cut (cooling + part of the '
          'heating), tested on the heating after it inside the fitted range')
    print(f'{"method":45s} | ' + ' | '.join(f'cut {k:>5s}: accel     gyro' for k in
                                            out['raw']))
    for name, r in out.items():
        print(f'{name:45s} | ' + ' | '.join(f'{a:16.4f} {g:8.5f}' for a, g in r.values()))
    return out


def first_part_folds(w, fractions=(0.25, 0.5)):
    """Return folds holding out the first ``fractions`` of the cooling leg's time (the rest fits).

    Blocks in the other direction than the history's end, which the selection's forward
    folds never score.
    """
    from thermal_imu_calib.estimation.thermal_lag import legs
    tm = 0.5 * (w.t0 + w.t1)
    ids, _ = legs(w)
    first = tm[ids == 0]
    folds = []
    for f in fractions:
        test = tm < first.min() + f * (first.max() - first.min())
        folds.append((~test, test, f'first {100 * f:.0f} % of the cooling leg'))
    return folds


def first_part_table(w, opts):
    """Score the default's specs (chosen on the forward folds) on other held-out blocks.

    The first part of the cooling leg (25 %, 50 % of its time) is held out and the specs are
    refitted on the rest (the remaining cooling and all the heating): blocks in the other
    direction than the history's end, which the selection never scored. Returns and prints
    {method: {sensor: mean figure}}.
    """
    from thermal_imu_calib.selection.time_folds import heldout_figures, select_history
    ctx = select.make_context(w, opts)
    chosen = select_history(ctx)['specs']
    folds = first_part_folds(w)
    out = {}
    for sig, t0 in (('accel', ctx.t0), ('gyro', ctx.gyro_t0)):
        specs = [chosen[sig], ARDUPILOT_SPEC]
        figs, raw = heldout_figures(w, [0, 0, 0], sig, specs, np.asarray(t0, float), folds)
        out.setdefault('raw', {})[sig] = [float(v) for v in raw]
        out.setdefault('default', {})[sig] = [float(v) for v in figs[chosen[sig]]]
        out.setdefault('default_spec', {})[sig] = chosen[sig].label()
        floor = [float(v) for v in figs[ARDUPILOT_SPEC]]
        out.setdefault('ArduPilot-style cubic', {})[sig] = floor
    print('\nthe default\'s specs on blocks the selection never scored: the first 25 % / 50 % '
          'of the cooling leg held out, refitted on the rest (30-s drift RMS)')
    for name in ('raw', 'default', 'ArduPilot-style cubic'):
        print(f'{name:24s} accel ' + ' / '.join(f'{v:.4f}' for v in out[name]['accel'])
              + '  gyro ' + ' / '.join(f'{v:.5f}' for v in out[name]['gyro']))
    print(f'(default: accel {out["default_spec"]["accel"]}; gyro {out["default_spec"]["gyro"]})')
    return out


def main(argv=None):
    """Run the bench; print the tables (and write JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--csv', default=CSV)
    ap.add_argument('--json', default=None)
    ap.add_argument('--all', action='store_true', help='print every grid candidate')
    args = ap.parse_args(argv)
    imu, tc = read_tofupilot_chamber(args.csv)
    w = windows_from_columns([imu], [tc])
    temp = tc.temperature
    t = imu.stamp_ns * 1e-9
    i_turn = int(np.argmin(temp))
    t_turn = t[i_turn]
    wm = 0.5 * (w.t0 + w.t1)
    cool_w, heat_w = w.select(wm <= t_turn), w.select(wm > t_turn)
    lo = max(cool_w.temp.min(), heat_w.temp.min())
    hi = min(cool_w.temp.max(), heat_w.temp.max())
    both = (temp >= lo) & (temp <= hi)
    directions = {'fit cooling, test heating': (cool_w, both & (t > t_turn)),
                  'fit heating, test cooling': (heat_w, both & (t <= t_turn))}
    opts = CalibrateOptions(inputs=[TemperatureInput(TOPIC)])
    rows, chosen = {}, {}
    t_start = time.perf_counter()
    for dname, (wl, test) in directions.items():
        rows.setdefault('raw', {})[dname] = (block_drift(t[test], imu.accel[test]),
                                             block_drift(t[test], imu.gyro[test]))
        for name, model in (('default (auto)', 'auto'), ('PX4-style cubic', 'px4'),
                            ('offset', 'offset'), ('lag', 'lag'), ('rvm', 'rvm')):
            try:
                r = calibrate_windows(wl, CalibrateOptions(**{**opts.__dict__,
                                                              'model': model}))
            except CalibrationRefused as e:
                rows.setdefault(name, {})[dname] = (float('nan'), float('nan'))
                print(f'{name} on {dname}: refused ({e})')
                continue
            rows.setdefault(name, {})[dname] = score(r.calibration, imu, temp, test)
            if model == 'auto':
                chosen[dname] = r.calibration.fit['model_choice']['reason']
        t0 = np.round(np.full(3, 0.5 * (wl.temp.min() + wl.temp.max())), 2)
        for spec in candidate_specs():
            name = ('ArduPilot-style cubic (tempcal_IMU.py form)' if spec is ARDUPILOT_SPEC
                    else spec.label())
            rows.setdefault(name, {})[dname] = score(spec_calibration(wl, spec, t0), imu,
                                                     temp, test)
    seconds = time.perf_counter() - t_start
    d1, d2 = directions
    ap_row = rows['ArduPilot-style cubic (tempcal_IMU.py form)']
    print(f'tofupilot chamber, training part only: leg-vs-leg over {lo:.1f}..{hi:.1f} degC '
          f'(30-s drift RMS; accel m/s^2, gyro rad/s)')
    print(f'{"method":58s} | {d1:^27s} | {d2:^27s} | mean vs ArduPilot')
    print(f'{"":58s} | {"accel":>12s} {"gyro":>13s} | {"accel":>12s} {"gyro":>13s} |'
          ' accel   gyro')
    fixed = ['raw', 'ArduPilot-style cubic (tempcal_IMU.py form)', 'PX4-style cubic',
             'offset', 'lag', 'rvm', 'default (auto)']
    grid = sorted((k for k in rows if k not in fixed),
                  key=lambda k: np.mean([rows[k][d][0] for d in directions]))
    shown = fixed + (grid if args.all else grid[:12])
    for name in shown:
        r = rows[name]
        rel = [100 * (1 - np.mean([r[d][s] for d in directions])
                      / np.mean([ap_row[d][s] for d in directions])) for s in (0, 1)]
        print(f'{name[:58]:58s} | {r[d1][0]:12.4f} {r[d1][1]:13.5f} | {r[d2][0]:12.4f} '
              f'{r[d2][1]:13.5f} | {rel[0]:+5.0f} % {rel[1]:+5.0f} %')
    if not args.all:
        print(f'({len(grid) - 12} more grid candidates: --all)')
    dflt = rows['default (auto)']
    verdict = {s: all(dflt[d][i] < ap_row[d][i] for d in directions)
               for i, s in enumerate(('accel', 'gyro'))}
    print('default beats the ArduPilot-style cubic in both directions: accel '
          f'{"PASS" if verdict["accel"] else "MISS"}, gyro '
          f'{"PASS" if verdict["gyro"] else "MISS"}')
    for d, why in chosen.items():
        print(f'auto on {d.split(",")[0][4:]}: {why}')
    fwd = forward_table(w, imu, temp, opts)
    other = first_part_table(w, opts)
    print(f'{seconds:.1f} s')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'overlap_degC': [lo, hi], 'rows': rows, 'auto_reason': chosen,
                       'forward': fwd, 'first_part_held_out': other,
                       'default_beats_ardupilot': verdict}, f, indent=1)
    return 0 if all(verdict.values()) else 1


if __name__ == '__main__':
    sys.exit(main())
