"""Lifelong calibration over a simulated robot month (and real logs): accuracy, swaps, bounds.

``month`` (default): for each seed, ``sim.robot_month`` (30 days, 10 Hz IMU during the
stops) is fed through the lifelong path the node runs (``lifelong.feed.Feeder``: the
temperature aligner, the stationary detector, the cmd_vel hint gate, ``Lifelong`` with the
node's default settings, re-estimates on the same thread), restarting the lifelong state
from its directory at the month's restart times. Every stop is scored with the
calibration active when it began, with the true model and with the raw output:

* gyro error: |mean(compensated - true rate)| over the stop's still samples (rad/s);
* accel error: |mean(compensated - true specific force) - c| (m/s^2) where c is the
  month's median of that error for the same policy (one mounting pose: the constant is
  not observable from stops and is removed once, like a levelling of the mount);
* per-sample error: sqrt(systematic^2 + white noise^2) of the gyro (what a consumer sees
  sample by sample; the true model's is the noise alone).

Reported per seed: first-day and last-week RMS of these, their ratios (targets: last week
<= 0.5 x first day and <= 1.5 x the true model), for every swap the next day's error with
the new and with the replaced calibration (no swap may make it worse), the knock: alarm
delay and the error the day before vs the second day after it, the largest process RSS and
the lifelong directory's size over the month. ``real``: the real recordings through
lifelong mode (every swap and alarm listed). ``dds``: the month played through DDS into
``calibrator_node`` in its own process, its RSS and the lifelong directory sampled over
the replay (``dds`` below).

    nice -n 10 .venv/bin/python bench/bench_lifelong.py month --seeds 20
    nice -n 10 .venv/bin/python bench/bench_lifelong.py real
    # seeds in two processes, then one file:
    ... month --seeds 10 --output a.json & ... month --seeds 10 --first-seed 10 --output b.json
    nice -n 10 .venv/bin/python bench/bench_lifelong.py merge a.json b.json

    nice -n 10 .venv/bin/python bench/bench_lifelong.py dds --days 30 --max-seconds 4200

Results: bench/results/bench_lifelong_month.json, bench_lifelong_real.json,
bench_lifelong_dds.json.
"""

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from thermal_imu_calib.app.calibrate import CalibrateSettings  # noqa: E402
from thermal_imu_calib.calibration import OUT_OF_RANGE_POLICIES  # noqa: E402
from thermal_imu_calib.cli.calibrate import margin_or_off  # noqa: E402
from thermal_imu_calib.estimation.gyro_static import earth_rate_parts  # noqa: E402
from thermal_imu_calib.estimation.options import HIGH_ORDER_SENSORS  # noqa: E402
from thermal_imu_calib.lifelong.config import (  # noqa: E402
    GYRO_CONTINUATIONS, INCUMBENT_SPECS, RANGE_SENSORS)
from thermal_imu_calib.lifelong.feed import Feeder  # noqa: E402
from thermal_imu_calib.lifelong.gate import ACCEL_SCORES  # noqa: E402
from thermal_imu_calib.lifelong.hints import HintGate, HintSource  # noqa: E402
from thermal_imu_calib.lifelong.manager import (  # noqa: E402
    ALARM_CUTS, ALARM_REFERENCES, ALARM_WINDOWS, Lifelong, LifelongConfig)
from thermal_imu_calib.sim.robot_month import DAY, robot_month  # noqa: E402

RESULTS = os.path.join(HERE, 'results')
CHUNK_S = 30.0
#: the file a checkpoint directory (``<work>/seedN.restartK``) carries its meta in
CHECKPOINT_META = 'bench_checkpoint.json'


def rss_mb():
    """Return this process's resident set size now (MB)."""
    with open('/proc/self/statm') as f:
        return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 2 ** 20


def dir_bytes(path):
    return sum(os.path.getsize(os.path.join(dp, f)) for dp, _, fs in os.walk(path) for f in fs)


def stop_chunks(seg):
    """Return the still samples of a stop as <= CHUNK_S chunk means (raw, truth, temp)."""
    still = np.flatnonzero(seg.still)
    if not len(still):
        return None
    t = (seg.imu.stamp_ns[still] - seg.imu.stamp_ns[0]) * 1e-9
    cid = np.floor((t - t[0]) / CHUNK_S).astype(int)
    n = np.bincount(cid).astype(float)
    keep = n > 0

    def mean(x):
        x = x[still]
        x = x.reshape(len(x), -1)
        return np.stack([np.bincount(cid, x[:, j]) for j in range(x.shape[1])], 1)[keep] \
            / n[keep, None]
    stamps = seg.imu.stamp_ns.astype(float)[:, None] * 1e-9
    return {'n': n[keep], 't': mean(stamps)[:, 0], 'accel': mean(seg.imu.accel),
            'gyro': mean(seg.imu.gyro),
            'f': mean(seg.specific_force), 'w': mean(seg.angular_rate),
            'temp': mean(seg.temp_true)}


def stop_error(cal, ch):
    """Return (gyro error vector (3,), accel error vector (3,)) of one stop, sample-weighted."""
    if cal is None:
        a, g = ch['accel'], ch['gyro']
    else:
        res = cal.apply(ch['accel'], ch['gyro'], ch['temp'], stamps=ch['t'])
        a, g = res.accel, res.gyro
    w = ch['n'] / ch['n'].sum()
    return w @ (g - ch['w']), w @ (a - ch['f'])


def drift_rms(errors):
    """Return the RMS of accel error vectors (m, 3) less their per-axis median, NaN if none.

    The bench's accelerometer drift: what varies between stops, not the constant offset a
    one-pose model leaves (m/s^2).
    """
    a = np.asarray(errors, float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum((a - np.median(a, 0)) ** 2, 1)))) if len(a) \
        else float('nan')


def scored_stops(m, t_from=0.0, t_to=np.inf):
    """Yield (segment, ``stop_chunks``) of every stop of ``m`` in [t_from, t_to) s scored.

    Blocked stops (no commanded stop) and stops without a still sample are not scored.
    """
    for seg in m.segments(t_from, t_to):
        ch = stop_chunks(seg)
        if ch is not None and not seg.stop.blocked:
            yield seg, ch


def active_stops(m, starts, cals):
    """Yield (segment, ``stop_chunks``, index, calibration active when the stop began).

    Every scored stop of ``m`` (``scored_stops``) after the first activation of a
    ``registry_timeline`` (``starts`` s, ``cals``).
    """
    for seg, ch in scored_stops(m):
        i = active_index(starts, seg.stop.t0)
        if i >= 0:
            yield seg, ch, i, cals[i]


def active_index(starts, t):
    """Return the index of the calibration active at ``t`` (s; ``registry_timeline``), -1: none."""
    return int(np.searchsorted(starts, t, side='right')) - 1


def registry_timeline(work_seed, start_ns):
    """Return (activated at s since ``start_ns``, calibrations) of a month's registry.

    ``work_seed``: a finished month's lifelong directory (``--work``/seedN); every
    calibration it activated, oldest first (a lifelong registry's ``time`` is the moment
    it was activated).
    """
    from thermal_imu_calib.calibration import Calibration
    from thermal_imu_calib.fleet import registry
    rows = registry.read_index(os.path.join(work_seed, 'registry'))
    starts = np.array([registry.parse_time(r['time']) - start_ns for r in rows]) * 1e-9
    return starts, [Calibration.load(os.path.join(work_seed, 'registry', r['file']))
                    for r in rows]


def months_parser(doc, output=True):
    """Return the argument parser of an after-the-fact script over finished months.

    Positional ``SEED:WORK_SEED_DIR`` of each month, ``--days`` and (``output``)
    ``--output``; the description is the first line of ``doc``.
    """
    ap = argparse.ArgumentParser(description=doc.split('\n')[0])
    ap.add_argument('months', nargs='+', help='SEED:WORK_SEED_DIR of finished months')
    ap.add_argument('--days', type=float, default=30.0)
    if output:
        ap.add_argument('--output', default='')
    return ap


#: the package's defaults, which the bench's options start from
DEFAULT = LifelongConfig()


def run_seed(seed, days, work, latitude=None, ageing=DEFAULT.ageing,
             per_sensor=DEFAULT.per_sensor, alarm_window=DEFAULT.alarm_window,
             one_sensor_after_alarm=DEFAULT.one_sensor_after_alarm,
             alarm_reference=DEFAULT.alarm_reference, alarm_cut=DEFAULT.alarm_cut,
             accel_score=DEFAULT.accel_score, raw_kept=DEFAULT.raw_kept,
             refit_on_swap=DEFAULT.refit_on_swap,
             out_of_range=CalibrateSettings.out_of_range,
             gyro_g_sensitivity=DEFAULT.gyro_g_sensitivity,
             gyro_continuation=DEFAULT.gyro_continuation, alarm_first=DEFAULT.alarm_first,
             high_order_margin=CalibrateSettings.high_order_margin,
             high_order_sensors=CalibrateSettings.high_order_sensors,
             placement_folds=DEFAULT.placement_folds,
             placement_floor=DEFAULT.placement_floor, stop_day=None,
             range_sensors=DEFAULT.range_sensors,
             placement_levels=DEFAULT.placement_levels,
             placement_levels_sensors=DEFAULT.placement_levels_sensors, checkpoints=False,
             resume=False, gyro_ageing_forward=DEFAULT.gyro_ageing_forward,
             gyro_pooled_gate=DEFAULT.gyro_pooled_gate,
             swap_must_explain=DEFAULT.swap_must_explain, gyro_follow=DEFAULT.gyro_follow,
             follow_without_latitude=DEFAULT.follow_without_latitude,
             incumbent_spec=DEFAULT.incumbent_spec,
             prequential_holds=DEFAULT.prequential_holds, **overrides):
    m = robot_month(seed, days=days, **overrides)
    d = os.path.join(work, f'seed{seed}')
    ckpt = latest_checkpoint(d) if resume else None
    shutil.rmtree(d, ignore_errors=True)
    if ckpt is not None:                    # the directory as it was at that restart
        shutil.copytree(ckpt[1], d, ignore=shutil.ignore_patterns(CHECKPOINT_META))
    settings = CalibrateSettings(latitude=latitude, out_of_range=out_of_range,
                                 high_order_margin=high_order_margin,
                                 high_order_sensors=high_order_sensors)
    log = []

    def make():
        return Lifelong(d, settings, 1, [m.config.temp_topic], m.config.frame_id,
                        registry_dir=os.path.join(d, 'registry'),
                        config=LifelongConfig(ageing=ageing, per_sensor=per_sensor,
                                              alarm_window=alarm_window,
                                              one_sensor_after_alarm=one_sensor_after_alarm,
                                              alarm_reference=alarm_reference,
                                              alarm_cut=alarm_cut,
                                              accel_score=accel_score,
                                              raw_kept=raw_kept,
                                              refit_on_swap=refit_on_swap,
                                              gyro_g_sensitivity=gyro_g_sensitivity,
                                              gyro_continuation=gyro_continuation,
                                              alarm_first=alarm_first,
                                              placement_folds=placement_folds,
                                              placement_floor=placement_floor,
                                              range_sensors=range_sensors,
                                              placement_levels=placement_levels,
                                              placement_levels_sensors=placement_levels_sensors,
                                              gyro_ageing_forward=gyro_ageing_forward,
                                              gyro_pooled_gate=gyro_pooled_gate,
                                              swap_must_explain=swap_must_explain,
                                              gyro_follow=gyro_follow,
                                              follow_without_latitude=follow_without_latitude,
                                              incumbent_spec=incumbent_spec,
                                              prequential_holds=prequential_holds),
                        log=lambda level, text: log.append((level, text)))
    life = make()
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    timeline = [(-np.inf, None)]            # (activated at s since start, calibration)
    stops, models = [], []                  # models: the active one (the follower's base)
    restarts = list(m.restart_times)
    peak_rss, peak_disk, t_run = rss_mb(), 0, time.perf_counter()
    done_s, after = 0.0, -np.inf            # a resumed month: seconds spent, restart time
    if ckpt is not None:
        k, _, meta = ckpt
        after, restarts = restarts[k], restarts[k + 1:]
        peak_rss, peak_disk = max(peak_rss, meta['peak_rss_mb']), meta['peak_dir_bytes']
        done_s = meta['seconds']
    base = m.start_ns * 1e-9
    for seg in m.segments():
        s = seg.stop
        if s.t0 <= after:
            continue                        # before the restart the month resumed from
        if stop_day is not None and s.t0 > stop_day * DAY:
            break                           # the month's first days only
        while restarts and restarts[0] < s.t0:
            k = len(m.restart_times) - len(restarts)
            restarts.pop(0)
            if checkpoints:                 # the restart reads this directory only
                save_checkpoint(d, k, {'seconds': done_s + time.perf_counter() - t_run,
                                       'peak_rss_mb': peak_rss, 'peak_dir_bytes': peak_disk})
            life = make()                   # restart: state from the directory only
            feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
        ch = stop_chunks(seg)
        if ch is not None and not s.blocked:      # scored with what is published now
            stops.append((s.t0, life.output if gyro_follow else timeline[-1][1], ch))
            models.append(timeline[-1][1])
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, still)
                                                 for t, still in seg.hints])
        for dec in feeder.decisions:
            if dec['action'] == 'swap':
                timeline.append((dec['time'] - base, life.active))
        feeder.decisions = []
        peak_rss = max(peak_rss, rss_mb())
        peak_disk = max(peak_disk, dir_bytes(d))
    seconds = done_s + time.perf_counter() - t_run
    if stop_day is not None:        # scored afterwards by lifelong_first_day.py
        return {'seed': seed, 'seconds': round(seconds, 1), 'stop_day': stop_day}
    decisions = life.decisions()
    in_model = latitude is None and follow_without_latitude
    scored = (evaluate(m, stops, timeline, decisions, gyro_noise(m), base,
                       models if gyro_follow else None, in_model) if ckpt is None
              else registry_scores(m, d, decisions, in_model)
              | {'resumed_from_restart': ckpt[0]})
    return scored | {
        'seed': seed, 'seconds': round(seconds, 1), 'peak_rss_mb': round(peak_rss, 1),
        'peak_dir_mb': round(peak_disk / 2 ** 20, 2), 'summary': m.summary(),
        'store': life.store.summary(), 'registry_rows': _registry_rows(d)}


def save_checkpoint(d, k, meta):
    """Copy the lifelong directory ``d`` as it is at the month's restart ``k`` (+ meta)."""
    dst = f'{d}.restart{k}'
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(d, dst + '.part')
    with open(os.path.join(dst + '.part', CHECKPOINT_META), 'w') as f:
        json.dump(meta, f)
    os.rename(dst + '.part', dst)           # complete or absent


def latest_checkpoint(d):
    """Return (restart index, directory, meta) of ``d``'s latest checkpoint, or None."""
    found = [k for k in range(16)
             if os.path.isfile(os.path.join(f'{d}.restart{k}', CHECKPOINT_META))]
    if not found:
        return None
    path = f'{d}.restart{found[-1]}'
    with open(os.path.join(path, CHECKPOINT_META)) as f:
        return found[-1], path, json.load(f)


def gyro_noise(m):
    """Return the gyro's white noise per sample of month ``m`` (rad/s, norm of 3 axes)."""
    spec, rate = m.device.spec, m.config.imu_rate
    return np.sqrt(3 * (spec.gyro_noise_density ** 2 * rate + spec.gyro_lsb ** 2 / 12))


def _registry_rows(d):
    from thermal_imu_calib.fleet import registry
    return len(registry.read_index(os.path.join(d, 'registry')))


def vertical_earth_rate(m, ch):
    """Return the vertical earth rate of month ``m`` along a stop's true up (3,) rad/s.

    Sample-weighted over the stop's chunks (``stop_chunks``): what a calibration fitted
    without the latitude takes into its gyro bias on a level hold.
    """
    up = ch['f'] / np.linalg.norm(ch['f'], axis=1, keepdims=True)
    return earth_rate_parts(m.config.latitude)[0] * (ch['n'] @ up) / ch['n'].sum()


def evaluate(m, stops, timeline, decisions, noise_g, base, models=None, in_model=False):
    """Score a month: ``stops`` (t0 s, the calibration published then, chunks).

    ``models``: per stop the active model when what was published differs from it (the
    gyro follower, ``LifelongConfig.gyro_follow``): also scored, as 'model'. The swaps
    compare the models of ``timeline``. ``in_model``: the month's calibrations were
    fitted without the latitude and are scored in their own convention: their gyro error
    is against the true rate less the vertical earth rate (``vertical_earth_rate``; the
    true model and the raw output are scored against the true rate).
    """
    t = np.array([s[0] for s in stops])
    truth = [m.true_calibration(t0) for t0, _, _ in stops]

    def fitted_error(cal, ch):
        g, a = stop_error(cal, ch)
        return (g + vertical_earth_rate(m, ch), a) if in_model and cal is not None \
            else (g, a)
    err = {'active': [fitted_error(cal, ch) for _, cal, ch in stops],
           'true': [stop_error(tc, ch) for tc, (_, _, ch) in zip(truth, stops)],
           'raw': [stop_error(None, ch) for _, _, ch in stops]}
    if models is not None:
        err['model'] = [fitted_error(cal, ch) for cal, (_, _, ch) in zip(models, stops)]
    out = {}
    figures = {}
    for name, e in err.items():
        g = np.array([x[0] for x in e])
        a = np.array([x[1] for x in e])
        c = np.median(a, axis=0)
        figures[name] = (np.linalg.norm(g, axis=1), np.linalg.norm(a - c, axis=1), c)
    days = m.config.days
    first = t < DAY
    last = t >= (days - 7) * DAY

    def rms(x, sel):
        return float(np.sqrt(np.mean(x[sel] ** 2))) if sel.any() else float('nan')

    def centred(name, sel):
        """RMS of the accel error with the period's median removed (drift within it)."""
        return drift_rms(np.array([x[1] for x in err[name]])[sel])
    for name, (g, a, _) in figures.items():
        out[name] = {'gyro_first_day': rms(g, first), 'gyro_last_week': rms(g, last),
                     'accel_first_day': rms(a, first), 'accel_last_week': rms(a, last),
                     'accel_drift_first_day': centred(name, first),
                     'accel_drift_last_week': centred(name, last),
                     'gyro_sample_first_day': float(np.hypot(rms(g, first), noise_g)),
                     'gyro_sample_last_week': float(np.hypot(rms(g, last), noise_g))}
    act, tru = out['active'], out['true']
    out['ratios'] = {
        'gyro_last_week_over_first_day': act['gyro_last_week'] / act['gyro_first_day'],
        'accel_last_week_over_first_day': act['accel_last_week'] / act['accel_first_day'],
        'accel_drift_last_week_over_first_day':
            act['accel_drift_last_week'] / act['accel_drift_first_day'],
        'accel_drift_last_week_over_true':
            act['accel_drift_last_week'] / max(tru['accel_drift_last_week'], 1e-12),
        'gyro_last_week_over_true': act['gyro_last_week'] / tru['gyro_last_week'],
        'accel_last_week_over_true': act['accel_last_week'] / max(tru['accel_last_week'],
                                                                  1e-12),
        'gyro_sample_last_week_over_first_day':
            act['gyro_sample_last_week'] / act['gyro_sample_first_day'],
        'gyro_sample_last_week_over_true':
            act['gyro_sample_last_week'] / tru['gyro_sample_last_week']}
    if models is not None:
        out['ratios']['model_gyro_last_week_over_true'] = \
            out['model']['gyro_last_week'] / tru['gyro_last_week']
    # swaps: the next day's error with the new and with the replaced calibration
    c_act = figures['active'][2]
    swaps = []
    for (ts, new), (_, old) in zip(timeline[2:], timeline[1:-1]):
        sel = [i for i, (t0, _, _) in enumerate(stops) if ts <= t0 < ts + DAY]
        if not sel:
            continue
        e_new = [fitted_error(new, stops[i][2]) for i in sel]
        e_old = [fitted_error(old, stops[i][2]) for i in sel]
        gn = np.sqrt(np.mean([np.sum(x[0] ** 2) for x in e_new]))
        go = np.sqrt(np.mean([np.sum(x[0] ** 2) for x in e_old]))
        an = np.sqrt(np.mean([np.sum((x[1] - c_act) ** 2) for x in e_new]))
        ao = np.sqrt(np.mean([np.sum((x[1] - c_act) ** 2) for x in e_old]))
        # the drift within the next day (each calibration's own median removed)
        dn, do = (float(np.sqrt(np.mean(np.sum((v - np.median(v, 0)) ** 2, 1))))
                  for v in (np.array([x[1] for x in e_new]), np.array([x[1] for x in e_old])))
        swaps.append({'day': ts / DAY, 'stops': len(sel), 'gyro_new': gn, 'gyro_old': go,
                      'accel_new': an, 'accel_old': ao,
                      'accel_drift_new': dn, 'accel_drift_old': do,
                      'gyro_worse': bool(gn > go), 'accel_worse': bool(an > ao),
                      'accel_drift_worse': bool(dn > do)})
    out['swaps'] = swaps
    out['swaps_total'] = len(timeline) - 1
    out['swaps_worse_gyro'] = sum(s['gyro_worse'] for s in swaps)
    out['swaps_worse_accel'] = sum(s['accel_worse'] for s in swaps)
    out['swaps_worse_accel_drift'] = sum(s['accel_drift_worse'] for s in swaps)
    # the knock
    k = m.knock_t
    alarms = [d['time'] - base for d in decisions if d['action'] == 'alarm']
    after = [a for a in alarms if a >= k]
    g = figures['active'][0]
    out['knock'] = {'day': k / DAY, 'alarms_before': sum(a < k for a in alarms),
                    'alarm_delay_h': (after[0] - k) / 3600 if after else None,
                    'gyro_day_before': rms(g, (t >= k - DAY) & (t < k)),
                    'gyro_day_after': rms(g, (t >= k) & (t < k + DAY)),
                    'gyro_second_day_after': rms(g, (t >= k + DAY) & (t < k + 2 * DAY)),
                    'true_gyro_day_before': rms(figures['true'][0], (t >= k - DAY) & (t < k))}
    if models is not None:
        gm = figures['model'][0]
        out['knock'].update(model_gyro_day_before=rms(gm, (t >= k - DAY) & (t < k)),
                            model_gyro_second_day_after=rms(
                                gm, (t >= k + DAY) & (t < k + 2 * DAY)))
    out['daily_gyro'] = [rms(g, (t >= dd * DAY) & (t < (dd + 1) * DAY))
                         for dd in range(int(np.ceil(days)))]
    out['decisions'] = {a: sum(d['action'] == a for d in decisions)
                        for a in ('swap', 'keep', 'refused', 'alarm')}
    return out


def month(args):
    work = args.work or tempfile.mkdtemp(prefix='bench_lifelong_')
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        r = run_seed(seed, args.days, work, args.latitude, not args.no_ageing,
                     not args.whole_swap, args.alarm_window, args.one_sensor_after_alarm,
                     args.alarm_reference, args.alarm_cut, args.accel_score,
                     args.raw_kept, args.refit_on_swap, args.out_of_range,
                     args.gyro_g_sensitivity, args.gyro_continuation, args.alarm_first,
                     args.high_order_margin, args.high_order_sensors,
                     args.placement_folds, args.placement_floor, args.stop_day,
                     args.range_sensors, placement_levels=args.placement_levels,
                     placement_levels_sensors=args.placement_levels_sensors,
                     checkpoints=args.checkpoints, resume=args.resume,
                     gyro_ageing_forward=args.gyro_ageing_forward,
                     gyro_pooled_gate=args.gyro_pooled_gate,
                     swap_must_explain=args.swap_must_explain,
                     gyro_follow=args.gyro_follow,
                     follow_without_latitude=args.follow_without_latitude,
                     incumbent_spec=args.incumbent_spec,
                     prequential_holds=args.prequential_holds,
                     dock_fraction=args.dock_fraction)
        rows.append(r)
        if args.stop_day is not None:
            print(f'seed {seed}: {r["seconds"]:.0f} s, stopped after day {args.stop_day:g} '
                  f'(score: bench/lifelong_first_day.py {seed}:{work}/seed{seed})',
                  flush=True)
            _write(args.output, {'command': ' '.join(sys.argv), 'rows': rows})
            continue
        ra, kn = r['ratios'], r['knock']
        print(f'seed {seed}: {r["seconds"]:.0f} s, gyro first day '
              f'{r["active"]["gyro_first_day"] * 1e3:.3f} last week '
              f'{r["active"]["gyro_last_week"] * 1e3:.3f} true '
              f'{r["true"]["gyro_last_week"] * 1e3:.3f} mrad/s (ratios '
              f'{ra["gyro_last_week_over_first_day"]:.2f}, {ra["gyro_last_week_over_true"]:.1f}'
              f'); accel ratios {ra["accel_last_week_over_first_day"]:.2f}; swaps '
              f'{r["swaps_total"]} (worse next day: gyro {r["swaps_worse_gyro"]}, accel '
              f'{r["swaps_worse_accel"]}); knock day {kn["day"]:.1f} alarm delay '
              f'{kn["alarm_delay_h"]} h, false alarms {kn["alarms_before"]}; RSS '
              f'{r["peak_rss_mb"]} MB, dir {r["peak_dir_mb"]} MB', flush=True)
        _write(args.output, {'command': ' '.join(sys.argv), 'days': args.days,
                             'seeds': [x['seed'] for x in rows], 'rows': rows,
                             'summary': summarise(rows)})
    if args.stop_day is None:
        print(json.dumps(summarise(rows), indent=1))


def summarise(rows):
    def col(f):
        return np.array([f(r) for r in rows], float)
    ra = {k: col(lambda r, k=k: r['ratios'][k]) for k in rows[0]['ratios']}
    delay = [r['knock']['alarm_delay_h'] for r in rows]
    return {
        'seeds': len(rows),
        'ratio_median_max': {k: [float(np.median(v)), float(np.max(v))] for k, v in ra.items()},
        'seeds_meeting_gyro_half_first_day': int(np.sum(
            ra['gyro_last_week_over_first_day'] <= 0.5)),
        'seeds_meeting_gyro_1_5_true': int(np.sum(ra['gyro_last_week_over_true'] <= 1.5)),
        'seeds_meeting_sample_1_5_true': int(np.sum(
            ra['gyro_sample_last_week_over_true'] <= 1.5)),
        'swaps': int(sum(r['swaps_total'] for r in rows)),
        'swaps_worse_next_day_gyro': int(sum(r['swaps_worse_gyro'] for r in rows)),
        'swaps_worse_next_day_accel': int(sum(r['swaps_worse_accel'] for r in rows)),
        'swaps_worse_next_day_accel_drift': int(sum(r.get('swaps_worse_accel_drift', 0)
                                                    for r in rows)),
        'seeds_meeting_accel_drift_half_first_day': int(sum(
            r['ratios'].get('accel_drift_last_week_over_first_day', np.inf) <= 0.5
            for r in rows)),
        'knock_detected_within_day': int(sum(d is not None and d <= 24 for d in delay)),
        'false_alarms_before_knock': int(sum(r['knock']['alarms_before'] for r in rows)),
        'recovered_second_day': int(sum(
            r['knock']['gyro_second_day_after'] <= 2 * r['knock']['gyro_day_before']
            for r in rows)),
        'peak_rss_mb_max': float(max(r['peak_rss_mb'] for r in rows)),
        'peak_dir_mb_max': float(max(r['peak_dir_mb'] for r in rows)),
        'seconds_per_seed': float(np.mean([r['seconds'] for r in rows]))}


def _write(path, obj):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, 'w') as f:
        json.dump(obj, f, indent=1, default=lambda x: x.tolist() if hasattr(x, 'tolist')
                  else str(x))


def real_pieces(name):
    """Return (ImuColumns, TemperatureColumns, piece seconds) of a real recording.

    The recordings are static throughout; cut into pieces (the detector restarted between
    them, as a robot that drives off and stops again) they become a sequence of holds.
    """
    from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
    from thermal_imu_calib.io.csv_logs import read_bmi270_rows, read_tofupilot_chamber
    real = os.environ.get('THERMAL_REAL_DATA', os.path.join(
        os.path.dirname(os.path.dirname(HERE)), 'shared', 'data', 'real'))
    fix = os.path.join(os.path.dirname(HERE), 'test', 'fixtures', 'real')
    if name == 'chamber':
        path = os.path.join(real, 'tofupilot_chamber', 'imu_chamber_train.csv')
        if not os.path.exists(path):
            path = os.path.join(fix, 'tofupilot_chamber', 'imu_chamber_train.csv.gz')
        imu, temp = read_tofupilot_chamber(path)
        t0 = 1_700_000_000 * 10 ** 9
        return (ImuColumns(imu.stamp_ns + t0, imu.accel, imu.gyro, 'imu'),
                TemperatureColumns(temp.stamp_ns + t0, temp.temperature, 'imu'), 120.0, path)
    parts, paths, t = [], [], 1_700_000_000 * 10 ** 9
    for f in ('BMI_270_cold_test_.csv', 'BMI_270_hot_test.csv'):   # cold soak, then hot
        path = os.path.join(real, 'bmi270_hot_cold', f)
        if not os.path.exists(path):
            path = os.path.join(fix, 'bmi270', f)
        x = read_bmi270_rows(path)[0]
        stamp = t + np.round(np.arange(len(x)) * 1e9 / 80.0).astype(np.int64)
        t = int(stamp[-1]) + 3600 * 10 ** 9           # an hour later
        parts.append((stamp, x))
        paths.append(path)
    stamp = np.concatenate([p[0] for p in parts])
    x = np.concatenate([p[1] for p in parts])
    return (ImuColumns(stamp, x[:, 1:4] * 4.0 * 9.80665, np.radians(x[:, 4:7]), 'imu'),
            TemperatureColumns(stamp, x[:, 0], 'imu'), 5.0, ' + '.join(paths))


def run_real(name, work, piece_s=None, config=None):
    """Play a real recording through lifelong mode; judge every swap on the later holds.

    ``config``: the ``LifelongConfig`` (None: the package's defaults).
    """
    from thermal_imu_calib.io.columns import TemperatureColumns
    from thermal_imu_calib.lifelong import gate
    imu, temp, piece, path = real_pieces(name)
    piece = piece_s or piece
    d = os.path.join(work, name)
    shutil.rmtree(d, ignore_errors=True)
    life = Lifelong(d, CalibrateSettings(), 1, ['/imu/temperature'], 'imu',
                    registry_dir=os.path.join(d, 'registry'), config=config)
    feeder = Feeder(life, None)
    t = (imu.stamp_ns - imu.stamp_ns[0]) * 1e-9
    pid = np.floor(t / piece).astype(int)
    actives = [(-np.inf, None)]
    for p in np.unique(pid):
        m = pid == p
        lo, hi = imu.stamp_ns[m][0], imu.stamp_ns[m][-1]
        tm = (temp.stamp_ns >= lo) & (temp.stamp_ns <= hi)
        tc = TemperatureColumns(temp.stamp_ns[tm], temp.temperature[tm], 'imu')
        feeder.push(imu.slice(m), [tc])
        feeder.finish()
        feeder.restart()
        for dec in feeder.decisions:
            if dec['action'] == 'swap':
                actives.append((dec['time'], life.active))
        feeder.decisions = []
    # every hold ever collected (raw; the store keeps them all at this size)
    holds = life.store.recent
    swaps = []
    for (ts, new), (_, old) in zip(actives[1:], actives[:-1]):
        later = holds.select(holds.t0 > ts) if len(holds) else holds
        row = {'time_s': ts - imu.stamp_ns[0] * 1e-9, 'id': new.id, 'later_holds': 0}
        if len(later) and len(later.hold_ids) >= 2:
            sn, so = (gate.score(c, later, new.gravity) for c in (new, old))
            swap, fig = gate.decide(so, sn)
            row.update(later_holds=int(len(later.hold_ids)), figures=fig,
                       harmful=bool(fig['gyro']['verdict'] == 'worse'
                                    or fig['accel']['verdict'] == 'worse'
                                    or fig['net_margins'] < -1.0),
                       text=gate.describe(fig))
        swaps.append(row)
    followed = follower_rows(d)
    scores = published_against_model(follower_timeline(d, 0.0), holds, actives)
    return {'recording': name, 'path': path, 'piece_s': piece,
            'follower_offsets': sum('offset_rad_s' in x for x in followed),
            'follower_why': sorted({x['why'] for x in followed if 'why' in x}),
            'follower_scores': scores,
            'holds': life.store.total_holds, 'decisions': life.decisions(),
            'swaps': swaps, 'harmful_swaps': sum(bool(s.get('harmful')) for s in swaps)}


def published_against_model(published, holds, actives):
    """Score the follower on a real recording's holds, each by what was published before it.

    ``published``: ``follower_timeline`` of the recording's directory (times on the
    holds' clock); ``holds``: the store's raw windows; ``actives``: (swap time s, model)
    on their clock. Per hold whose start saw an offset published for the model active
    then: the gyro error (rad/s, ``gate.hold_errors`` without a latitude: the norm of the
    compensated mean, the model's convention) of the published calibration and of the
    model alone. Returns the holds scored and the two RMS (None when no hold had one).
    """
    from thermal_imu_calib.lifelong import gate
    pub, mod = [], []
    for hid in (holds.hold_ids if len(holds) else []):
        one = holds.select(holds.hold == hid)
        t0 = float(one.t0.min())
        model = [c for t, c in actives if t <= t0][-1]
        cal = published(t0, model)
        if cal is model:                    # no model, or no offset published for it
            continue
        pub.append(gate.hold_errors(cal, one, model.gravity)['gyro'][0])
        mod.append(gate.hold_errors(model, one, model.gravity)['gyro'][0])
    if not pub:
        return None
    return {'holds': len(pub), 'published_rms_rad_s': float(np.sqrt(np.mean(np.square(pub)))),
            'model_rms_rad_s': float(np.sqrt(np.mean(np.square(mod))))}


def real(args):
    work = args.work or tempfile.mkdtemp(prefix='bench_lifelong_real_')
    rows = []
    for name in ('bmi270', 'chamber'):
        r = run_real(name, work, config=LifelongConfig(
            placement_folds=args.placement_folds, placement_floor=args.placement_floor,
            range_sensors=args.range_sensors, placement_levels=args.placement_levels,
            placement_levels_sensors=args.placement_levels_sensors,
            gyro_continuation=args.gyro_continuation,
            gyro_ageing_forward=args.gyro_ageing_forward,
            gyro_pooled_gate=args.gyro_pooled_gate,
            swap_must_explain=args.swap_must_explain, gyro_follow=args.gyro_follow,
            follow_without_latitude=args.follow_without_latitude,
            incumbent_spec=args.incumbent_spec,
            prequential_holds=args.prequential_holds))
        rows.append(r)
        fixture = os.sep + 'fixtures' + os.sep in r['path']
        print(f'{name}: {r["holds"]} holds, decisions '
              f'{[d["action"] for d in r["decisions"]]}, swaps {len(r["swaps"])}, harmful '
              f'{r["harmful_swaps"]} ({r["path"]}'
              + ('; the test fixture\'s slice: set THERMAL_REAL_DATA to the shared '
                 'recordings for the whole' if fixture else '') + ')')
        for s in r['swaps']:
            print(f'  swap at {s["time_s"]:.0f} s ({s["later_holds"]} later holds): '
                  f'{s.get("text", "no later holds to judge it on")}')
        fs = r['follower_scores']
        if fs:
            print(f'  follower: {fs["holds"]} holds after an offset, gyro RMS published '
                  f'{fs["published_rms_rad_s"] * 1e3:.4f} mrad/s, model '
                  f'{fs["model_rms_rad_s"] * 1e3:.4f}')
    _write(args.output, {'command': ' '.join(sys.argv), 'rows': rows})


def history_alarms(reg, knock_day):
    """Return what ``thermal-imu-calib history`` flags on a lifelong registry."""
    from thermal_imu_calib.fleet import registry
    from thermal_imu_calib.sim.robot_month import MONTH_EPOCH_NS
    rows = registry.read_index(reg)
    alarms, info = registry.assess(rows)
    knock = MONTH_EPOCH_NS + int(knock_day * DAY * 1e9) if np.isfinite(knock_day) else None
    flagged = [a for v in alarms.values() for a in v]
    return {'calibrations': len(rows), 'alarms': flagged,
            'threshold_sigma': info['threshold_sigma'],
            'changes_after_knock': [a for a in flagged if knock and 'changed' in a and
                                    registry.parse_time(a.split('-> ')[1][:16]) >= knock]}


def reeval_seed(work_seed, seed, days, in_model=False, **month):
    """Score a finished month again from its lifelong directory (registry = the timeline).

    ``in_model``: as in ``evaluate``; ``month``: ``RobotMonthConfig`` fields the month ran
    with (e.g. ``dock_fraction``).
    """
    with open(os.path.join(work_seed, 'decisions.jsonl')) as f:
        decisions = [json.loads(x) for x in f if x.strip()]
    return registry_scores(robot_month(seed, days=days, **month), work_seed, decisions,
                           in_model)


def registry_scores(m, work_seed, decisions, in_model=False):
    """Score month ``m`` from its lifelong directory: the registry is the timeline."""
    from thermal_imu_calib.calibration import Calibration
    from thermal_imu_calib.fleet import registry
    base = m.start_ns * 1e-9
    rows = registry.read_index(os.path.join(work_seed, 'registry'))
    timeline = [(-np.inf, None)] + [
        (registry.parse_time(r['time']) * 1e-9 - base,
         Calibration.load(os.path.join(work_seed, 'registry', r['file']))) for r in rows]
    stops, models = [], []
    published = follower_timeline(work_seed, base)
    for seg, ch in scored_stops(m):
        cal = [c for t, c in timeline if t <= seg.stop.t0][-1]
        stops.append((seg.stop.t0, published(seg.stop.t0, cal), ch))
        models.append(cal)
    return evaluate(m, stops, timeline, decisions, gyro_noise(m), base,
                    models if published.used else None, in_model)


def follower_rows(d):
    """Return the gyro follower's log of lifelong directory ``d`` (dicts), [] without one."""
    from thermal_imu_calib.lifelong import files
    from thermal_imu_calib.lifelong.manager import FOLLOWER_LOG
    path = os.path.join(d, FOLLOWER_LOG)
    return files.read_decisions(path) if os.path.exists(path) else []


def follower_timeline(work_seed, base):
    """Return ``published(t, model)``: what a month's node published at ``t`` s.

    From the gyro follower's log (``follower_rows``): the model with the offset of the
    newest record at or before ``t`` that names it; without a log, or no such record, the
    model itself. ``published.used``: a log was found.
    """
    from thermal_imu_calib.lifelong import follower
    rows = follower_rows(work_seed)
    times = np.array([r['time'] - base for r in rows])

    def published(t, model):
        if model is None or not rows:
            return model
        i = int(np.searchsorted(times, t, side='right')) - 1
        if i < 0 or rows[i].get('active') != model.id or 'offset_rad_s' not in rows[i]:
            return model
        return follower.with_offset(model, rows[i]['offset_rad_s'], rows[i]['time'],
                                    DEFAULT.follow_horizon_days)
    published.used = bool(rows)
    return published


def reeval(args):
    """Re-score month result files from their --work directories (same metrics for all)."""
    rows = []
    for path in args.inputs:
        with open(path) as f:
            rows += json.load(f)['rows']
    out = []
    for r in sorted(rows, key=lambda r: r['seed']):
        for work in args.work:
            d = os.path.join(work, f'seed{r["seed"]}')
            if os.path.isdir(os.path.join(d, 'registry')):
                new = reeval_seed(d, r['seed'], r['summary']['days'])
                keep = {k: r[k] for k in ('seed', 'seconds', 'peak_rss_mb', 'peak_dir_mb',
                                          'summary', 'store', 'registry_rows')}
                out.append(new | keep | {'history_alarms': history_alarms(
                    os.path.join(d, 'registry'), r['knock']['day'])})
                print(f'seed {r["seed"]} re-scored', flush=True)
                break
    _write(args.output, {'command': ' '.join(sys.argv), 'seeds': [x['seed'] for x in out],
                         'rows': out, 'summary': summarise(out)})
    print(json.dumps(summarise(out), indent=1))


def merge(args):
    """Merge month result files (seeds run in parallel processes) into one."""
    rows, commands = [], []
    for path in args.inputs:
        with open(path) as f:
            d = json.load(f)
        rows += d['rows']
        commands.append(d['command'])
    rows.sort(key=lambda r: r['seed'])
    for r in rows:                       # the registry's drift alarms (history) per seed
        for work in args.work:
            reg = os.path.join(work, f'seed{r["seed"]}', 'registry')
            if os.path.isdir(reg):
                r['history_alarms'] = history_alarms(reg, r['knock']['day'])
    _write(args.output, {'command': ' ; '.join(commands), 'days': rows[0]['summary']['days'],
                         'seeds': [r['seed'] for r in rows], 'rows': rows,
                         'summary': summarise(rows)})
    print(json.dumps(summarise(rows), indent=1))


def node_rss(args):
    """Start calibrator_node in lifelong mode on a copy of a month's lifelong directory.

    Reports the node process's RSS once it has loaded the state and published the active
    calibration (what a robot's node holds after a month), and the directory's size.
    """
    import subprocess
    d = os.path.join(tempfile.mkdtemp(prefix='bench_lifelong_node_'), 'life')
    shutil.copytree(args.dir, d)
    proc = subprocess.Popen([sys.executable, '-m', 'thermal_imu_calib.nodes.calibrator',
                             '--ros-args', '-p', 'lifelong:=true', '-p',
                             f'lifelong_dir:={d}', '-p', 'frame_id:=imu_link', '-p',
                             f'collection_file:={d}/collection.jsonl', '-p',
                             f'calibration_file:={d}/calibration.yaml'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rss, t0 = 0.0, time.monotonic()
    try:
        while time.monotonic() - t0 < args.seconds:
            time.sleep(1.0)
            with open(f'/proc/{proc.pid}/status') as f:
                for line in f:
                    if line.startswith('VmRSS:'):
                        rss = max(rss, int(line.split()[1]) / 1024)
    finally:
        proc.terminate()
        out = proc.communicate(timeout=30)[0]
    res = {'dir': args.dir, 'dir_mb': dir_bytes(args.dir) / 2 ** 20, 'node_rss_mb': rss,
           'log': out.strip().splitlines()[-5:]}
    print(json.dumps(res, indent=1))
    _write(args.output, res)


def _proc_status(pid):
    """Return {'rss_mb', 'hwm_mb'} of process ``pid`` from /proc (MB; {} when gone)."""
    out = {}
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    out['rss_mb'] = int(line.split()[1]) / 1024
                elif line.startswith('VmHWM:'):
                    out['hwm_mb'] = int(line.split()[1]) / 1024
    except OSError:
        pass
    return out


def _dds_events(seg, base_ns):
    """Return the stop's messages in header-stamp order: (stamp ns, kind, index, sync).

    kind 0: IMU sample, 1: temperature reading, 2: cmd_vel hint. ``sync`` marks the hints
    the node must stamp right (a change of the command, the segment's last one): before
    them the replay waits until the node has taken in every IMU message sent.
    """
    ev = [(int(s), 0, i, False) for i, s in enumerate(seg.imu.stamp_ns)]
    ev += [(int(s), 1, i, False) for i, s in enumerate(seg.temperature.stamp_ns)]
    prev = None
    for i, (t, still) in enumerate(seg.hints):
        sync = still != prev or i == len(seg.hints) - 1
        ev.append((base_ns + int(round((t - base_ns * 1e-9) * 1e9)), 2, i, sync))
        prev = still
    ev.sort(key=lambda e: (e[0], e[1]))
    return ev


def dds(args):
    """Replay robot-month days through DDS into calibrator_node; sample its RSS and directory.

    calibrator_node runs in its own process (``python -m thermal_imu_calib.nodes.calibrator``,
    lifelong mode with the /cmd_vel hint, the default settings otherwise); this process
    generates the month (``sim.robot_month``, the stops only, 10 Hz) and publishes every
    IMU message, temperature reading and cmd_vel command in header-stamp order, as fast as
    the node takes them: at most ``--window`` IMU messages in flight (counted by the node's
    ~/progress ``imu_received``), below its input queue depth, so nothing is dropped. The
    node stamps a Twist with the newest IMU stamp it processed: before a change of the
    command the replay waits until the node has taken in all IMU sent and two more
    ~/progress ticks. The node is not restarted (the month's restarts are not replayed).
    The node process's RSS (``/proc/<pid>/status`` VmRSS, VmHWM) is sampled every
    ``--sample-s`` seconds and at the end of every simulated day, with the lifelong
    directory's size and the store counts /diagnostics reports; the JSON is rewritten after
    every day, so a run cut by ``--max-seconds`` keeps what it replayed.
    """
    import subprocess
    import threading
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist
    from sensor_msgs.msg import Imu, Temperature
    from std_msgs.msg import String
    from thermal_imu_calib.nodes.player import imu_msg, temperature_msg

    m = robot_month(args.seed)
    cfg = m.config
    work = args.work or tempfile.mkdtemp(prefix='bench_lifelong_dds_')
    d = os.path.join(work, 'life')
    shutil.rmtree(d, ignore_errors=True)
    os.makedirs(d)
    log_path = os.path.join(work, 'node.log')
    cmd = [sys.executable, '-m', 'thermal_imu_calib.nodes.calibrator', '--ros-args',
           '-p', 'lifelong:=true', '-p', f'lifelong_dir:={d}', '-p', 'cmd_vel_topic:=/cmd_vel',
           '-p', f'frame_id:={cfg.frame_id}', '-p', f'collection_file:={work}/collection.jsonl',
           '-p', f'calibration_file:={work}/calibration.yaml', '-p', 'report:=false',
           '-p', f'progress_period:={args.progress_period}']
    log_file = open(log_path, 'w')
    proc = subprocess.Popen(cmd, stdout=log_file, stderr=subprocess.STDOUT)
    rclpy.init()
    node = rclpy.create_node('bench_lifelong_player')
    imu_pub = node.create_publisher(Imu, cfg.imu_topic, 1000)
    temp_pub = node.create_publisher(Temperature, cfg.temp_topic, 1000)
    cmd_pub = node.create_publisher(Twist, '/cmd_vel', 100)
    state = {'received': 0, 'ticks': 0, 'life': {}}
    cond = threading.Condition()

    def on_progress(msg):
        p = json.loads(msg.data)
        with cond:
            state['received'] = p['imu_received']
            state['ticks'] += 1
            cond.notify_all()

    def on_diag(msg):
        for s in msg.status:
            if s.name.endswith('lifelong calibration'):
                state['life'] = {kv.key: kv.value for kv in s.values}
    node.create_subscription(String, '/thermal_imu_calibrator/progress', on_progress, 100)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    spinner = threading.Thread(target=ex.spin, daemon=True)
    spinner.start()

    def wait(pred, what, timeout=args.timeout):
        with cond:
            if not cond.wait_for(pred, timeout):
                raise RuntimeError(f'timed out after {timeout} s waiting for {what} '
                                   f'(node log: {log_path})')
    samples, days, stop_sampling = [], [], threading.Event()
    t_start = time.monotonic()

    def sampler():
        while not stop_sampling.wait(args.sample_s):
            st = _proc_status(proc.pid)
            if st:
                samples.append((round(time.monotonic() - t_start, 1),
                                round(st['rss_mb'], 1)))
    wait(lambda: state['ticks'] > 0, 'the node\'s first ~/progress', 120.0)
    for pub in (imu_pub, temp_pub, cmd_pub):
        t0 = time.monotonic()
        while pub.get_subscription_count() == 0:
            if time.monotonic() - t0 > 120.0:
                raise RuntimeError(f'no subscriber on {pub.topic_name}')
            time.sleep(0.05)
    start_rss = _proc_status(proc.pid)
    threading.Thread(target=sampler, daemon=True).start()
    base_ns = m.start_ns
    sent = {'imu': 0, 'temperature': 0, 'cmd_vel': 0}
    twist_drive, twist_still = Twist(), Twist()
    twist_drive.linear.x = 0.5
    out = {'command': ' '.join(sys.argv), 'seed': args.seed, 'node_command': ' '.join(cmd),
           'month': m.summary(), 'start_node_rss_mb': start_rss, 'days': days,
           'rss_samples': samples}

    def caught_up(extra_ticks=0):
        n = sent['imu']
        wait(lambda: state['received'] >= n, 'the node to take in the IMU messages sent')
        if extra_ticks:
            t = state['ticks']
            wait(lambda: state['ticks'] >= t + extra_ticks, 'two more ~/progress ticks')

    def record(day, last_t):
        caught_up()
        st = _proc_status(proc.pid)
        row = {'day': day, 'replayed_to_day': round(last_t / DAY, 3),
               'wall_s': round(time.monotonic() - t_start, 1), 'imu_sent': sent['imu'],
               'imu_received': state['received'], 'node_rss_mb': round(st.get('rss_mb', 0), 1),
               'node_peak_rss_mb': round(st.get('hwm_mb', 0), 1),
               'dir_mb': round(dir_bytes(d) / 2 ** 20, 3),
               'bench_rss_mb': round(rss_mb(), 1)}
        row.update({k: state['life'].get(k) for k in (
            'holds_total', 'raw_holds', 'raw_windows', 'compacted_bins', 'clusters', 'swaps',
            'kept', 'alarms', 'estimates', 'disk_bytes')})
        days.append(row)
        print(json.dumps(row), flush=True)
        out.update(wall_s=row['wall_s'], replayed_days=row['replayed_to_day'], sent=dict(sent))
        _write(args.output, out)

    day, last_t, cut = 0, 0.0, ''
    try:
        for s in m.stops:
            if s.t0 >= args.days * DAY:
                break
            if time.monotonic() - t_start > args.max_seconds:
                cut = f'stopped by --max-seconds {args.max_seconds:.0f}'
                break
            while s.t0 >= (day + 1) * DAY:
                record(day, last_t)
                day += 1
            seg = m.segment(s)
            accel, gyro = seg.imu.accel.tolist(), seg.imu.gyro.tolist()
            temps = seg.temperature.temperature.tolist()
            for stamp, kind, i, sync in _dds_events(seg, base_ns):
                if kind == 0:
                    if sent['imu'] - state['received'] >= args.window:
                        n = sent['imu'] - args.window // 2
                        wait(lambda: state['received'] >= n, 'the node to take in IMU')
                    imu_pub.publish(imu_msg(stamp, accel[i], gyro[i], cfg.frame_id))
                    sent['imu'] += 1
                elif kind == 1:
                    temp_pub.publish(temperature_msg(stamp, temps[i], cfg.frame_id))
                    sent['temperature'] += 1
                else:
                    if sync:
                        caught_up(extra_ticks=2)
                    cmd_pub.publish(twist_still if seg.hints[i][1] else twist_drive)
                    sent['cmd_vel'] += 1
            last_t = s.t1 + cfg.pad_s
        record(day, last_t)
        # the node's last estimate may still run: wait for the estimates to settle
        out['stopped'] = cut or f'replayed {args.days:g} days'
    finally:
        stop_sampling.set()
        st = _proc_status(proc.pid)
        out['end_node_peak_rss_mb'] = round(st.get('hwm_mb', 0), 1)
        out['peak_dir_mb'] = max((r['dir_mb'] for r in days), default=0)
        proc.send_signal(2)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
        log_file.close()
        out['node_exit'] = proc.returncode
        with open(log_path) as f:
            lines = f.read().splitlines()
        out['node_log_tail'] = lines[-8:]
        out['decisions'] = {}
        try:
            with open(os.path.join(d, 'decisions.jsonl')) as f:
                for x in f:
                    if x.strip():
                        a = json.loads(x)['action']
                        out['decisions'][a] = out['decisions'].get(a, 0) + 1
        except OSError:
            pass
        out['sent'] = dict(sent)
        _write(args.output, out)
        ex.shutdown()
        spinner.join(timeout=10)
        node.destroy_node()
        rclpy.shutdown()
    print(json.dumps({k: out[k] for k in ('replayed_days', 'wall_s', 'sent', 'stopped',
                                          'end_node_peak_rss_mb', 'peak_dir_mb',
                                          'decisions') if k in out}, indent=1))


def table(args):
    """Print the markdown tables of docs/lifelong.md from a merged month result."""
    with open(args.input) as f:
        d = json.load(f)
    mr = 1e3
    print('| seed | gyro first day | last week | true model | last/first | last/true | '
          'accel first day | last week | last/first | per-sample gyro last/true | swaps '
          '(next day worse: gyro, accel) | knock day, alarm delay h, false alarms | gyro day '
          'before / 2nd day after knock | peak RSS MB | peak dir MB | s |')
    print('|' + '---|' * 16)
    for r in d['rows']:
        a, t, ra, k = r['active'], r['true'], r['ratios'], r['knock']
        delay = 'none' if k['alarm_delay_h'] is None else f'{k["alarm_delay_h"]:.1f}'
        print(f'| {r["seed"]} | {a["gyro_first_day"] * mr:.3f} | {a["gyro_last_week"] * mr:.3f} '
              f'| {t["gyro_last_week"] * mr:.3f} | {ra["gyro_last_week_over_first_day"]:.2f} | '
              f'{ra["gyro_last_week_over_true"]:.1f} | {a["accel_first_day"] * mr:.1f} | '
              f'{a["accel_last_week"] * mr:.1f} | {ra["accel_last_week_over_first_day"]:.2f} | '
              f'{ra["gyro_sample_last_week_over_true"]:.2f} | {r["swaps_total"]} '
              f'({r["swaps_worse_gyro"]}, {r["swaps_worse_accel"]}) | {k["day"]:.1f}, {delay}, '
              f'{k["alarms_before"]} | {k["gyro_day_before"] * mr:.3f} / '
              f'{k["gyro_second_day_after"] * mr:.3f} | {r["peak_rss_mb"]:.0f} | '
              f'{r["peak_dir_mb"]:.1f} | {r["seconds"]:.0f} |')
    print()
    print('| seed | accel drift first day | last week | true model | last/first | days from '
          'knock to gyro error <= 2x pre-knock | swaps worse next day by > 25 %: gyro, accel '
          'drift |')
    print('|' + '---|' * 7)
    for r in d['rows']:
        a, t, k = r['active'], r['true'], r['knock']
        kd = int(np.floor(k['day']))
        rec = next((i - kd for i, v in enumerate(r['daily_gyro'])
                    if i > kd and v <= 2 * k['gyro_day_before']), None)
        g25, a25 = _worse25(r)
        print(f'| {r["seed"]} | {a["accel_drift_first_day"] * mr:.1f} | '
              f'{a["accel_drift_last_week"] * mr:.1f} | {t["accel_drift_last_week"] * mr:.2f} | '
              f'{r["ratios"]["accel_drift_last_week_over_first_day"]:.2f} | {rec} | {g25}, '
              f'{a25} |')
    print()
    print(json.dumps(d['summary'], indent=1))


def _worse25(r, swaps=None):
    """Return (gyro, accel drift) counts of swaps whose next day was worse by > 25 %.

    ``swaps``: those of ``r``'s swap rows to count (default: all)."""
    swaps = r['swaps'] if swaps is None else swaps
    return (sum(s['gyro_new'] > 1.25 * s['gyro_old'] for s in swaps),
            sum(s['accel_drift_new'] > 1.25 * s['accel_drift_old'] for s in swaps))


def _worse25_own(r, other, tol_days=0.01):
    """Return ``_worse25``'s (gyro, accel drift) counts over the swaps of ``r`` that the
    ``other`` month (the same seed, the other arm) has no swap within ``tol_days`` of."""
    there = np.array([s['day'] for s in other['swaps']])
    own = [s for s in r['swaps'] if not np.any(np.abs(there - s['day']) <= tol_days)]
    return _worse25(r, own)


def _acted(work, seed, text):
    """Return how many swap decisions of a month's directory contain ``text`` (None: none)."""
    path = os.path.join(work, f'seed{seed}', 'decisions.jsonl')
    if not os.path.exists(path):
        return None
    with open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    return sum(d.get('action') == 'swap' and text in d.get('text', '') for d in rows)


def compare(args):
    """Print two month results side by side on their common seeds, with geometric means."""
    runs = []
    for path in (args.base, args.candidate):
        with open(path) as f:
            runs.append({r['seed']: r for r in json.load(f)['rows']})
    seeds = sorted(set(runs[0]) & set(runs[1]))
    print('| seed | gyro last/true: base / candidate | accel drift last week mm/s^2 | '
          'swaps | worse next day > 25 % (gyro + accel drift) | knock alarm delay h | '
          'false alarms | rule acted (swaps) |')
    print('|' + '---|' * 8)
    geo = {'g': [[], []], 'a': [[], []], 'a1': [[], []], 'g1': [[], []], 'k2': [[], []]}
    tot, own = [0, 0], [0, 0]
    for seed in seeds:
        b, c = runs[0][seed], runs[1][seed]
        for i, r in enumerate((b, c)):
            geo['g'][i].append(r['ratios']['gyro_last_week_over_true'])
            geo['a'][i].append(r['active']['accel_drift_last_week'])
            geo['a1'][i].append(r['active']['accel_drift_first_day'])
            geo['g1'][i].append(r['active']['gyro_first_day'])
            geo['k2'][i].append(r['knock']['gyro_second_day_after'])
            tot[i] += sum(_worse25(r))
            own[i] += sum(_worse25_own(r, (c, b)[i]))
        delay = ['none' if r['knock']['alarm_delay_h'] is None else
                 f'{r["knock"]["alarm_delay_h"]:.1f}' for r in (b, c)]
        acted = _acted(args.work, seed, args.grep) if args.work and args.grep else None
        cells = [f'{b["ratios"]["gyro_last_week_over_true"]:.2f} / '
                 f'{c["ratios"]["gyro_last_week_over_true"]:.2f}',
                 f'{b["active"]["accel_drift_last_week"] * 1e3:.1f} / '
                 f'{c["active"]["accel_drift_last_week"] * 1e3:.1f}',
                 f'{b["swaps_total"]} / {c["swaps_total"]}',
                 f'{sum(_worse25(b))} / {sum(_worse25(c))}', ' / '.join(delay),
                 f'{b["knock"]["alarms_before"]} / {c["knock"]["alarms_before"]}',
                 '' if acted is None else str(acted)]
        print(f'| {seed} | ' + ' | '.join(cells) + ' |')

    gm = geometric_mean
    print(f'\ngeometric mean over seeds {seeds}: gyro last/true {gm(geo["g"][0]):.3f} -> '
          f'{gm(geo["g"][1]):.3f} ({gm(geo["g"][1]) / gm(geo["g"][0]) - 1:+.1%}); accel drift '
          f'last week {gm(geo["a"][0]) * 1e3:.2f} -> {gm(geo["a"][1]) * 1e3:.2f} mm/s^2 '
          f'({gm(geo["a"][1]) / gm(geo["a"][0]) - 1:+.1%}); swaps worse next day by > 25 % '
          f'(gyro + accel drift) {tot[0]} -> {tot[1]} (of them in swaps the other arm does '
          f'not make: {own[0]} -> {own[1]}); gyro on the second day after the '
          f'knock {gm(geo["k2"][0]) * 1e3:.3f} -> {gm(geo["k2"][1]) * 1e3:.3f} mrad/s '
          f'({gm(geo["k2"][1]) / gm(geo["k2"][0]) - 1:+.1%})')
    raw = [runs[1][seed]['raw'] for seed in seeds]
    print(f'first day: accel drift {gm(geo["a1"][0]) * 1e3:.2f} -> {gm(geo["a1"][1]) * 1e3:.2f} '
          f'mm/s^2 ({gm(geo["a1"][1]) / gm(geo["a1"][0]) - 1:+.1%}; raw '
          f'{gm([r["accel_drift_first_day"] for r in raw]) * 1e3:.2f}), gyro '
          f'{gm(geo["g1"][0]) * 1e3:.3f} -> {gm(geo["g1"][1]) * 1e3:.3f} mrad/s '
          f'({gm(geo["g1"][1]) / gm(geo["g1"][0]) - 1:+.1%}; raw '
          f'{gm([r["gyro_first_day"] for r in raw]) * 1e3:.3f}); last week raw accel drift '
          f'{gm([r["accel_drift_last_week"] for r in raw]) * 1e3:.2f} mm/s^2')


def geometric_mean(x):
    """Return the geometric mean of positive numbers ``x``."""
    return float(np.exp(np.mean(np.log(x))))


def follower_table(args):
    """Print the gyro follower's criteria table: published against model, one run each.

    Each ``SEED:WORK/seedSEED`` of a month run with ``--gyro-follow`` is re-scored from its
    directory (``registry_scores``: the registry and ``follower.jsonl``).
    """
    rows = []
    for spec in args.runs:
        seed, d = spec.split(':', 1)
        rows.append(reeval_seed(d, int(seed), args.days, args.earth_rate_in_model,
                                dock_fraction=args.dock_fraction) | {'seed': int(seed)})
    mr = 1e3
    print('| seed | gyro last week / true: model / published | first day mrad/s: model / '
          'published | 2nd day after the knock mrad/s: model / published | knock alarm h, '
          'false alarms | swaps (worse next day > 25 %: gyro, accel drift) |')
    print('|' + '---|' * 6)
    geo = {k: [] for k in ('lm', 'lp', 'fm', 'fp', 'km', 'kp')}
    for r in rows:
        ra, k, a, m = r['ratios'], r['knock'], r['active'], r['model']
        vals = dict(lm=ra['model_gyro_last_week_over_true'], lp=ra['gyro_last_week_over_true'],
                    fm=m['gyro_first_day'], fp=a['gyro_first_day'],
                    km=k['model_gyro_second_day_after'], kp=k['gyro_second_day_after'])
        for key, v in vals.items():
            geo[key].append(v)
        delay = 'none' if k['alarm_delay_h'] is None else f'{k["alarm_delay_h"]:.1f}'
        g25, a25 = _worse25(r)
        print(f'| {r["seed"]} | {vals["lm"]:.2f} / {vals["lp"]:.2f} | {vals["fm"] * mr:.3f} / '
              f'{vals["fp"] * mr:.3f} | {vals["km"] * mr:.3f} / {vals["kp"] * mr:.3f} | '
              f'{delay}, {k["alarms_before"]} | {r["swaps_total"]} ({g25}, {a25}) |')

    # a month shorter than the knock's second day after has no figure there: left out
    g = {key: geometric_mean(np.asarray(v)[np.isfinite(v)]) if np.isfinite(v).any()
         else float('nan') for key, v in geo.items()}
    print(f'\ngeometric means: last/true {g["lm"]:.3f} -> {g["lp"]:.3f} '
          f'({g["lp"] / g["lm"] - 1:+.1%}); first day {g["fm"] * mr:.4f} -> {g["fp"] * mr:.4f} '
          f'mrad/s ({g["fp"] / g["fm"] - 1:+.1%}); 2nd day after the knock {g["km"] * mr:.4f} '
          f'-> {g["kp"] * mr:.4f} mrad/s ({g["kp"] / g["km"] - 1:+.1%}); worst month, '
          f'published over model: '
          f'{max(p / m for p, m in zip(geo["lp"], geo["lm"])) - 1:+.1%}; within 1.5x true: '
          f'model {sum(v <= 1.5 for v in geo["lm"])}, published '
          f'{sum(v <= 1.5 for v in geo["lp"])} of {len(rows)}')
    if args.output:
        _write(args.output, {'command': ' '.join(sys.argv), 'rows': rows,
                             'geometric_means': g})


def option(parser, field, text):
    """Add ``--field`` (and ``--no-field``) for a boolean ``LifelongConfig`` field."""
    parser.add_argument('--' + field.replace('_', '-'), action=argparse.BooleanOptionalAction,
                        default=getattr(DEFAULT, field),
                        help=f'{text} (LifelongConfig.{field}; default: the package\'s)')


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest='cmd')
    mo = sub.add_parser('month')
    mo.add_argument('--seeds', type=int, default=20)
    mo.add_argument('--first-seed', type=int, default=0)
    mo.add_argument('--days', type=float, default=30.0)
    mo.add_argument('--work', default='')
    mo.add_argument('--latitude', type=float, default=None,
                    help='give the calibrations the latitude (deg; the month is at 45)')
    mo.add_argument('--no-ageing', action='store_true',
                    help='without the gyro ageing candidate (LifelongConfig.ageing False)')
    mo.add_argument('--whole-swap', action='store_true',
                    help='swap whole calibrations only (LifelongConfig.per_sensor False)')
    mo.add_argument('--alarm-window', choices=ALARM_WINDOWS, default=DEFAULT.alarm_window,
                    help='holds the change alarm watches (LifelongConfig.alarm_window)')
    mo.add_argument('--one-sensor-after-alarm', action='store_true',
                    help='one-sensor swaps after a change alarm too '
                         '(LifelongConfig.one_sensor_after_alarm)')
    mo.add_argument('--alarm-reference', choices=ALARM_REFERENCES,
                    default=DEFAULT.alarm_reference,
                    help='holds a swap measures the change alarm\'s reference on '
                         '(LifelongConfig.alarm_reference)')
    mo.add_argument('--alarm-cut', choices=ALARM_CUTS, default=DEFAULT.alarm_cut,
                    help='what a change alarm does with the older holds: drop both sensors\' '
                         'history, the flagged sensor\'s only, or shift them by the step the '
                         'newer holds show (LifelongConfig.alarm_cut)')
    mo.add_argument('--accel-score', choices=ACCEL_SCORES, default=DEFAULT.accel_score,
                    help='how the swap gate measures the accelerometer on held-out holds '
                         '(LifelongConfig.accel_score)')
    mo.add_argument('--raw-kept', action='store_true',
                    help='with no active calibration, a one-sensor swap leaves the other '
                         'sensor raw (LifelongConfig.raw_kept)')
    mo.add_argument('--refit-on-swap', action='store_true',
                    help='a swap puts in use the estimate fitted again on every hold '
                         '(LifelongConfig.refit_on_swap)')
    mo.add_argument('--out-of-range', choices=OUT_OF_RANGE_POLICIES,
                    default=CalibrateSettings.out_of_range,
                    help='the calibrations\' out-of-range policy (CalibrateSettings.'
                         'out_of_range)')
    option(mo, 'gyro_g_sensitivity', 'the gyro also takes the g-sensitivity the stops off '
           'the mounting pose support, held out')
    mo.add_argument('--gyro-continuation', choices=GYRO_CONTINUATIONS,
                    default=DEFAULT.gyro_continuation,
                    help='the gyro beyond its range: off (the calibrate policy), history '
                         '(continued when the holds outside earlier ranges support it) or '
                         'span (the same on the holds of calibrations spanning at least '
                         'half the new one\'s span; LifelongConfig.gyro_continuation)')
    mo.add_argument('--incumbent-spec', choices=INCUMBENT_SPECS,
                    default=DEFAULT.incumbent_spec,
                    help='the spec of the model in use offered to the next estimate, kept '
                         'while within the margin of the best (LifelongConfig.incumbent_spec)')
    mo.add_argument('--prequential-holds', type=int, default=DEFAULT.prequential_holds,
                    help='a swap the gate passes waits for this many later holds and takes '
                         'effect when they favour it (LifelongConfig.prequential_holds)')
    option(mo, 'gyro_ageing_forward', 'an estimate fitted with the gyro ageing removed carries '
           'the rates forward in time in its file')
    option(mo, 'gyro_pooled_gate', 'the gyro swap also judged on the held-out holds of '
           'successive estimates pooled')
    option(mo, 'swap_must_explain', 'no swap to a calibration that misses misfit_holds of the '
           'held-out holds by the change alarm\'s limit')
    option(mo, 'alarm_first', 'no re-estimate while the change alarm is deciding')
    option(mo, 'gyro_follow', 'the published gyro has the newest holds\' miss of the active '
           'model taken off (scored as published; the model alone as "model")')
    option(mo, 'follow_without_latitude', 'without --latitude the follower follows in the '
           'model\'s convention (scored so: the vertical earth rate counted as bias)')
    mo.add_argument('--high-order-margin', type=margin_or_off, metavar='DEGC|off',
                    default=CalibrateSettings.high_order_margin,
                    help='valid-range margin (degC) of a model above first order in '
                         'temperature, or off (CalibrateSettings.high_order_margin; default: '
                         'the package\'s)')
    mo.add_argument('--high-order-sensors', choices=tuple(HIGH_ORDER_SENSORS),
                    default=CalibrateSettings.high_order_sensors,
                    help='the sensors --high-order-margin applies to')
    mo.add_argument('--placement-folds', action=argparse.BooleanOptionalAction,
                    default=DEFAULT.placement_folds,
                    help='held-out folds never keep a test stop\'s other windows in training '
                         '(LifelongConfig.placement_folds; default: the package\'s)')
    mo.add_argument('--placement-floor', action=argparse.BooleanOptionalAction,
                    default=DEFAULT.placement_floor,
                    help='one-way first estimates: a sensor\'s thermal model must beat its raw '
                         'output on held-out stops (LifelongConfig.placement_floor; default: '
                         'the package\'s)')
    mo.add_argument('--placement-levels', action=argparse.BooleanOptionalAction,
                    default=DEFAULT.placement_levels,
                    help='a random level per stop in the thermal-history fits (REML; '
                         'LifelongConfig.placement_levels; default: the package\'s)')
    mo.add_argument('--checkpoints', action='store_true',
                    help='copy each lifelong directory at each of the month\'s restarts to '
                    '<work>/seedN.restartK (the restart reads that directory only)')
    mo.add_argument('--resume', action='store_true',
                    help='continue each seed from its latest checkpoint in --work (the '
                    'decisions are those of an uninterrupted run; scored from the registry)')
    mo.add_argument('--stop-day', type=float, default=None,
                    help='stop the month after this day (the first days only; no month '
                         'figures: score them with bench/lifelong_first_day.py)')
    mo.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_month.json'))
    re_ = sub.add_parser('real')
    for sp in (mo, re_):
        sp.add_argument('--placement-levels-sensors', choices=tuple(HIGH_ORDER_SENSORS),
                        default=DEFAULT.placement_levels_sensors,
                        help='the sensors --placement-levels applies to '
                             '(LifelongConfig.placement_levels_sensors)')
        sp.add_argument('--range-sensors', choices=RANGE_SENSORS,
                        default=DEFAULT.range_sensors,
                        help='whose own ranges bound the common range: every sensor\'s, or '
                             'only models that depend on temperature '
                             '(LifelongConfig.range_sensors; default: the package\'s)')
    re_.add_argument('--work', default='')
    for field in ('gyro_ageing_forward', 'gyro_pooled_gate', 'swap_must_explain',
                  'gyro_follow', 'follow_without_latitude'):
        option(re_, field, 'as in month')
    re_.add_argument('--gyro-continuation', choices=GYRO_CONTINUATIONS,
                     default=DEFAULT.gyro_continuation,
                     help='LifelongConfig.gyro_continuation (default: the package\'s)')
    re_.add_argument('--incumbent-spec', choices=INCUMBENT_SPECS,
                     default=DEFAULT.incumbent_spec,
                     help='LifelongConfig.incumbent_spec (default: the package\'s)')
    re_.add_argument('--prequential-holds', type=int, default=DEFAULT.prequential_holds,
                     help='LifelongConfig.prequential_holds (default: the package\'s)')
    for flag in ('folds', 'floor', 'levels'):
        re_.add_argument(f'--placement-{flag}', action=argparse.BooleanOptionalAction,
                         default=getattr(DEFAULT, f'placement_{flag}'),
                         help=f'LifelongConfig.placement_{flag} (default: the package\'s)')
    re_.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_real.json'))
    fo = sub.add_parser('follower', help='the gyro follower: published against model')
    fo.add_argument('runs', nargs='+', help='SEED:WORK/seedSEED of --gyro-follow month runs')
    fo.add_argument('--days', type=float, default=30.0)
    for sp in (mo, fo):
        sp.add_argument('--dock-fraction', type=float, default=0.0,
                        help='the fraction of stops level at one heading, a dock '
                             '(RobotMonthConfig.dock_fraction)')
    fo.add_argument('--earth-rate-in-model', action='store_true',
                    help='months run without --latitude, with --follow-without-latitude: '
                         'their calibrations scored in their own convention (the vertical '
                         'earth rate in the bias)')
    fo.add_argument('--output', default='')
    me = sub.add_parser('merge')
    me.add_argument('inputs', nargs='+')
    me.add_argument('--work', action='append', default=[],
                    help='month --work directories: add the registry history alarms')
    me.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_month.json'))
    no = sub.add_parser('node')
    no.add_argument('--dir', required=True, help='a month\'s lifelong directory')
    no.add_argument('--seconds', type=float, default=20.0)
    no.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_node.json'))
    dd = sub.add_parser('dds', help='replay days of a robot month through DDS into '
                        'calibrator_node; sample its RSS')
    dd.add_argument('--seed', type=int, default=0)
    dd.add_argument('--days', type=float, default=30.0)
    dd.add_argument('--max-seconds', type=float, default=np.inf,
                    help='stop after the stop in progress when the replay took this long')
    dd.add_argument('--window', type=int, default=400, help='IMU messages in flight at most')
    dd.add_argument('--progress-period', type=float, default=0.1)
    dd.add_argument('--sample-s', type=float, default=2.0)
    dd.add_argument('--timeout', type=float, default=600.0)
    dd.add_argument('--work', default='')
    dd.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_dds.json'))
    rv = sub.add_parser('reeval')
    rv.add_argument('inputs', nargs='+')
    rv.add_argument('--work', action='append', default=[])
    rv.add_argument('--output', default=os.path.join(RESULTS, 'bench_lifelong_month.json'))
    ta = sub.add_parser('table')
    ta.add_argument('input')
    co = sub.add_parser('compare', help='two month results side by side (common seeds)')
    co.add_argument('base')
    co.add_argument('candidate')
    co.add_argument('--work', default='', help="the candidate's --work (decision texts)")
    co.add_argument('--grep', default='', help='count the candidate\'s swap decisions whose '
                    'text contains this (did a rule act)')
    args = p.parse_args(sys.argv[1:] or ['month'])
    if args.cmd in (None, 'month'):
        month(args)
    elif args.cmd == 'merge':
        merge(args)
    elif args.cmd == 'node':
        node_rss(args)
    elif args.cmd == 'table':
        table(args)
    elif args.cmd == 'compare':
        compare(args)
    elif args.cmd == 'reeval':
        reeval(args)
    elif args.cmd == 'dds':
        dds(args)
    elif args.cmd == 'follower':
        follower_table(args)
    else:
        real(args)
    print(f'max RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB')


if __name__ == '__main__':
    main()
