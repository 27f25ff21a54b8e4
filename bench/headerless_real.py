"""The real recordings with a temperature, their temperature without a usable header stamp.

Usage (from the repository root; a ROS domain of your own for the live runs)::

    ROS_DOMAIN_ID=72 .venv/bin/python bench/headerless_real.py [--work DIR] [--json OUT]
        [--no-live] [--kinds float64 float64_followed stamp0 renamed]

For the BMI270 soaks and the chamber log's training part (``real_recordings``), the log is
written again with each temperature reading logged half an IMU period after its sample (a
driver publishing the temperature after the IMU message it read it with), in one of two
forms (``KINDS``):

* ``float64``: as std_msgs/Float64, no header (the nodes get ``temperature_types``);
* ``float64_followed``: the same log, the node left at its default type (sensor_msgs/
  Temperature): it must subscribe as Float64 once it sees the player's publisher on the
  graph (``nodes/thermal_types``);
* ``stamp0``: as sensor_msgs/Temperature with header stamp 0 (a driver that never sets it;
  ``io.headerless.StampChoice`` puts it on the IMU's clock);
* ``renamed``: as sensor_msgs/Temperature with its stamps, on ``/temperature`` (where the
  Xsens driver publishes it) instead of the node's ``imu/temperature``: ``calibrate`` runs
  without ``--temperature-topic`` (it takes the log's only Temperature topic) and the node
  with the shipped config follows it (``nodes/topic_follower``).

Then, default options as in ``scoreboard.py``:

* offline: ``calibrate`` on that log must equal ``calibrate`` on the original log
  (sensor_msgs/Temperature stamped with the IMU sample's stamp): each reading takes the
  stamp of the IMU message logged before it, which is that sample's;
* live: that log replayed into calibrator_node, every message counted, must equal the
  offline calibration (``scoreboard.compare``, 1e-9 relative).
"""

import argparse
import json
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import live_replay  # noqa: E402
import real_recordings as rr  # noqa: E402
from scoreboard import compare, offline, REL_TOL  # noqa: E402
from thermal_imu_calib.io.bag_writer import write_columns  # noqa: E402
from thermal_imu_calib.io.columns import TemperatureColumns  # noqa: E402

FLOAT = 'std_msgs/msg/Float64'
#: the forms of the temperature: no header, a header stamp of 0, or another topic name
KINDS = ('float64', 'float64_followed', 'stamp0', 'renamed')
#: the topic of ``renamed`` (the Xsens ROS 2 driver's)
RENAMED = '/temperature'


def _verdict(c):
    return {k: c[k] for k in ('same_holds', 'same_model', 'numbers_compared', 'max_rel_diff',
                              'max_rel_diff_at', 'structure')}


def _write_stamp0(path, rec, imu, temps, log_ns):
    """Write the log with Temperature readings stamped 0, logged at ``log_ns``."""
    from thermal_imu_calib.io import cdr
    from thermal_imu_calib.io.bag_writer import LogWriter
    imu_raw = cdr.encode_imu(imu)
    temp_raw = cdr.encode_temperature(TemperatureColumns(np.zeros(len(temps), np.int64),
                                                         temps.temperature, temps.frame_id))
    order = sorted([(int(t), 0, i) for i, t in enumerate(imu.stamp_ns)]
                   + [(int(t), 1, i) for i, t in enumerate(log_ns)])
    with LogWriter(path, 'mcap', overwrite=True) as w:
        w.add_topic(rec.imu_topic, cdr.IMU_MSGTYPE)
        w.add_topic(rec.temperature_topic, cdr.TEMPERATURE_MSGTYPE)
        for t, kind, i in order:
            w.write(rec.temperature_topic if kind else rec.imu_topic, t,
                    temp_raw[i] if kind else imu_raw[i])


def run(rec, work, domain_id, live=True, kind='float64'):
    """Return the row of one recording: offline original vs ``kind``, live vs offline."""
    imu, temps = rr.read_log(rec.log, rec.imu_topic, rec.temperature_topic)
    half = int(round(0.5 * 1e9 / rec_rate(imu)))
    bare = os.path.join(work, f'{rec.name}_{kind}.mcap')
    # log time = stamp + half a period: after the IMU message of the same stamp
    if kind.startswith('float64'):
        write_columns(bare, rec.imu_topic, imu, {rec.temperature_topic: TemperatureColumns(
            temps.stamp_ns + half, temps.temperature)}, msgtypes={rec.temperature_topic: FLOAT},
            overwrite=True)
    elif kind == 'renamed':
        write_columns(bare, rec.imu_topic, imu, {RENAMED: TemperatureColumns(
            temps.stamp_ns, temps.temperature)}, overwrite=True)
    else:
        _write_stamp0(bare, rec, imu, temps, temps.stamp_ns + half)
    a = offline(rec.log, rec, os.path.join(work, f'{rec.name}_stamped.yaml'),
                rec.temperature_topic)
    b = offline(bare, rec, os.path.join(work, f'{rec.name}_{kind}.yaml'),
                None if kind == 'renamed' else rec.temperature_topic)
    row = {'name': rec.name, 'kind': kind, 'imu_messages': len(imu), 'readings': len(temps),
           'offline_rc': [a['rc'], b['rc']], 'offline_summary': b['summary'],
           'vs_stamped': _verdict(compare(a['yaml'], b['yaml'])) if a['rc'] == 0
           == b['rc'] else None, 'seconds_offline': [a['seconds'], b['seconds']]}
    if live:
        shifted = TemperatureColumns(temps.stamp_ns + (0 if kind == 'renamed' else half),
                                     temps.temperature)
        r = live_replay.run_live(imu, shifted, rec.gravity, domain_id,
                                 workdir=os.path.join(work, f'{rec.name}_{kind}_live'),
                                 temperature_type=FLOAT if kind.startswith('float64')
                                 else live_replay.TEMPERATURE_TYPE,
                                 temperature_header_ns=None if kind.startswith('float64')
                                 else None if kind == 'renamed'
                                 else np.zeros(len(temps), np.int64),
                                 set_temperature_type=kind != 'float64_followed',
                                 published_on=RENAMED if kind == 'renamed'
                                 else live_replay.TEMPERATURE_TOPIC)
        row['live'] = {'error': r.error, 'success': r.success, 'message': r.message[:300],
                       'imu': [r.imu_received, r.imu_sent], 'readings': [r.temp_received,
                                                                         r.temp_sent],
                       'attempts': r.attempts, 'seconds': r.seconds}
        row['live_vs_offline'] = (_verdict(compare(b['yaml'], r.calibration_text))
                                  if r.success else None)
    return row


def rec_rate(imu):
    """Median IMU rate (Hz) from the header stamps."""
    return 1e9 / float(np.median(np.diff(imu.stamp_ns)))


def equal(v):
    """True when a comparison found the same holds, model and numbers (1e-9 relative)."""
    return bool(v and v['same_holds'] and v['same_model'] and not v['structure']
                and v['numbers_compared'] > 0 and v['max_rel_diff'] <= REL_TOL)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--work', default=None)
    ap.add_argument('--json', default=None)
    ap.add_argument('--no-live', action='store_true')
    ap.add_argument('--kinds', nargs='+', choices=KINDS, default=list(KINDS))
    a = ap.parse_args(argv)
    work = a.work or tempfile.mkdtemp(prefix='headerless-')
    os.makedirs(work, exist_ok=True)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '0'))
    if not a.no_live:
        live_replay.install_cleanup()
        try:
            live_replay.check_domain(domain)
        except live_replay.DomainBusy as e:
            sys.exit(f'headerless_real: {e}')
    recs = [rr.bmi270(work, 'hot'), rr.bmi270(work, 'cold'), rr.chamber(work)]
    rows = []
    for rec, kind in [(r, k) for k in a.kinds for r in recs]:
        row = run(rec, work, domain, live=not a.no_live, kind=kind)
        rows.append(row)
        ok_off = equal(row['vs_stamped'])
        ok_live = equal(row.get('live_vs_offline')) and row['live']['imu'][0] == row[
            'live']['imu'][1] and row['live']['readings'][0] == row['live']['readings'][1] \
            if 'live' in row else None
        print(f"{rec.name}: {row['imu_messages']} IMU, {row['readings']} {kind} readings; "
              f"offline {kind} == stamped: {ok_off} "
              f"(max rel {(row['vs_stamped'] or {}).get('max_rel_diff')}); "
              f"live == offline: {ok_live}"
              + (f" (max rel {row['live_vs_offline']['max_rel_diff']}, IMU "
                 f"{row['live']['imu'][0]}/{row['live']['imu'][1]}, readings "
                 f"{row['live']['readings'][0]}/{row['live']['readings'][1]})"
                 if row.get('live_vs_offline') else ''), flush=True)
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'rows': rows}, f, indent=1, default=str)
    return 0 if all(equal(r['vs_stamped']) and (a.no_live or equal(
        r.get('live_vs_offline'))) for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
