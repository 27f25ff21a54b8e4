"""The drift alarms' terms on one real sensor's sessions: is a change between them in sigma?

Usage (from the repository root)::

    .venv/bin/python bench/yardstick_sessions.py [--work DIR] [--json OUT]

The four getovermassif sessions (``real_recordings.getovermassif``) are one IMU recorded
with one ROS 2 driver on different days (2023-08-11 and 08-19 for data1 and data4; no
temperature). Each is calibrated with default options as ``scoreboard.py`` does, and the
terms a registry's drift alarms test (``fleet/alarms``: accelerometer bias and scale at
T0 per axis, with their stds) are compared between consecutive sessions as z = change /
sqrt(std_a^2 + std_b^2), three times: at S pooled over the sessions as ``history`` tests
them (``fleet/pooled_s.py``, since 2026-12-03; the variance given S plus S's part), on the
alarm yardstick's own stds (``fit.alarm_yardstick``, the field model fitted to the same
holds, what the alarms read 2026-12-02/03) and on the calibration's own model
(``models.alarm_terms.bias_scale_terms``: the standard fit's, what they read before). A
session whose yardstick could not be fitted is left out, with the reason.

Nobody knows whether the sensor changed between the sessions (no temperature, days apart),
so this does not measure the stds' honesty; it shows what the alarms would say of a real
sensor, and how the two sets of stds compare on the same changes.
"""

import argparse
import json
import os
import sys
import tempfile

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import real_recordings as rr  # noqa: E402
from scoreboard import offline  # noqa: E402
from thermal_imu_calib.calibration import Calibration  # noqa: E402
from thermal_imu_calib.models.alarm_terms import bias_scale_terms  # noqa: E402

SESSIONS = ('data1', 'data2', 'data3', 'data4')


def pooled_z(texts):
    """Return [(b z (3,), k z (3,))] of consecutive changes at the sessions' pooled S.

    The calibrations as one unit's registry rows, a day apart, tested as ``history`` tests
    them (``fleet/pooled_s.py``: terms given S, S pooled over the sessions).
    """
    from thermal_imu_calib.fleet import registry as reg
    from thermal_imu_calib.fleet.alarms import accel_family
    from thermal_imu_calib.fleet.pooled_s import unit_pools
    rows = [{k: str(v) for k, v in reg.index_row(
        'gom', Calibration.from_yaml(t, 'session calibration'),
        (1_700_000_000 + 86400 * i) * 10 ** 9, (1_700_000_000 + 86400 * i - 3600) * 10 ** 9,
        f'{i}.yaml', [str(i)]).items()} for i, t in enumerate(texts)]
    pooled = unit_pools(rows, accel_family).get(accel_family(rows[-1]))
    out = []
    for a, b in zip(rows, rows[1:]):
        z = reg.compare(a, b, pooled=pooled)
        out.append((z['db0'], z['dk0']))
    return out, pooled


def terms(text):
    """Return ({'b','b_std','k','k_std'} of the yardstick, of the own model, or an error)."""
    d = yaml.safe_load(text)
    y = d['fit'].get('alarm_yardstick') or {}
    cal = Calibration.from_yaml(text, 'session calibration')
    own = bias_scale_terms(cal.accel)
    first = {k: np.asarray(own[k], float)[:, 0] for k in ('b', 'b_std', 'k', 'k_std')}
    if 'error' in y or not y:
        return None, first, y.get('error', 'no yardstick (the field model itself)')
    yard = {k: np.asarray(y[k], float)[:, 0] for k in ('b', 'b_std', 'k', 'k_std')}
    return yard, first, ''


def z_of(a, b):
    """Return (z of the bias change per axis, z of the scale change per axis)."""
    return ((b['b'] - a['b']) / np.hypot(a['b_std'], b['b_std']),
            (b['k'] - a['k']) / np.hypot(a['k_std'], b['k_std']))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--work', default=None)
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='yardstick-sessions-')
    os.makedirs(work, exist_ok=True)
    got = {}
    for s in SESSIONS:
        rec = rr.getovermassif(os.path.join(work, 'logs'), s)
        out = offline(rec.log, rec, os.path.join(work, f'{s}.yaml'))
        if out['rc'] != 0:
            print(f'{s}: calibrate failed: {out["last_lines"]}')
            continue
        yard, own, why = terms(out['yaml'])
        model = yaml.safe_load(out['yaml'])['fit']['model_choice']['model']
        got[s] = {'yardstick': yard, 'own': own, 'model': model, 'why': why,
                  'text': out['yaml']}
        print(f'{s}: auto {model}' + (f'; no yardstick: {why[:120]}' if why else ''))
    rows = []
    names = [s for s in SESSIONS if s in got and got[s]['yardstick'] is not None]
    at_pooled, pooled = pooled_z([got[s]['text'] for s in names])
    if pooled is not None:
        print(f'pooled S over {len(names)} sessions: {np.round(pooled[0], 5).tolist()} +- '
              f'{np.round(np.sqrt(np.diag(pooled[1])), 5).tolist()}')
    for (x, y), (pb, pk) in zip(zip(names, names[1:]), at_pooled):
        row = {'from': x, 'to': y}
        row['pooled_s'] = {'b_z': np.round(pb, 2).tolist(), 'k_z': np.round(pk, 2).tolist()}
        for which in ('yardstick', 'own'):
            zb, zk = z_of(got[x][which], got[y][which])
            row[which] = {'b_z': np.round(zb, 2).tolist(), 'k_z': np.round(zk, 2).tolist()}
        row['db_mm_s2'] = np.round((got[y]['yardstick']['b'] - got[x]['yardstick']['b'])
                                   * 1e3, 2).tolist()
        row['dk_ppm'] = np.round((got[y]['yardstick']['k'] - got[x]['yardstick']['k'])
                                 * 1e6).tolist()
        rows.append(row)
        print(f"{x} -> {y}: yardstick b z {row['yardstick']['b_z']}, k z "
              f"{row['yardstick']['k_z']}; own model b z {row['own']['b_z']}, k z "
              f"{row['own']['k_z']}; at the pooled S b z {row['pooled_s']['b_z']}, k z "
              f"{row['pooled_s']['k_z']}; change b {row['db_mm_s2']} mm/s^2, k "
              f"{row['dk_ppm']} ppm")
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'sessions': {s: {'model': v['model'], 'no_yardstick': v['why']}
                                    for s, v in got.items()}, 'changes': rows,
                       'pooled_s': None if pooled is None else {
                           'value': pooled[0].tolist(),
                           'std': np.sqrt(np.diag(pooled[1])).tolist()}}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
