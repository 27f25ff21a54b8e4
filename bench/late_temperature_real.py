r"""A temperature driver started late, on real recordings: live against ``calibrate``.

For each recording the temperature readings are kept from ``--from`` of the way into the
IMU rows on (a driver started then), written as a log and calibrated offline with
``calibrate`` (default options, the temperature topic given); then the IMU rows before that
point are replayed into the launched calibrator_node (shipped config, ``gravity:=``), which
decides to collect without a temperature; the temperature's publisher is created, matched,
and the rest replayed with its readings (``live_replay.run_live(..., late_from=)``). The node
takes the temperature from its first reading (``nodes/late_inputs``); the two files are
compared as the scoreboard compares them (holds, model, every number to 1e-9 relative).

    ROS_DOMAIN_ID=88 .venv/bin/python bench/late_temperature_real.py --work /tmp/late \
        --json bench/results/late_temperature_real.json

``--type std_msgs/msg/Float32``: the readings as std_msgs/Float32 (no header: logged at their
stamps, published in that order), the node at its default type: it follows the late
publisher's type (``nodes/thermal_types``) and puts each reading on the IMU's clock, as
``calibrate`` does a log's (``io.headerless``). ``--renamed``: the readings on
``/temperature`` (where the Xsens driver publishes it), ``calibrate`` without
``--temperature-topic`` (it takes the log's only Temperature topic), the node with the
shipped ``temperature_topics``: it moves its watched input there by the same rule
(``nodes/topic_follower``).

Times in the table: seconds of the recording; no unit elsewhere (counts, relative).
"""

import argparse
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import live_replay  # noqa: E402
import real_recordings  # noqa: E402
from scoreboard import compare  # noqa: E402
from thermal_imu_calib.io.bag_writer import write_columns  # noqa: E402
from thermal_imu_calib.io.columns import TemperatureColumns  # noqa: E402
from thermal_imu_calib.nodes.common import THERMAL_TYPES  # noqa: E402

#: where the Xsens ROS 2 driver publishes its temperature (not the shipped imu/temperature)
RENAMED = '/temperature'
#: the recordings with a real temperature, and one without (a flat room temperature added)
NAMES = ('bmi270_hot', 'bmi270_cold', 'mpu6050')


def _recording(name, work):
    if name.startswith('bmi270'):
        rec = real_recordings.bmi270(work, name.split('_')[1])
    else:
        rec = real_recordings.mpu6050(work)
    imu, temps = real_recordings.read_log(rec.log, rec.imu_topic, rec.temperature_topic)
    if temps is None:
        temps = real_recordings.flat_temperature(imu)
    return rec, imu, temps


def run(name, work, frac, domain, kind=live_replay.TEMPERATURE_TYPE, renamed=False):
    """Return the row of recording ``name`` with the temperature from ``frac`` on, as ``kind``.

    ``renamed``: on ``RENAMED`` instead of the shipped topic.
    """
    topic = RENAMED if renamed else real_recordings.TEMP_TOPIC
    rec, imu, temps = _recording(name, work)
    i = int(frac * len(imu))
    keep = temps.stamp_ns >= imu.stamp_ns[i]
    late = TemperatureColumns(temps.stamp_ns[keep], temps.temperature[keep], temps.frame_id)
    log = os.path.join(work, f'{name}_late.mcap')
    typed = kind != live_replay.TEMPERATURE_TYPE
    write_columns(log, '/imu', imu, {topic: late}, overwrite=True,
                  msgtypes={topic: kind} if typed else None)
    out = os.path.join(work, f'{name}_late_offline.yaml')
    r = subprocess.run([os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib'),
                        'calibrate', log, '--imu-topic', '/imu', '--gravity', repr(rec.gravity),
                        '-o', out] + ([] if renamed else ['--temperature-topic', topic]),
                       capture_output=True, text=True)
    row = {'recording': name, 'type': kind, 'topic': topic, 'imu_rows': len(imu),
           'late_from_row': i,
           'late_from_s': round((imu.stamp_ns[i] - imu.stamp_ns[0]) * 1e-9, 1),
           'offline_exit': r.returncode}
    if r.returncode:
        row['offline_error'] = r.stderr.strip().splitlines()[-1]
        return row
    with open(out) as f:
        offline = f.read()
    live = live_replay.run_live(imu, late, rec.gravity, domain,
                                workdir=os.path.join(work, f'{name}_live'), late_from=i,
                                temperature_type=kind, set_temperature_type=False,
                                published_on=RENAMED if renamed else live_replay.TEMPERATURE_TOPIC)
    row.update({'imu_sent': live.imu_sent, 'imu_received': live.imu_received,
                'temp_sent': live.temp_sent, 'temp_received': live.temp_received,
                'live_success': live.success, 'live_error': live.error,
                'live_message': live.message})
    if live.success and live.calibration_text:
        c = compare(offline, live.calibration_text)
        row.update({k: c[k] for k in ('equal', 'same_holds', 'same_model', 'max_rel_diff',
                                      'numbers_compared')})
        row['holds'] = c['offline']['holds']
        row['model'] = c['offline']['accel_kind']
    return row


def main(argv=None):
    """Run the recordings; print one line each and write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--work', required=True, help='folder for the logs and the live runs')
    ap.add_argument('--from', dest='frac', type=float, default=0.2,
                    help='where the temperature starts, as a fraction of the IMU rows')
    ap.add_argument('--only', nargs='*', default=None, help='recording names')
    ap.add_argument('--type', default=live_replay.TEMPERATURE_TYPE,
                    choices=sorted(THERMAL_TYPES), help="the readings' message type")
    ap.add_argument('--renamed', action='store_true',
                    help=f'publish the temperature on {RENAMED}, not the shipped topic')
    ap.add_argument('--json', help='write the rows here')
    a = ap.parse_args(argv)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '88'))
    live_replay.check_domain(domain)
    os.makedirs(a.work, exist_ok=True)
    rows = []
    for name in a.only or NAMES:
        row = run(name, a.work, a.frac, domain, a.type, a.renamed)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'from': a.frac, 'type': a.type, 'renamed': a.renamed, 'rows': rows}, f,
                      indent=1)
    return 0 if all(r.get('equal') for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
