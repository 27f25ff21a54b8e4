"""Readers for the public real-data CSV formats used in tests and benchmarks (SI units out).

Each reader returns a :class:`CsvLog`: IMU columns in m/s^2 and rad/s with synthesized
header stamps (sample index / rate, starting at 0 s: these files have no time column), the
sample rate, labelled sections where the source has them, and the conversion constants
used. Paths ending in ``.gz`` are read through gzip.

imucal Ferraris sessions (github.com/mad-lab-fau/imucal, ``example_data/``, MIT):

* ``example_ferraris_session.csv``: ``n_samples, gyr_x..z [deg/s], acc_x..z [m/s^2]``;
  102.4 Hz (see ``IMUCAL_SESSION_RATE``), sections from ``example_ferraris_session_list.json``
  (``{name: {start, end}}`` sample indices, end exclusive as imucal slices them);
* ``annotated_session.csv``: ``part, samples, acc_x..z, gyr_x..z`` in raw counts, already cut
  into sections, 204.8 Hz (imucal's tests). Scales assumed from the sensor (BMI160, +-16 g
  and +-2000 deg/s): 2048 counts/g and 16.4 counts/(deg/s); imucal's own calibration of
  this session (its test snapshot) has K_a ~ 208-215 counts/(m/s^2) = 2040-2106 counts/g
  and K_g ~ 16.2-16.7 counts/(deg/s), consistent with both.

MPU-6050 session (github.com/tomisuarez2/ImuCalibration, ``calibration data/``, MIT):

* 4 preamble lines (``Fs,100`` ...), then ``ax,ay,az,gx,gy,gz`` raw int16 counts; default
  ranges +-2 g (16384 counts/g) and +-250 deg/s (131 counts/(deg/s)), 100 Hz from ``Fs``.
"""

import csv
import gzip
import io
import json
import math
import os
from dataclasses import dataclass, field
from typing import Dict, Tuple

import numpy as np

from ..gravity import STANDARD_GRAVITY
from .columns import ImuColumns

DEG = math.pi / 180.0
#: sample rate of imucal's example_ferraris_session.csv: 10376 samples in ~101 s, and the
#: three rotation sections integrate to ~360 deg only at this rate (imucal's example script
#: passes 204.8 Hz, which halves every integrated angle)
IMUCAL_SESSION_RATE = 102.4
IMUCAL_ANNOTATED_RATE = 204.8
BMI160_ACC_COUNTS_PER_G = 2048.0       # +-16 g
BMI160_GYR_COUNTS_PER_DPS = 16.4       # +-2000 deg/s
MPU6050_ACC_COUNTS_PER_G = 16384.0     # +-2 g
MPU6050_GYR_COUNTS_PER_DPS = 131.0     # +-250 deg/s


class CsvFormatError(ValueError):
    """A CSV that is not in the expected format; the message names the file and the problem."""


@dataclass
class CsvLog:
    """IMU samples from a CSV file, in SI units, with what is known about them."""

    imu: ImuColumns
    rate_hz: float
    #: section name -> (start, end) sample indices into ``imu`` (end exclusive)
    sections: Dict[str, Tuple[int, int]] = field(default_factory=dict)
    #: conversion constants and source facts (counts per unit, preamble values)
    meta: dict = field(default_factory=dict)
    source: str = ''

    def aligned(self, chunk_size=None):
        """Yield the samples as AlignedChunk's without temperature inputs (for the detectors)."""
        from .columns import AlignedChunk
        n = len(self.imu)
        step = n if not chunk_size else int(chunk_size)
        for i in range(0, n, max(step, 1)):
            imu = self.imu.slice(slice(i, i + step))
            yield AlignedChunk(imu, np.zeros((len(imu), 0)), np.zeros((len(imu), 0)))

    def section(self, name):
        """Return the ImuColumns of one labelled section."""
        if name not in self.sections:
            raise KeyError(f'{self.source}: no section {name!r}; sections: '
                           f'{", ".join(self.sections) or "none"}')
        a, b = self.sections[name]
        return self.imu.slice(slice(a, b))


def _open_text(path):
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f'{path} does not exist')
    if path.endswith('.gz'):
        return io.TextIOWrapper(gzip.open(path, 'rb'), encoding='utf-8')
    return open(path, encoding='utf-8')


def _stamps(n, rate_hz, start_index=0):
    idx = np.arange(n, dtype=np.float64) + start_index
    return np.round(idx * (1e9 / rate_hz)).astype(np.int64)


def read_imucal_session(path, sections_path=None, rate_hz=IMUCAL_SESSION_RATE):
    """Read imucal's continuous Ferraris session CSV (gyro deg/s, acc m/s^2)."""
    with _open_text(path) as f:
        rows = list(csv.reader(f))
    head = [h.strip() for h in rows[0]]
    need = ['gyr_x', 'gyr_y', 'gyr_z', 'acc_x', 'acc_y', 'acc_z']
    if any(h not in head for h in need):
        raise CsvFormatError(f'{path}: header {head} lacks {need}')
    data = np.array(rows[1:], dtype=float)
    gyr = data[:, [head.index(h) for h in need[:3]]] * DEG
    acc = data[:, [head.index(h) for h in need[3:]]]
    imu = ImuColumns(_stamps(len(data), rate_hz), acc, gyr, 'imucal')
    sections = {}
    if sections_path is not None:
        with _open_text(sections_path) as f:
            d = json.load(f)
        sections = {k: (int(v['start']), int(v['end'])) for k, v in d.items()}
    return CsvLog(imu, float(rate_hz), sections,
                  {'accel_unit_in': 'm/s^2', 'gyro_unit_in': 'deg/s'}, os.fspath(path))


def read_imucal_annotated(path, rate_hz=IMUCAL_ANNOTATED_RATE,
                          acc_counts_per_g=BMI160_ACC_COUNTS_PER_G,
                          gyr_counts_per_dps=BMI160_GYR_COUNTS_PER_DPS,
                          gravity=STANDARD_GRAVITY):
    """Read imucal's annotated session (raw counts, cut into labelled sections).

    The sections are concatenated in file order; ``sections`` gives their row ranges and
    the stamps keep each row's original sample index (gaps between sections stay gaps).
    """
    with _open_text(path) as f:
        rows = list(csv.reader(f))
    head = [h.strip() for h in rows[0]]
    need = ['part', 'samples', 'acc_x', 'acc_y', 'acc_z', 'gyr_x', 'gyr_y', 'gyr_z']
    if any(h not in head for h in need):
        raise CsvFormatError(f'{path}: header {head} lacks {need}')
    ip = head.index('part')
    part = [r[ip] for r in rows[1:]]
    num = np.array([[float(r[head.index(h)]) for h in need[1:]] for r in rows[1:]])
    sample = num[:, 0].astype(np.int64)
    acc_lsb = gravity / acc_counts_per_g
    gyr_lsb = DEG / gyr_counts_per_dps
    sections = {}
    start = 0
    for i in range(1, len(part) + 1):
        if i == len(part) or part[i] != part[start]:
            if part[start] in sections:
                raise CsvFormatError(f'{path}: section {part[start]!r} appears twice')
            sections[part[start]] = (start, i)
            start = i
    imu = ImuColumns(np.round(sample * (1e9 / rate_hz)).astype(np.int64), num[:, 1:4] * acc_lsb,
                     num[:, 4:7] * gyr_lsb, 'imucal')
    return CsvLog(imu, float(rate_hz), sections,
                  {'accel_m_s2_per_count': acc_lsb, 'gyro_rad_s_per_count': gyr_lsb,
                   'accel_counts_per_g': acc_counts_per_g,
                   'gyro_counts_per_dps': gyr_counts_per_dps}, os.fspath(path))


def read_mpu6050_csv(path, acc_counts_per_g=MPU6050_ACC_COUNTS_PER_G,
                     gyr_counts_per_dps=MPU6050_GYR_COUNTS_PER_DPS, gravity=STANDARD_GRAVITY):
    """Read a tomisuarez2/ImuCalibration MPU-6050 log (preamble + raw int16 counts)."""
    with _open_text(path) as f:
        lines = f.read().splitlines()
    meta = {}
    i = 0
    while i < len(lines) and not lines[i].replace(' ', '').startswith('ax,'):
        key, _, val = lines[i].partition(',')
        meta[key.strip()] = val.strip()
        i += 1
        if i > 20:
            raise CsvFormatError(f'{path}: no "ax,ay,az,gx,gy,gz" header in the first lines')
    if i >= len(lines):
        raise CsvFormatError(f'{path}: no "ax,ay,az,gx,gy,gz" header')
    if 'Fs' not in meta:
        raise CsvFormatError(f'{path}: the preamble has no "Fs" (sample rate) line')
    rate = float(meta['Fs'])
    data = np.loadtxt(io.StringIO('\n'.join(lines[i + 1:])), delimiter=',', ndmin=2)
    if data.shape[1] != 6:
        raise CsvFormatError(f'{path}: expected 6 columns, found {data.shape[1]}')
    acc_lsb = gravity / acc_counts_per_g
    gyr_lsb = DEG / gyr_counts_per_dps
    imu = ImuColumns(_stamps(len(data), rate), data[:, :3] * acc_lsb, data[:, 3:] * gyr_lsb,
                     'mpu6050')
    meta.update({'accel_m_s2_per_count': acc_lsb, 'gyro_rad_s_per_count': gyr_lsb,
                 'accel_counts_per_g': acc_counts_per_g,
                 'gyro_counts_per_dps': gyr_counts_per_dps})
    return CsvLog(imu, rate, {}, meta, os.fspath(path))


def read_static_intervals(path):
    """Read the authors' static intervals file (row 1 starts, row 2 ends): (n, 2) int."""
    with _open_text(path) as f:
        arr = np.loadtxt(f, delimiter=',', ndmin=2)
    if arr.shape[0] != 2:
        raise CsvFormatError(f'{path}: expected two rows (starts, ends), got {arr.shape[0]}')
    return np.stack([arr[0], arr[1]], axis=1).astype(np.int64)


def read_bmi270_rows(path):
    """Return the (n, 7) rows of a BMI270 soak log (Ganesh999-tech, PuTTY capture).

    Columns: die temperature degC, accel x, y, z in g/4, gyro x, y, z deg/s (see the
    fixture's SOURCE.md); lines that are not 7 floats (banner, serial garbage) are skipped.
    Returns (rows, bytes, lines) so a caller can estimate the UART-limited line rate.
    """
    rows, nbytes, nlines = [], 0, 0
    with open(os.fspath(path), errors='replace') as f:   # serial garbage is not UTF-8
        for line in f:
            nbytes += len(line) + 1          # PuTTY lines end in CR LF
            nlines += 1
            vals = line.strip().split(',')
            if len(vals) == 7:
                try:
                    rows.append([float(v) for v in vals])
                except ValueError:
                    pass
    return np.asarray(rows).reshape(-1, 7), nbytes, nlines


def read_tofupilot_chamber(path):
    """Read the tofupilot climatic-chamber log (tab-separated, one orientation, ~2 Hz).

    Header ``timestamp imu.gyro.x..z imu.acc.x..z imu.status imu.temperature``; timestamp
    in microseconds, gyro rad/s, acc m/s^2, temperature degC. Returns (ImuColumns with
    stamps from the timestamp column, TemperatureColumns on the same stamps).
    """
    from .columns import TemperatureColumns
    with _open_text(path) as f:
        head = f.readline().rstrip('\n').split('\t')
        need = ['timestamp', 'imu.gyro.x', 'imu.gyro.y', 'imu.gyro.z', 'imu.acc.x',
                'imu.acc.y', 'imu.acc.z', 'imu.temperature']
        if any(h not in head for h in need):
            raise CsvFormatError(f'{path}: header {head} lacks {need}')
        data = np.loadtxt(f, delimiter='\t', ndmin=2)
    col = {h: data[:, head.index(h)] for h in need}
    stamp = np.round((col['timestamp'] - col['timestamp'][0]) * 1e3).astype(np.int64)
    imu = ImuColumns(stamp, np.column_stack([col[f'imu.acc.{a}'] for a in 'xyz']),
                     np.column_stack([col[f'imu.gyro.{a}'] for a in 'xyz']), 'imu')
    return imu, TemperatureColumns(stamp, col['imu.temperature'], 'imu')
