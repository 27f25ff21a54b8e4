"""Every real recording of ``../shared/data/real`` as a ROS 2 log, with how it is scored.

One ``Recording`` per scoreboard row: the log the CLI reads (written as MCAP in SI units
from the text files, or the original rosbag2 sqlite bag as it is), its IMU topic and
gravity, the still intervals the score is taken over (sample index ranges into the log's
IMU messages) and the peer's or authors' figure. ``flat_temperature`` writes the same log
with a room temperature (24 degC +- 0.15, slow random walk plus noise, fixed seed) added on
``/imu/temperature`` (sensor_msgs/Temperature).

Units (see each SOURCE.md): xsens counts -> (c - 32768) * 0.0024690608 m/s^2 and
(c - 32768) / 6258 rad/s; getovermassif text files m/s^2 and rad/s with stamps t [s];
imucal/MPU-6050 through ``io.csv_logs``; BMI270 g/4 and deg/s at an assumed 80 Hz
(``make_real_bags.BMI_RATE_HZ``); the chamber log m/s^2, rad/s, degC, stamps in us.
"""

import json
import os
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from imutk_reference import detect_static, load_imutk_calib
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
from thermal_imu_calib.io.csv_logs import (read_bmi270_rows, read_imucal_session,
                                           read_mpu6050_csv, read_static_intervals)

REAL = os.environ.get('THERMAL_REAL_DATA', os.path.join(
    os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
    'shared', 'data', 'real'))
#: header stamp of the first sample of logs made from files without absolute time
T0_NS = 1_700_000_000 * 10 ** 9
IMUTK_G = 9.81744
#: gravity passed for recordings without a stated one (imucal's example uses 9.81)
LAB_G = 9.81
XSENS_ACC_SCALE = 0.0024690608
XSENS_GYRO_SCALE = 1.0 / 6258.0
BMI_RATE_HZ = 80.0
TEMP_TOPIC = '/imu/temperature'
FLAT_T_DEGC, FLAT_T_SPREAD = 24.0, 0.15
FLAT_T_RATE_HZ = 1.0


@dataclass
class Recording:
    """One scoreboard row: a log and how its calibration is scored."""

    name: str
    log: str                         # path of the log the CLI and the replay read
    imu_topic: str
    gravity: float
    kind: str                        # 'multi' (poses), 'single' (one orientation)
    temperature_topic: Optional[str] = None
    #: still intervals scored, (start, end) IMU sample indices, end exclusive
    intervals: List[Tuple[int, int]] = field(default_factory=list)
    interval_source: str = ''
    peer_ug: Optional[float] = None
    peer_label: str = ''
    #: imu_tk .calib (T, K, b) of the authors, scored with the same intervals
    authors_calib: Optional[str] = None
    #: also score over the bench imu_tk-style detector's intervals (when the given ones are
    #: questionable)
    bench_intervals: List[Tuple[int, int]] = field(default_factory=list)
    target: str = ''
    notes: List[str] = field(default_factory=list)


def read_log(path, imu_topic, temperature_topic=None):
    """Return (ImuColumns, TemperatureColumns or None) of a log, as the CLI reads it."""
    imus, temps = [], []
    with open_log(path) as r:
        tt = [temperature_topic] if temperature_topic else []
        for ch in r.stream(imu_topic, tt):
            imus.append(ch.imu)
            if temperature_topic:
                temps.append(ch.temps[temperature_topic])
    imu = ImuColumns.concat(imus)
    if not temperature_topic:
        return imu, None
    tc = [t for t in temps if len(t)]
    return imu, TemperatureColumns(np.concatenate([t.stamp_ns for t in tc]),
                                   np.concatenate([t.temperature for t in tc]))


def _write(path, imu, temps=None):
    if not os.path.exists(path):
        write_columns(path, '/imu', imu, temps or {}, overwrite=True)
    return path


def flat_temperature(imu, seed=0):
    """Return a room temperature for the span of ``imu``: 24 degC, +-0.15 walk and noise."""
    rng = np.random.default_rng(seed)
    t0, t1 = int(imu.stamp_ns[0]), int(imu.stamp_ns[-1])
    stamps = np.arange(t0, t1 + 1, int(1e9 / FLAT_T_RATE_HZ), dtype=np.int64)
    walk = np.cumsum(rng.normal(0.0, 0.01, len(stamps)))
    walk = FLAT_T_SPREAD * np.tanh(walk / FLAT_T_SPREAD)       # stays within +-0.15
    noise = rng.normal(0.0, 0.02, len(stamps))
    return TemperatureColumns(stamps, FLAT_T_DEGC + walk + noise)


def write_flat(rec, out_dir):
    """Write ``rec``'s log with the room temperature added; return its path."""
    path = os.path.join(out_dir, f'{rec.name}_flatT.mcap')
    if not os.path.exists(path):
        imu, _ = read_log(rec.log, rec.imu_topic)
        write_columns(path, rec.imu_topic, imu, {TEMP_TOPIC: flat_temperature(imu)},
                      overwrite=True)
    return path


def _txt(path):
    return np.loadtxt(path)


def _seconds_to_index(t, intervals):
    """Map (start_s, end_s) to (i0, i1) sample ranges of stamps ``t`` (s from the first)."""
    return [(int(np.searchsorted(t, a)), int(np.searchsorted(t, b, side='right')))
            for a, b in intervals]


def xsens(out):
    d = os.path.join(REAL, 'imutk_xsens')
    acc, gyr = _txt(os.path.join(d, 'xsens_acc.mat')), _txt(os.path.join(d, 'xsens_gyro.mat'))
    t = acc[:, 0] - acc[0, 0]
    imu = ImuColumns(T0_NS + np.round(t * 1e9).astype(np.int64),
                     (acc[:, 1:] - 32768.0) * XSENS_ACC_SCALE,
                     (gyr[:, 1:] - 32768.0) * XSENS_GYRO_SCALE, 'xsens')
    with open(os.path.join(d, 'imu_tk_static_intervals.json')) as f:
        ivs = json.load(f)['intervals']
    return Recording('imutk_xsens', _write(os.path.join(out, 'imutk_xsens.mcap'), imu), '/imu',
                     IMUTK_G, 'multi', intervals=_seconds_to_index(t, ivs),
                     interval_source="imu_tk's own 38 intervals (imu_tk_static_intervals.json)",
                     peer_ug=113.8, peer_label='imu_tk 113.8', target='<= 113.8 ug (imu_tk)')


GOM_AUTHORS = {'data1': 1039.0, 'data2': 231.0, 'data3': 235.0, 'data4': 255.0}
GOM_BAGS = {'data1': 'rosbag2_2023_08_11-21_37_35', 'data4': 'rosbag2_2023_08_19-15_38_14'}


def getovermassif(out, session, bag=False):
    d = os.path.join(REAL, 'imutk_getovermassif')
    if bag:
        log = os.path.join(d, 'original_rosbag2', GOM_BAGS[session])
        imu, _ = read_log(log, '/imu')
        name = f'imutk_gom_{session}_rosbag2'
    else:
        acc = _txt(os.path.join(d, session, 'acc_data.txt'))
        gyr = _txt(os.path.join(d, session, 'gyro_data.txt'))
        assert np.array_equal(acc[:, 0], gyr[:, 0]), 'acc and gyro stamps differ'
        imu = ImuColumns(T0_NS + np.round(acc[:, 0] * 1e9).astype(np.int64), acc[:, 1:],
                         gyr[:, 1:], 'gyro_link')
        name = f'imutk_gom_{session}'
        log = _write(os.path.join(out, name + '.mcap'), imu)
    ivs = detect_static(imu.t - imu.t[0], imu.accel)
    return Recording(name, log, '/imu', IMUTK_G, 'multi', intervals=ivs,
                     interval_source='bench imu_tk-style detector (imutk_reference)',
                     peer_ug=GOM_AUTHORS[session], peer_label=f'authors {GOM_AUTHORS[session]:g}',
                     authors_calib=os.path.join(d, session, 'test_imu_acc.calib'),
                     target="<= authors' and <= 1.2x standard fit")


def ferraris(out):
    d = os.path.join(REAL, 'imucal_ferraris')
    s = read_imucal_session(os.path.join(d, 'example_ferraris_session.csv'),
                            os.path.join(d, 'example_ferraris_session_list.json'))
    imu = ImuColumns(s.imu.stamp_ns + T0_NS, s.imu.accel, s.imu.gyro, 'imucal')
    faces = ('x_p', 'x_a', 'y_p', 'y_a', 'z_p', 'z_a')
    return Recording('imucal_ferraris', _write(os.path.join(out, 'imucal_ferraris.mcap'), imu),
                     '/imu', LAB_G, 'multi', intervals=[s.sections[f] for f in faces],
                     interval_source='the six annotated face sections',
                     peer_ug=40.3, peer_label='imucal 40.3 (in-sample)',
                     target='<= 40.3 ug (imucal)')


def mpu6050(out):
    d = os.path.join(REAL, 'mpu6050_tomisuarez')
    m = read_mpu6050_csv(os.path.join(d, 'example_data_calibration.csv'))
    imu = ImuColumns(m.imu.stamp_ns + T0_NS, m.imu.accel, m.imu.gyro, 'mpu6050')
    se = read_static_intervals(os.path.join(d, 'static_intervals.csv'))
    return Recording('mpu6050', _write(os.path.join(out, 'mpu6050.mcap'), imu), '/imu', LAB_G,
                     'multi', intervals=[(int(a), int(b) + 1) for a, b in se],
                     interval_source="the authors' static_intervals.csv (10; two of them are 3 "
                     "and 13 samples long)",
                     bench_intervals=detect_static(imu.t - imu.t[0], imu.accel),
                     peer_label="authors' Tedaldi fit 0.66 mg on the faces (bench_real_data)",
                     target='no worse than before (|a|-g 0.19 mg max, docs)')


def mpu6050_tinit(out):
    d = os.path.join(REAL, 'mpu6050_tomisuarez')
    m = read_mpu6050_csv(os.path.join(d, 'example_data_tinit_calc.csv'))
    imu = ImuColumns(m.imu.stamp_ns + T0_NS, m.imu.accel, m.imu.gyro, 'mpu6050')
    return Recording('mpu6050_tinit', _write(os.path.join(out, 'mpu6050_tinit.mcap'), imu),
                     '/imu', LAB_G, 'single', intervals=[(0, len(imu))],
                     interval_source='the whole 449 s still log',
                     target='exit 0 with an honest one-orientation note')


def bmi270(out, tag):
    name = {'hot': 'BMI_270_hot_test.csv', 'cold': 'BMI_270_cold_test_.csv'}[tag]
    x = read_bmi270_rows(os.path.join(REAL, 'bmi270_hot_cold', name))[0]
    stamp = T0_NS + np.round(np.arange(len(x)) * 1e9 / BMI_RATE_HZ).astype(np.int64)
    imu = ImuColumns(stamp, x[:, 1:4] * 4.0 * 9.80665, np.radians(x[:, 4:7]), 'imu')
    temp = TemperatureColumns(stamp, x[:, 0])
    path = _write(os.path.join(out, f'bmi270_{tag}.mcap'), imu, {TEMP_TOPIC: temp})
    return Recording(f'bmi270_{tag}', path, '/imu', LAB_G, 'single',
                     temperature_topic=TEMP_TOPIC, intervals=[(0, len(imu))],
                     interval_source='the whole soak (drift: 30-s windows)',
                     target='model ends at offset')


def chamber(out):
    p = os.path.join(REAL, 'tofupilot_chamber', 'imu_chamber_train.csv')
    x = np.loadtxt(p, skiprows=1)
    stamp = T0_NS + np.round((x[:, 0] - x[0, 0]) * 1e3).astype(np.int64)
    imu = ImuColumns(stamp, x[:, 4:7], x[:, 1:4], 'imu')
    temp = TemperatureColumns(stamp, x[:, 8])
    path = _write(os.path.join(out, 'tofupilot_chamber_train.mcap'), imu, {TEMP_TOPIC: temp})
    return Recording('tofupilot_chamber_train', path, '/imu', LAB_G, 'single',
                     temperature_topic=TEMP_TOPIC, intervals=[(0, len(imu))],
                     interval_source='training part only (test leg held back)',
                     peer_label='held-out leg: PX4 cubic 0.0211, ArduPilot cubic 0.0173 m/s^2',
                     target='(thermal modelling: another engineer)')


def all_recordings(out):
    """Return every Recording, writing the logs into ``out`` (kept between runs)."""
    os.makedirs(out, exist_ok=True)
    recs = [xsens(out)]
    for s in ('data1', 'data2', 'data3', 'data4'):
        recs.append(getovermassif(out, s))
    for s in ('data1', 'data4'):
        recs.append(getovermassif(out, s, bag=True))
    recs += [ferraris(out), mpu6050(out), mpu6050_tinit(out), bmi270(out, 'hot'),
             bmi270(out, 'cold'), chamber(out)]
    return recs


__all__ = ['Recording', 'all_recordings', 'read_log', 'write_flat', 'flat_temperature',
           'load_imutk_calib']
