"""Every real recording, default options, offline (CLI) and live (launched node over DDS).

Usage (from the repository root; one ROS domain of your own for the live runs)::

    ROS_DOMAIN_ID=63 .venv/bin/python bench/scoreboard.py [--work DIR] [--only NAME ...]
        [--no-live] [--node-param NAME=VALUE ...] [--render]

For each recording of ``../shared/data/real`` (``real_recordings``):

* offline: ``thermal-imu-calib calibrate LOG --imu-topic /imu --gravity G -o X.yaml`` (plus
  ``--temperature-topic`` where the log has one), the installed console script;
* live: calibrator_node started as the launch file describes it (shipped
  ``config/calibrator.yaml``, ``calibration_file:=``, ``nodes:=calibrator``, plus
  ``gravity``; the harness's ``progress_period`` 0.1 s), the same log replayed on
  ``imu/data_raw`` (+ ``/imu/temperature``) with every message counted, ``~/calibrate``
  called, the written file read (``live_replay``).
  Logs without temperature are launched with the shipped ``temperature_topics`` too (since
  2026-12-02; nothing is published on them, so the node collects without a temperature,
  ``nodes/absent_inputs``; before, with ``temperature_topics:='[]'``); they are also
  run the way a ROS user meets them (issue 20): the shipped topics and a room temperature
  (24 +- 0.15 degC) on ``/imu/temperature``, compared with ``calibrate`` on that same log;
* live == offline: same holds and windows, same model (accel kind, auto's choice, gyro
  choice), every number of the accel/gyro parameters (values and std) equal to 1e-9
  relative; the largest relative difference and where it is are reported;
* score: static | |mean a| - g | RMS (ug) over the recording's still intervals with the
  calibration applied (``Calibration.stream().apply``), next to the standard fit
  (``imutk_reference``: imu_tk's 9 parameters on one mean per interval, in the bench) and
  the peer's or authors' figure; single-orientation logs: the 30-s drift RMS.

Writes ``bench/results/scoreboard.md`` and ``.json`` (``--out`` to change).

Before any row, a live run checks that no other node is on its ROS domain (a
calibrator_node left by a killed run would share the topics and spoil every live row) and
exits non-zero naming them; the nodes it launches are stopped however it ends, short of
SIGKILL (``live_replay.install_cleanup``).
"""

import argparse
import json
import math
import os
import shlex
import subprocess
import sys
import time

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, ROOT)

import imutk_reference as ref  # noqa: E402
import live_replay  # noqa: E402
import real_recordings as rr  # noqa: E402
from thermal_imu_calib.calibration import Calibration  # noqa: E402
from thermal_imu_calib.io.bag_writer import write_columns  # noqa: E402

BIN = os.path.dirname(sys.executable)
REL_TOL = 1e-9
DRIFT_WINDOW_S = 30.0


# ------------------------------------------------------------------ offline
def offline(log, rec, out_yaml, temperature_topic=None):
    """Run the CLI with default options; return {rc, seconds, summary, yaml text}."""
    cmd = [os.path.join(BIN, 'thermal-imu-calib'), 'calibrate', log, '--imu-topic',
           rec.imu_topic, '--gravity', repr(rec.gravity), '-o', out_yaml]
    if temperature_topic:
        cmd += ['--temperature-topic', temperature_topic]
    if os.path.exists(out_yaml):
        os.unlink(out_yaml)
    t = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True)
    text = open(out_yaml).read() if r.returncode == 0 and os.path.exists(out_yaml) else ''
    lines = (r.stdout + r.stderr).strip().splitlines()
    return {'rc': r.returncode, 'seconds': round(time.monotonic() - t, 2),
            'command': ' '.join(shlex.quote(c) for c in cmd),
            'summary': next((x for x in lines if ': ' in x and 'holds (' in x), ''),
            'last_lines': lines[-3:], 'yaml': text}


# ------------------------------------------------------------------ comparison
def _numbers(node, path=''):
    """Yield (path, float) of every number under ``node``."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, f'{path}.{k}' if path else str(k))
    elif isinstance(node, (list, tuple)):
        for i, v in enumerate(node):
            yield from _numbers(v, f'{path}[{i}]')
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path, float(node)


def summary_of(text):
    """Return holds, windows and model of a calibration YAML."""
    d = yaml.safe_load(text)
    fit = d.get('fit') or {}
    mc = fit.get('model_choice') or {}
    gyro = mc.get('gyro') or {}
    return {'holds': fit.get('holds'), 'windows': fit.get('windows'),
            'accel_kind': (d.get('accel') or {}).get('kind'),
            'gyro_kind': (d.get('gyro') or {}).get('kind'),
            'auto': mc.get('model'), 'gyro_choice': gyro.get('model') if gyro else None,
            'left_out': [h.get('hold') for h in (fit.get('hold_consistency') or {})
                         .get('left_out', [])]}


def compare(text_a, text_b):
    """Compare two calibration files: holds, model, every accel/gyro number (relative).

    Also the drift alarms' yardstick (``fit.alarm_yardstick``, since 2026-12-02), which
    a registry tests instead of the accelerometer model's own terms.
    """
    a, b = yaml.safe_load(text_a), yaml.safe_load(text_b)
    sa, sb = summary_of(text_a), summary_of(text_b)
    worst, where, count, differ = 0.0, '', 0, []
    for sec in ('accel', 'gyro', 'temperature', 'gravity', 'alarm_yardstick'):
        if sec == 'alarm_yardstick':
            da = (a.get('fit') or {}).get(sec) or {}
            db = (b.get('fit') or {}).get(sec) or {}
        else:
            da, db = a.get(sec) or {}, b.get(sec) or {}
        na = dict(_numbers(da, sec))
        nb = dict(_numbers(db, sec))
        if set(na) != set(nb):
            differ.append(f'{sec}: different fields ({sorted(set(na) ^ set(nb))[:4]})')
        for k in set(na) & set(nb):
            x, y = na[k], nb[k]
            count += 1
            den = max(abs(x), abs(y))
            rel = 0.0 if x == y else (abs(x - y) / den if den > 0 else math.inf)
            if rel > worst:
                worst, where = rel, k
    same_model = all(sa[k] == sb[k] for k in ('accel_kind', 'gyro_kind', 'auto', 'gyro_choice'))
    same_holds = sa['holds'] == sb['holds'] and sa['windows'] == sb['windows'] and \
        sa['left_out'] == sb['left_out']
    equal = same_model and same_holds and worst <= REL_TOL and not differ
    return {'equal': equal, 'same_holds': same_holds, 'same_model': same_model,
            'max_rel_diff': worst, 'max_rel_diff_at': where, 'numbers_compared': count,
            'structure': differ, 'offline': sa, 'live': sb}


# ------------------------------------------------------------------ scores
def calibrated_accel(text, imu, temps=None):
    """Apply a calibration file to the whole log (streamed, with the inputs interpolated)."""
    cal = Calibration.from_yaml(text, 'scored calibration')
    k = len(cal.inputs)
    if k:
        if temps is None:
            raise ValueError('calibration needs a temperature the log does not have')
        tv = np.interp(imu.stamp_ns.astype(float), temps.stamp_ns.astype(float),
                       temps.temperature)[:, None].repeat(k, 1)
    else:
        tv = np.zeros((len(imu), 0))
    return cal.stream().apply(imu.t, imu.accel, imu.gyro, tv).accel


def interval_score(accel, intervals, g):
    """(RMS, max) of | |mean a| - g | over the intervals, micro-g."""
    return ref.static_rms_ug(ref.interval_means(accel, intervals), g)


def drift_rms(t, accel, window_s=DRIFT_WINDOW_S):
    """RMS over 30-s windows of |mean_w(a) - mean(a)| (m/s^2), as the chamber SOURCE.md."""
    idx = np.floor((t - t[0]) / window_s).astype(int)
    means = np.array([accel[idx == i].mean(0) for i in np.unique(idx)])
    return float(np.sqrt(np.mean(np.sum((means - means.mean(0)) ** 2, axis=1))))


# ------------------------------------------------------------------ one row
#: extra node parameters for every live run (``--node-param``; none by default)
NODE_PARAMS = {}


def live_run(rec, imu, temps, work, tag, domain_id):
    return live_replay.run_live(imu, temps, rec.gravity, domain_id,
                                workdir=os.path.join(work, f'live_{rec.name}_{tag}'),
                                extra_params=NODE_PARAMS)


def _live_dict(r):
    return {'success': r.success, 'message': r.message[:400], 'error': r.error[:600],
            'imu_sent': r.imu_sent, 'imu_received': r.imu_received,
            'temp_sent': r.temp_sent, 'temp_received': r.temp_received,
            'complete': r.complete, 'attempts': r.attempts,
            'seconds': {k: round(v, 1) for k, v in r.seconds.items()},
            'command': ' '.join(shlex.quote(c) for c in r.command)}


def _live_scored(r, rec, imu, temps, g, offline_yaml, drift=True):
    """Return (the live run's dict with its summary and scores, comparison with offline)."""
    out = _live_dict(r)
    if not r.calibration_text:
        return out, None
    out.update(summary_of(r.calibration_text))
    a = calibrated_accel(r.calibration_text, imu, temps)
    s = interval_score(a, rec.intervals, g)
    out['score_ug'] = {'rms': s[0], 'max': s[1]}
    if drift and rec.kind == 'single':
        out['drift_rms'] = drift_rms(imu.t, a)
    return out, (compare(offline_yaml, r.calibration_text) if offline_yaml else None)


def run_row(rec, work, domain_id, live=True):
    """Return the JSON record of one recording."""
    row = {'recording': rec.name, 'log': rec.log, 'kind': rec.kind, 'gravity': rec.gravity,
           'intervals': len(rec.intervals), 'interval_source': rec.interval_source,
           'peer': rec.peer_label, 'target': rec.target}
    imu, temps = rr.read_log(rec.log, rec.imu_topic, rec.temperature_topic)
    off = offline(rec.log, rec, os.path.join(work, f'{rec.name}.yaml'), rec.temperature_topic)
    row['offline'] = {k: v for k, v in off.items() if k != 'yaml'}
    g = rec.gravity
    raw = interval_score(imu.accel, rec.intervals, g)
    row['raw_ug'] = {'rms': raw[0], 'max': raw[1]}
    if off['yaml']:
        row['offline'].update(summary_of(off['yaml']))
        a = calibrated_accel(off['yaml'], imu, temps)
        s = interval_score(a, rec.intervals, g)
        row['offline']['score_ug'] = {'rms': s[0], 'max': s[1]}
        row['offline']['notes'] = yaml.safe_load(off['yaml']).get('notes', [])[:6]
        if rec.kind == 'single':
            row['offline']['drift_rms'] = drift_rms(imu.t, a)
    if rec.kind == 'single':
        row['raw_drift_rms'] = drift_rms(imu.t, imu.accel)
    if rec.kind == 'multi':
        means = ref.interval_means(imu.accel, rec.intervals)
        p, info = ref.fit_standard(means, g)
        s = ref.static_rms_ug(ref.apply_params(p, means), g)
        row['standard_fit'] = {'rms': s[0], 'max': s[1], 'params': p.tolist(), **info}
    if rec.bench_intervals and off['yaml']:
        a = calibrated_accel(off['yaml'], imu, temps)
        s = interval_score(a, rec.bench_intervals, g)
        means = ref.interval_means(imu.accel, rec.bench_intervals)
        p, _ = ref.fit_standard(means, g)
        st = ref.static_rms_ug(ref.apply_params(p, means), g)
        row['bench_detector'] = {'intervals': len(rec.bench_intervals), 'offline_rms': s[0],
                                 'offline_max': s[1], 'standard_fit_rms': st[0],
                                 'standard_fit_max': st[1]}
    if rec.authors_calib:
        c = ref.load_imutk_calib(rec.authors_calib)
        means = ref.interval_means(imu.accel, rec.intervals)
        s = ref.static_rms_ug(ref.apply_imutk_calib(c, means), g)
        row['authors_calib_ug'] = {'rms': s[0], 'max': s[1], 'file': rec.authors_calib}
    flat_off = None
    if rec.temperature_topic is None:
        flat = rr.write_flat(rec, work)
        flat_off = offline(flat, rec, os.path.join(work, f'{rec.name}_flatT.yaml'),
                           rr.TEMP_TOPIC)
        row['flat_temperature'] = {k: v for k, v in flat_off.items() if k != 'yaml'}
        if flat_off['yaml']:
            fimu, ft = rr.read_log(flat, rec.imu_topic, rr.TEMP_TOPIC)
            a = calibrated_accel(flat_off['yaml'], fimu, ft)
            s = interval_score(a, rec.intervals, g)
            row['flat_temperature'].update(summary_of(flat_off['yaml']))
            row['flat_temperature']['score_ug'] = {'rms': s[0], 'max': s[1]}
    if rec.name == 'tofupilot_chamber_train':
        row['legs'] = chamber_legs(rec, imu, temps, work)
    if not live:
        return row
    # the shipped config and gravity only, with or without a temperature (since
    # 2026-12-02; before, logs without one were launched with temperature_topics:='[]')
    r = live_run(rec, imu, temps, work, 'log', domain_id)
    row['live'], cmp = _live_scored(r, rec, imu, temps, g, off['yaml'])
    if cmp is not None:
        row['live_vs_offline'] = cmp
    if flat_off is not None:
        fimu, ft = rr.read_log(rr.write_flat(rec, work), rec.imu_topic, rr.TEMP_TOPIC)
        r2 = live_run(rec, fimu, ft, work, 'flatT', domain_id)
        row['live_flat'], cmp = _live_scored(r2, rec, fimu, ft, g, flat_off['yaml'], False)
        if cmp is not None:
            row['live_flat_vs_offline'] = cmp
    return row


def chamber_legs(rec, imu, temps, work):
    """Fit the cooling leg, score the heating leg's drift (and the reverse); offline."""
    T = np.interp(imu.stamp_ns.astype(float), temps.stamp_ns.astype(float), temps.temperature)
    cut = int(np.argmin(T))
    out = {'cut_s': float(imu.t[cut] - imu.t[0]), 'min_degC': float(T[cut])}
    legs = {'cooling': slice(0, cut), 'heating': slice(cut, len(imu))}
    yamls = {}
    for name, sl in legs.items():
        part = imu.slice(sl)
        m = (temps.stamp_ns >= part.stamp_ns[0]) & (temps.stamp_ns <= part.stamp_ns[-1])
        tc = type(temps)(temps.stamp_ns[m], temps.temperature[m])
        path = os.path.join(work, f'chamber_{name}.mcap')
        if not os.path.exists(path):
            write_columns(path, rec.imu_topic, part, {rr.TEMP_TOPIC: tc}, overwrite=True)
        o = offline(path, rec, os.path.join(work, f'chamber_{name}.yaml'), rr.TEMP_TOPIC)
        yamls[name] = (o['yaml'], part, tc)
        out[f'{name}_model'] = summary_of(o['yaml'])['accel_kind'] if o['yaml'] else \
            f'exit {o["rc"]}'
        out[f'{name}_raw_drift'] = drift_rms(part.t, part.accel)
    for fit_leg, test_leg in (('cooling', 'heating'), ('heating', 'cooling')):
        text = yamls[fit_leg][0]
        _, part, tc = yamls[test_leg]
        if text:
            try:
                a = calibrated_accel(text, part, tc)
                out[f'fit_{fit_leg}_drift_on_{test_leg}'] = drift_rms(part.t, a)
            except ValueError as e:
                out[f'fit_{fit_leg}_drift_on_{test_leg}'] = str(e)
    return out


# ------------------------------------------------------------------ table
def _f(x, nd=1):
    if x is None:
        return '-'
    if isinstance(x, str):
        return x
    return f'{x:.{nd}f}' if abs(x) < 1e5 else f'{x:.3g}'


def _score(d, key='score_ug'):
    sc = (d or {}).get(key) or {}
    return f'{_f(sc.get("rms"))} ({_f(sc.get("max"))})' if sc else '-'


def _model(d):
    if d and not d.get('accel_kind') and d.get('gyro_kind'):
        return f'gyro only ({d["gyro_kind"]})'
    if not d or not d.get('accel_kind'):
        return None
    return f'{d.get("auto") or "?"} ({d["accel_kind"]}/{d.get("gyro_choice") or d["gyro_kind"]})'


def _eq(cmp, live):
    if live is None:
        return 'not run'
    if live.get('error') and not cmp:
        return 'FAILED: ' + live['error'][:160]
    if not live.get('success'):
        return 'live refused/failed: ' + (live.get('message') or live.get('error'))[:160]
    if not cmp:
        return 'offline failed'
    tag = 'EQUAL' if cmp['equal'] else 'DIFFER'
    parts = [f'{tag}: max rel {cmp["max_rel_diff"]:.2e}'
             + (f' at {cmp["max_rel_diff_at"]}' if cmp['max_rel_diff'] else '')]
    if not cmp['same_holds']:
        parts.append(f'holds {cmp["offline"]["holds"]}/{cmp["live"]["holds"]}, windows '
                     f'{cmp["offline"]["windows"]}/{cmp["live"]["windows"]}')
    if not cmp['same_model']:
        parts.append('model differs')
    parts.append(f'{live["imu_received"]}/{live["imu_sent"]} IMU, '
                 f'{live["temp_received"]}/{live["temp_sent"]} T delivered'
                 + (f' (attempt {live["attempts"]})' if live.get('attempts', 1) > 1 else '')
                 + ('' if live['complete'] else ' (INCOMPLETE: not comparable)'))
    return '; '.join(parts)


def target_met(row):
    off = row.get('offline', {})
    s = (off.get('score_ug') or {}).get('rms')
    name = row['recording']
    eq = all((row.get(c) or {}).get('equal') and (row.get(lv) or {}).get('complete')
             for c, lv in (('live_vs_offline', 'live'), ('live_flat_vs_offline', 'live_flat'))
             if lv in row or c == 'live_vs_offline')
    flat = (row.get('flat_temperature', {}).get('score_ug') or {}).get('rms')
    flat_ok = None if flat is None or s is None else flat <= 1.2 * s
    why = []
    if name == 'imutk_xsens':
        ok = s is not None and s <= 113.8
        why.append(f'score {"<=" if ok else ">"} 113.8')
    elif name.startswith('imutk_gom'):
        peer = float(row['peer'].split()[1])
        std = row['standard_fit']['rms']
        ok = s is not None and s <= peer and s <= 1.2 * std
        why.append(f'score vs authors {_f(s)}/{peer:g}, vs 1.2x std {_f(1.2 * std)}')
    elif name == 'imucal_ferraris':
        ok = s is not None and s <= 40.3
        why.append(f'score {"<=" if ok else ">"} 40.3')
    elif name == 'mpu6050':
        # 'no worse than today': this board is today's record; the docs' 0.19 mg max is the
        # CLI's own in-sample figure on its holds, not comparable with these intervals
        ok = off.get('rc') == 0
        why.append(f'baseline today: {_score(off)} on the authors\' intervals')
    elif name == 'mpu6050_tinit':
        note = ' '.join(off.get('notes') or [])
        ok = off.get('rc') == 0 and 'orientation' in note
        has = 'yes' if 'orientation' in note else 'no'
        why.append(f'exit {off.get("rc")}, one-orientation note {has}')
    elif name.startswith('bmi270'):
        ok = off.get('accel_kind') == 'offset_polynomial' or off.get('auto') == 'offset'
        why.append(f'model {off.get("auto")}')
    else:
        return (f'accuracy n/a (thermal modelling elsewhere); live==offline '
                f'{"yes" if eq else "NO"}')
    if flat_ok is not None:
        why.append(f'flat T {"<=" if flat_ok else ">"} 1.2x')
        ok = ok and flat_ok
    return (f'accuracy {"yes" if ok else "NO"}; live==offline {"yes" if eq else "NO"} ('
            + '; '.join(why) + ')')


def markdown(rows, command, meta):
    h = ['recording', 'holds found (offline/live)', 'model offline / live', 'score offline',
         'score live', 'live==offline (max rel diff)', 'standard fit', 'peer/authors figure',
         'flat-temperature score', 'target met?']
    extra = meta.get('node_params')
    out = [f'# Real-recording scoreboard ({meta["date"]}, commit {meta["commit"]})', '',
           *([f'**Experiment: live nodes with extra parameters {extra}** (not the shipped '
              'config).', ''] if extra else []),
           'Reproduce:', '', '```', command, '```', '',
           'Scores: static | |mean a| - g | RMS in ug (max in brackets) over each recording\'s '
           'still intervals (see `interval_source` in the .json), calibration applied to every '
           'sample; single-orientation logs: 30-s drift RMS (m/s^2) raw -> calibrated. '
           'Standard fit: imu_tk\'s 9-parameter model fitted in the bench '
           '(`bench/imutk_reference.py`) to one mean per interval, in-sample. Live: '
           'calibrator_node started as the launch file describes it (shipped config + '
           '`gravity`; the harness reads progress every 0.1 s), the log replayed over DDS, '
           '`~/calibrate`. Logs without temperature: '
           'live with the shipped config too (nothing on `/imu/temperature`: the node '
           'collects without a temperature); the second line (flat T) is the issue-20 user '
           'path: shipped topics, room temperature on `/imu/temperature`, compared with '
           '`calibrate` on that same log.', '',
           '| ' + ' | '.join(h) + ' |', '|' + '---|' * len(h)]
    for r in rows:
        off, live = r.get('offline', {}), r.get('live')
        lf = r.get('live_flat')
        ff = r.get('flat_temperature')
        holds = f'{off.get("holds", "-")}/{(live or {}).get("holds", "-")}'
        if lf:
            holds += f' (flat T: {ff.get("holds", "-")}/{lf.get("holds", "-")})'
        model = f'{_model(off) or "exit " + str(off.get("rc"))} / {_model(live) or "-"}'
        if lf:
            model += f' (flat T: {_model(ff) or "-"} / {_model(lf) or "-"})'
        if r['kind'] == 'single':
            # one orientation: |a| - g is not calibrated (only an offset vs temperature)
            ag = _f((off.get('score_ug') or {}).get('rms'), 0)
            so = (f'drift {r["raw_drift_rms"]:.4f} -> {_f(off.get("drift_rms"), 4)} m/s^2 '
                  f'(\\|a\\|-g {ag} ug, one orientation)')
        else:
            so = _score(off)
        key = 'drift_rms' if r['kind'] == 'single' else None
        sl = ((_f((live or {}).get('drift_rms'), 4) if key else
               _f((live or {}).get('score_ug', {}).get('rms'))) if live else 'not run')
        if lf:
            sl += f' (flat T: {_f(lf.get("score_ug", {}).get("rms"))})'
        eq = _eq(r.get('live_vs_offline'), live)
        if lf:
            eq += ' <br> flat T: ' + _eq(r.get('live_flat_vs_offline'), lf)
        std = r.get('standard_fit')
        stds = f'{_f(std["rms"])} ({_f(std["max"])})' if std else '-'
        if std and std.get('underdetermined'):
            stds += f' ({std["n_intervals"]} intervals < 9 parameters: exact by construction)'
        bd = r.get('bench_detector')
        if bd:
            so += (f'; over the bench detector\'s {bd["intervals"]} intervals: '
                   f'{_f(bd["offline_rms"])} ({_f(bd["offline_max"])})')
            stds += (f'; bench detector: {_f(bd["standard_fit_rms"])} '
                     f'({_f(bd["standard_fit_max"])})')
        peer = r.get('peer') or '-'
        if r.get('authors_calib_ug'):
            peer += ('; authors\' .calib with the bench detector: '
                     f'{_f(r["authors_calib_ug"]["rms"])}')
        if r.get('legs'):
            lg = r['legs']
            c2h = _f(lg.get('fit_cooling_drift_on_heating'), 4)
            h2c = _f(lg.get('fit_heating_drift_on_cooling'), 4)
            peer += (f'; legs (drift m/s^2, raw -> fitted on the other leg): cooling '
                     f'{lg["cooling_raw_drift"]:.4f} -> {h2c}, heating '
                     f'{lg["heating_raw_drift"]:.4f} -> {c2h} (models {lg["cooling_model"]}/'
                     f'{lg["heating_model"]})')
        fl = '-'
        if ff:
            fs = (ff.get('score_ug') or {}).get('rms')
            base = (off.get('score_ug') or {}).get('rms')
            fl = f'{_f(fs)}' + (f' ({fs / base:.2f}x)' if fs and base else '') + \
                (f', exit {ff["rc"]}' if ff.get('rc') else '')
        out.append('| ' + ' | '.join([r['recording'], holds, model, so, sl, eq, stds, peer, fl,
                                      target_met(r)]) + ' |')
    out += ['', f'Raw (uncalibrated) scores, offline summaries, notes and live timings: '
            f'`{meta["json"]}`.', '']
    return '\n'.join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--work', default=os.path.join('/tmp', f'thermal-scoreboard-{os.getuid()}'))
    ap.add_argument('--only', nargs='*', help='recording names (default: all)')
    ap.add_argument('--no-live', action='store_true')
    ap.add_argument('--out', default=os.path.join(HERE, 'results', 'scoreboard'))
    ap.add_argument('--node-param', action='append', default=[], metavar='NAME=VALUE',
                    help='experiment: add a parameter (YAML value) to every live node, e.g. '
                         'min_hold_s=0.0 (default: none, the shipped config)')
    ap.add_argument('--render', action='store_true',
                    help='only rewrite OUT.md from OUT.json (no runs)')
    a = ap.parse_args(argv)
    if a.render:
        with open(a.out + '.json') as f:
            d = json.load(f)
        with open(a.out + '.md', 'w') as f:
            f.write(markdown(d['rows'], d['command'], d))
        return
    for item in a.node_param:
        k, _, v = item.partition('=')
        NODE_PARAMS[k] = yaml.safe_load(v)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '63'))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if not a.no_live:
        # every launched node is stopped when this process ends (exit, SIGTERM/HUP/INT);
        # one left by a SIGKILLed run would share the domain: refuse before any row
        live_replay.install_cleanup()
        print(f'checking ROS domain {domain} for other nodes (up to '
              f'{live_replay.GUARD_S:.0f} s) ...', flush=True)
        try:
            live_replay.check_domain(domain)
        except live_replay.DomainBusy as e:
            sys.exit(f'scoreboard: {e}')
    recs = rr.all_recordings(os.path.join(a.work, 'logs'))
    if a.only:
        recs = [r for r in recs if r.name in a.only]
    rows = []
    for rec in recs:
        t = time.monotonic()
        print(f'{rec.name} ...', flush=True)
        row = run_row(rec, a.work, domain, live=not a.no_live)
        row['seconds'] = round(time.monotonic() - t, 1)
        rows.append(row)
        print(f'  {row["seconds"]} s; offline {row["offline"].get("score_ug")}; '
              f'live==offline {(row.get("live_vs_offline") or {}).get("max_rel_diff")}',
              flush=True)
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(['git', 'status', '--porcelain', '--', 'thermal_imu_calib', 'config',
                            'launch'], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    meta = {'date': time.strftime('%Y-%m-%d'), 'commit': commit + (' +dirty' if dirty else ''),
            'node_params': NODE_PARAMS,
            'json': os.path.relpath(a.out + '.json', ROOT)}
    command = (f'ROS_DOMAIN_ID={domain} .venv/bin/python bench/scoreboard.py'
               + (f' --work {a.work}' if a.work != ap.get_default('work') else '')
               + (' --only ' + ' '.join(a.only) if a.only else '')
               + (' --no-live' if a.no_live else '')
               + ''.join(f' --node-param {p}' for p in a.node_param)
               + (f' --out {os.path.relpath(a.out, ROOT)}' if a.out != ap.get_default('out')
                  else ''))
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out + '.json', 'w') as f:
        json.dump({'command': command, **meta, 'rows': rows}, f, indent=1, default=str)
    with open(a.out + '.md', 'w') as f:
        f.write(markdown(rows, command, meta))
    print(f'wrote {a.out}.md and .json')


if __name__ == '__main__':
    main()
