"""Live equals offline over DDS, on a real recording (issue 20, item 1).

The MPU-6050 multi-position session (``fixtures/real/mpu6050_tomisuarez``, 100 Hz, ten
poses, no temperature) is written as an MCAP log and

* calibrated with ``thermal-imu-calib calibrate LOG --imu-topic /imu --gravity 9.81``
  (the installed console script, default options);
* replayed over DDS into calibrator_node started as ``launch/thermal_imu_calib.launch.py``
  describes it (the shipped ``config/calibrator.yaml``, ``nodes:=calibrator``,
  ``calibration_file:=``, plus ``gravity``; ``bench/launch_nodes.py``), every IMU and
  temperature message counted by the node's ``~/progress``; then ``~/calibrate``.

Both calibrations must have the same holds and windows, the same model (accel kind, auto's
choice, the gyro choice) and every accel/gyro/temperature number equal to 1e-9 relative
(``bench/scoreboard.compare``). Two ways a ROS user runs it:

* no thermal input: ``temperature_topics:='[]'`` (the log has none);
* the shipped thermal input: a room temperature (24 +- 0.15 degC) on ``/imu/temperature``,
  and ``calibrate`` on the same log with that topic.

Waits are on conditions (the node's counts, the service), bounded by a stall time, and fail
at once when the node process exits (``bench/live_replay.py``).
"""

import os
import subprocess
import sys
import warnings

from conftest import DOMAIN_ID, SPARE_DOMAINS, venv_exe
import numpy as np
import pytest
import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'bench'))

import live_replay  # noqa: E402
import real_recordings  # noqa: E402
from scoreboard import compare, REL_TOL  # noqa: E402
from thermal_imu_calib.io.bag_writer import write_columns  # noqa: E402
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns  # noqa: E402
from thermal_imu_calib.io.csv_logs import read_mpu6050_csv  # noqa: E402

FIXTURE = os.path.join(ROOT, 'test', 'fixtures', 'real', 'mpu6050_tomisuarez',
                       'example_data_calibration.csv.gz')
GRAVITY = 9.81


def _recording():
    m = read_mpu6050_csv(FIXTURE)
    return ImuColumns(m.imu.stamp_ns + real_recordings.T0_NS, m.imu.accel, m.imu.gyro,
                      'mpu6050')


def _with_bad_samples(imu, temps):
    """Return copies with what ``calibrate`` drops: a driver's all-zero accelerometer rows
    at the start, samples beyond any sensor's range, duplicated stamps and steps back,
    -300 degC readings."""
    accel, gyro, values = imu.accel.copy(), imu.gyro.copy(), temps.temperature.copy()
    stamps = imu.stamp_ns.copy()
    accel[:3] = 0.0
    rows = np.linspace(len(imu) // 8, len(imu) - len(imu) // 8, 9).astype(int)
    accel[rows[::2], 2] = 1e5                      # m/s^2, inside and between holds
    gyro[rows[1::2], 0] = 500.0                    # rad/s
    stamps[rows + 7] = stamps[rows + 6]            # a duplicated stamp
    stamps[rows[::3] + 13] = stamps[rows[::3] + 11]   # a step back by one sample
    values[[len(values) // 3, 2 * len(values) // 3]] = -300.0
    return (ImuColumns(stamps, accel, gyro, imu.frame_id),
            TemperatureColumns(temps.stamp_ns, values, temps.frame_id))


def _slow(temps):
    """Return the readings every 4 s (a driver publishing at 0.25 Hz), with a 12-s dropout."""
    keep = (temps.stamp_ns - temps.stamp_ns[0]) % (4 * 10 ** 9) == 0
    keep[len(keep) // 2:len(keep) // 2 + 12] = False
    return TemperatureColumns(temps.stamp_ns[keep], temps.temperature[keep], temps.frame_id)


#: where the Xsens ROS 2 driver publishes its temperature (not the shipped imu/temperature)
RENAMED = '/temperature'
#: where in the recording a late temperature driver starts (a fraction of the IMU rows)
LATE_FROM = 0.2
#: a temperature driver stamping by another clock than the IMU's (s ahead)
OTHER_CLOCK_S = 1000


def _write_other_clock(path, imu, temps):
    """Write the log with the readings logged at their stamps, stamped OTHER_CLOCK_S later."""
    from thermal_imu_calib.io import cdr
    from thermal_imu_calib.io.bag_writer import LogWriter
    shifted = TemperatureColumns(temps.stamp_ns + OTHER_CLOCK_S * 10 ** 9, temps.temperature,
                                 temps.frame_id)
    imu_raw, temp_raw = cdr.encode_imu(imu), cdr.encode_temperature(shifted)
    order = sorted([(int(t), 0, i) for i, t in enumerate(imu.stamp_ns)]       # IMU first
                   + [(int(t), 1, i) for i, t in enumerate(temps.stamp_ns)])   # at a tie
    with LogWriter(path, 'mcap') as w:
        w.add_topic('/imu', cdr.IMU_MSGTYPE)
        w.add_topic(real_recordings.TEMP_TOPIC, cdr.TEMPERATURE_MSGTYPE)
        for t, kind, i in order:
            w.write(real_recordings.TEMP_TOPIC if kind else '/imu', t,
                    temp_raw[i] if kind else imu_raw[i])


@pytest.mark.parametrize('thermal', ['none', 'none_shipped_config', 'room_temperature',
                                     'bad_samples',
                                     'slow_temperature', 'float32_temperature',
                                     'float32_followed', 'temperature_on_another_clock',
                                     'renamed_followed', 'late_temperature',
                                     'late_float32_followed', 'late_renamed_followed'])
def test_live_calibration_equals_offline(tmp_path, thermal):
    """``bad_samples``: the room-temperature case with samples ``calibrate`` drops; the
    node drops the same ones (before 2026-11-28 it dropped only non-finite ones).
    ``slow_temperature``: readings every 4 s and a 12-s dropout. ``float32_temperature``:
    the room temperature as std_msgs/Float32 without a header (the um6/um7 drivers), logged
    at its time and published in that order; the node gets ``temperature_types``.
    ``none_shipped_config``: no temperature, and the node with the shipped
    ``temperature_topics`` ([imu/temperature]) instead of ``[]``: nothing is published on
    it, so it collects without a temperature, as calibrate does (``nodes/absent_inputs``).
    ``float32_followed``: the same, the node left at its default type: it subscribes as
    Float32 once it sees the publisher on the graph (``nodes/thermal_types``), and says so.
    ``temperature_on_another_clock``: the room temperature stamped ``OTHER_CLOCK_S`` ahead
    of the IMU's clock, logged and published at its time: both put it on the IMU's clock
    (``io.headerless.StampChoice``). ``renamed_followed``: the room temperature on
    ``/temperature`` (as the Xsens driver publishes it), ``calibrate`` without
    ``--temperature-topic`` (it takes the log's only Temperature topic) and the node with the
    shipped ``[imu/temperature]``: it subscribes ``/temperature``, published with the IMU
    topic, by the same rule (``nodes/topic_follower``), and says so. ``late_temperature``: the
    room temperature's driver starts ``LATE_FROM`` of the way into the recording, after the
    node (shipped config) has decided to collect without a temperature: it takes the
    temperature from its first reading (``nodes/late_inputs``), as ``calibrate`` takes the
    log's (the IMU samples more than 5 s before it not collected), and says so.
    ``late_float32_followed``: the same with the room temperature as std_msgs/Float32 and
    the node left at its default type: it follows the late publisher's type, and puts each
    reading on the IMU's clock as calibrate puts a log's. ``late_renamed_followed``: the
    late room temperature on ``/temperature``: the node, having decided without one, moves
    its watched input there by calibrate's rule and takes it."""
    imu = _recording()
    temps = None
    topics = {}
    kind = live_replay.TEMPERATURE_TYPE
    if thermal in ('float32_temperature', 'float32_followed', 'late_float32_followed'):
        kind = 'std_msgs/msg/Float32'
    if not thermal.startswith('none'):
        temps = real_recordings.flat_temperature(imu)
        if thermal == 'bad_samples':
            imu, temps = _with_bad_samples(imu, temps)
        if thermal == 'slow_temperature':
            temps = _slow(temps)
        if thermal.startswith('late_'):
            late = temps.stamp_ns >= imu.stamp_ns[int(LATE_FROM * len(imu))]
            temps = TemperatureColumns(temps.stamp_ns[late], temps.temperature[late],
                                       temps.frame_id)
        topics = {RENAMED if thermal.endswith('renamed_followed') else real_recordings.TEMP_TOPIC:
                  temps}
    log = str(tmp_path / 'mpu6050.mcap')
    if thermal == 'temperature_on_another_clock':
        _write_other_clock(log, imu, temps)
    else:
        write_columns(log, '/imu', imu, topics,
                      msgtypes={t: kind for t in topics}
                      if kind != live_replay.TEMPERATURE_TYPE else None)

    out = str(tmp_path / 'offline.yaml')
    cmd = [venv_exe('thermal-imu-calib'), 'calibrate', log, '--imu-topic', '/imu',
           '--gravity', str(GRAVITY), '-o', out]
    if temps is not None and not thermal.endswith('renamed_followed'):
        cmd += ['--temperature-topic', real_recordings.TEMP_TOPIC]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    if thermal == 'temperature_on_another_clock':
        assert f'is stamped +{OTHER_CLOCK_S} s from the IMU messages' in r.stderr
    with open(out) as f:
        offline = f.read()

    live = live_replay.run_live(imu, temps, GRAVITY, DOMAIN_ID,
                                temperature_topics='[]' if thermal == 'none' else None,
                                workdir=str(tmp_path / 'live'), temperature_type=kind,
                                temperature_header_ns=None if thermal != 'temperature_on_'
                                'another_clock' else temps.stamp_ns + OTHER_CLOCK_S * 10 ** 9,
                                set_temperature_type=not thermal.endswith('_followed'),
                                published_on=(RENAMED if thermal.endswith('renamed_followed')
                                              else live_replay.TEMPERATURE_TOPIC),
                                late_from=(int(LATE_FROM * len(imu))
                                           if thermal.startswith('late_') else None),
                                spare_domains=SPARE_DOMAINS)
    if live.earlier:        # shown in the run's warnings summary (CI prints it)
        warnings.warn(f'live run retried on domain {live.domain}: {live.earlier}')
    assert not live.error, live.error
    assert live.imu_sent == len(imu) and live.imu_received == live.imu_sent, \
        f'{live.imu_received} of {live.imu_sent} IMU messages arrived'
    if temps is not None:
        assert live.temp_sent == len(temps) and live.temp_received == live.temp_sent, \
            f'{live.temp_received} of {live.temp_sent} temperatures arrived'
    assert live.success, live.message
    if thermal == 'none_shipped_config':     # the node said what it did, and the file
        with open(tmp_path / 'live' / f'attempt{live.attempts}' / 'node.log') as f:
            assert 'no temperature is published: nothing on /imu/temperature and no thermal ' \
                'topic on the graph' in f.read()
        notes = yaml.safe_load(live.calibration_text)['notes']
        assert [n for n in notes if n.startswith('input: no temperature is published')], notes
    if thermal.startswith('late_'):          # the node said what it did, and the file
        said = (RENAMED if thermal.endswith('renamed_followed') else '/imu/temperature') \
            + ': the first reading came'
        with open(tmp_path / 'live' / f'attempt{live.attempts}' / 'node.log') as f:
            assert said in f.read()
        notes = yaml.safe_load(live.calibration_text)['notes']
        assert [n for n in notes if n.startswith('input: ' + said)], notes
    if thermal.endswith('float32_followed'):     # the node said what it did, and the file
        said = ('/imu/temperature is published as std_msgs/msg/Float32 by '
                '/scoreboard_player, not sensor_msgs/msg/Temperature: subscribed as '
                'std_msgs/msg/Float32')
        with open(tmp_path / 'live' / f'attempt{live.attempts}' / 'node.log') as f:
            assert said in f.read()
        notes = yaml.safe_load(live.calibration_text)['notes']
        assert [n for n in notes if n.startswith('input: ' + said)], notes
    if thermal.endswith('renamed_followed'):     # the node said what it did, and the file
        said = ('nothing is published on /imu/temperature; /temperature '
                '(sensor_msgs/msg/Temperature), published with the IMU topic by '
                '/scoreboard_player, is the only sensor_msgs/Temperature topic it publishes: '
                'subscribed to it instead')
        with open(tmp_path / 'live' / f'attempt{live.attempts}' / 'node.log') as f:
            assert said in f.read()
        cal = yaml.safe_load(live.calibration_text)
        assert [n for n in cal['notes'] if n.startswith('input: ' + said)], cal['notes']
        assert cal['temperature']['inputs'] == yaml.safe_load(offline)['temperature']['inputs']
    if thermal == 'temperature_on_another_clock':     # the node said what it did (the
        # distance to the IMU stamps received so far: about OTHER_CLOCK_S)
        with open(tmp_path / 'live' / f'attempt{live.attempts}' / 'node.log') as f:
            assert "s from the IMU messages before it (more than 5 s: not stamped by the " \
                "IMU's clock)" in f.read()
        for text in (offline, live.calibration_text):     # both files say so (the offset
            notes = yaml.safe_load(text)['notes']          # differs: the spans it is from)
            assert len([n for n in notes if n.startswith('input: ')
                        and "not stamped by the IMU's clock" in n]) == 1, notes
    c = compare(offline, live.calibration_text)
    assert c['same_holds'], (f'holds/windows offline {c["offline"]} vs live {c["live"]}')
    assert c['same_model'], (f'model offline {c["offline"]} vs live {c["live"]}')
    assert not c['structure'], c['structure']
    assert c['numbers_compared'] > 0
    assert c['max_rel_diff'] <= REL_TOL, \
        f'parameters differ: {c["max_rel_diff"]:.3e} relative at {c["max_rel_diff_at"]}'
