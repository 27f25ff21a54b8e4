"""A simulated robot month: everyday stops, weather, ageing, a knock, restarts, pushes.

``RobotMonth(seed)`` draws a consumer MEMS IMU (``devices.draw_device('mems', seed)``) on
a mobile robot for ``days`` days:

* temperature (degC): seasonal mean ``season`` (start -> end of the month, linear) plus a
  diurnal swing (amplitude ``diurnal_amp``, warmest at 15:00) and weather (three random
  sinusoids of 2-6 day periods, ``weather_amp``), clipped to 0..40 degC; the IMU sits
  ``heat_moving`` above that while the robot drives and relaxes to ``heat_idle`` during a
  stop (time constant ``heat_tau_s``);
* stops: ``stops_per_day`` at uniformly random times, each 10 s .. 10 min (log-uniform
  ``stop_s``), level (tilt 0..``level_tilt_deg``, random heading) or, with probability
  ``slope_fraction``, on a slope of ``slope_deg``; with probability ``dock_fraction``
  (default 0) a stop is level at one heading, ``dock_heading_deg`` (a robot that returns
  to its dock: drawn from a stream of its own, so 0 leaves the month as it was);
* bias ageing: accel bias drifts ``age_accel`` m/s^2/day and the gyro bias ``age_gyro``
  rad/s/day (random direction); a knock at a random day in ``knock_day`` steps them by
  ``knock_accel`` / ``knock_gyro`` (random direction);
* motion hints: the robot is commanded still during each stop; with probability
  ``push_fraction`` someone pushes it for 2-6 s inside a commanded stop (the detector
  must split the hold), with probability ``blocked_fraction`` a stop happens while the
  command says drive (blocked: the hints must refuse it);
* restarts: ``restarts`` random times at which the node restarts.

Only the stops are sampled densely (``imu_rate``, default 10 Hz, plus ``pad_s`` of driving
on both sides, so the detector sees each stop begin and end); the driving between stops is
not sampled (the stream has gaps). A month is ~2 M IMU samples, generated stop by stop
(``segments``) in bounded memory. ``true_calibration(t)`` is the exact calibration at time
``t`` (with ageing and the knock), the reference of the benchmark.
"""

from dataclasses import dataclass, field, replace
from typing import List, Optional, Tuple

import numpy as np

from ..calibration import Calibration, TemperatureInput
from ..gravity import normal_gravity
from ..io.columns import ImuColumns, TemperatureColumns
from ..models.field import FieldPolynomialModel
from ..models.polynomial import OffsetPolynomialModel
from ..models.whole_unit import WholeUnitGyroModel
from .devices import _rng, accel_forward, DEG, draw_device, EARTH_RATE, gyro_forward
from .schedule import first_order_lag

DAY = 86400.0
#: 2025-03-01T00:00:00Z: the month starts at midnight UTC (local time = UTC here)
MONTH_EPOCH_NS = 1_740_787_200 * 10 ** 9


@dataclass(frozen=True)
class RobotMonthConfig:
    """Everything that defines a robot month except the seed (SI units, degC, days)."""

    name: str = 'robot-month'
    description: str = ('a mobile robot for 30 days: 30-60 stops a day of 10 s-10 min at '
                        'random times (mostly level, some on slopes), diurnal and seasonal '
                        'temperature 0-40 degC, bias ageing plus a knock, restarts, pushes '
                        'during commanded stops; cmd_vel motion hints')
    days: float = 30.0
    imu_rate: float = 10.0
    temp_rate: float = 1.0
    temp_lsb: float = 1.0 / 512.0
    temp_noise: float = 0.02
    stops_per_day: Tuple[int, int] = (30, 60)
    stop_s: Tuple[float, float] = (10.0, 600.0)
    pad_s: float = 4.0
    level_tilt_deg: float = 0.3
    slope_fraction: float = 0.1
    slope_deg: Tuple[float, float] = (3.0, 12.0)
    dock_fraction: float = 0.0
    dock_heading_deg: float = 30.0
    season: Tuple[float, float] = (8.0, 24.0)
    diurnal_amp: Tuple[float, float] = (5.0, 9.0)
    weather_amp: float = 3.0
    heat_moving: float = 6.0
    heat_idle: float = 1.5
    heat_tau_s: float = 900.0
    age_accel: float = 3e-4
    age_gyro: float = 1.5e-5
    knock_day: Tuple[float, float] = (12.0, 22.0)
    knock_accel: Tuple[float, float] = (0.03, 0.08)
    knock_gyro: Tuple[float, float] = (2e-3, 5e-3)
    push_fraction: float = 0.05
    blocked_fraction: float = 0.03
    restarts: int = 4
    latitude: float = 45.0
    temp_topic: str = '/imu/temperature'
    imu_topic: str = '/imu/data_raw'
    frame_id: str = 'imu_link'


@dataclass
class Stop:
    """One commanded stop (or, ``blocked``, a stop while the command says drive)."""

    index: int
    t0: float                  # s since the start of the month, still from here
    t1: float
    c_nb: np.ndarray           # (3, 3) attitude, sensor to ENU
    slope_deg: float
    push: Optional[Tuple[float, float]] = None    # s: pushed (moving) inside the stop
    blocked: bool = False


@dataclass
class Segment:
    """The samples around one stop: IMU, temperature readings, hints and the truth."""

    stop: Stop
    imu: ImuColumns
    temperature: TemperatureColumns
    #: [(stamp s since the epoch, still)] of the velocity command (cmd_vel), in order
    hints: List[Tuple[float, bool]]
    specific_force: np.ndarray     # (n, 3) m/s^2 true
    angular_rate: np.ndarray       # (n, 3) rad/s true
    temp_true: np.ndarray          # (n,) degC true sensor temperature
    still: np.ndarray              # (n,) bool truly still


@dataclass
class RobotMonth:
    """A drawn robot month (see the module docstring)."""

    seed: int
    config: RobotMonthConfig = field(default_factory=RobotMonthConfig)

    def __post_init__(self):
        cfg, seed = self.config, int(self.seed)
        self.device = draw_device('mems', seed)
        self.gravity = normal_gravity(cfg.latitude)
        self.start_ns = MONTH_EPOCH_NS
        rng = _rng(seed, 'robot-month', 'schedule')
        env = _rng(seed, 'robot-month', 'environment')
        dock = _rng(seed, 'robot-month', 'dock')
        days = cfg.days
        # stops
        stops, t = [], []
        for d in range(int(np.ceil(days))):
            n = int(rng.integers(cfg.stops_per_day[0], cfg.stops_per_day[1] + 1))
            t.extend(d * DAY + np.sort(rng.uniform(0, DAY, n)))
        t = np.array([x for x in t if x < days * DAY - 700.0])
        lo, hi = np.log(cfg.stop_s[0]), np.log(cfg.stop_s[1])
        dur = np.exp(rng.uniform(lo, hi, len(t)))
        keep, end = [], -np.inf
        for i in range(len(t)):             # stops do not overlap: 30 s driving at least
            if t[i] >= end + 30.0 + 2 * cfg.pad_s:
                keep.append(i)
                end = t[i] + dur[i]
        for j, i in enumerate(keep):
            slope = rng.random() < cfg.slope_fraction
            tilt = rng.uniform(*cfg.slope_deg) if slope else \
                rng.uniform(0, cfg.level_tilt_deg)
            c = _attitude(rng.uniform(0, 360), tilt, rng.uniform(0, 2 * np.pi))
            if cfg.dock_fraction and dock.random() < cfg.dock_fraction:
                slope, tilt = False, dock.uniform(0, cfg.level_tilt_deg)
                c = _attitude(cfg.dock_heading_deg, tilt, dock.uniform(0, 2 * np.pi))
            push = None
            if rng.random() < cfg.push_fraction and dur[i] > 30:
                p0 = t[i] + rng.uniform(5, dur[i] - 15)
                push = (p0, p0 + rng.uniform(2, 6))
            blocked = bool(rng.random() < cfg.blocked_fraction)
            stops.append(Stop(j, float(t[i]), float(t[i] + dur[i]), c, tilt if slope else 0.0,
                              push, blocked))
        self.stops = stops
        # temperature on a 10-s grid
        self.grid_dt = 10.0
        tg = np.arange(0.0, days * DAY + 2 * self.grid_dt, self.grid_dt)
        season = np.interp(tg, [0, days * DAY], cfg.season)
        amp = env.uniform(*cfg.diurnal_amp)
        diurnal = amp * np.cos(2 * np.pi * (tg / DAY - 15.0 / 24.0))
        per = env.uniform(2.0, 6.0, 3) * DAY
        ph = env.uniform(0, 2 * np.pi, 3)
        weather = cfg.weather_amp / np.sqrt(1.5) * np.sum(
            np.sin(2 * np.pi * tg[:, None] / per + ph), axis=1)
        ambient = np.clip(season + diurnal + weather, 0.0, 40.0)
        moving = np.ones(len(tg), bool)
        for s in stops:
            moving[int(s.t0 // self.grid_dt):int(np.ceil(s.t1 / self.grid_dt))] = False
        target = np.where(moving, cfg.heat_moving, cfg.heat_idle)
        heat = first_order_lag(target, self.grid_dt, cfg.heat_tau_s)
        self.temp_grid = np.clip(ambient + heat, 0.0, 40.0)
        # ageing and the knock
        age = _rng(seed, 'robot-month', 'ageing')
        self.age_accel = _direction(age) * cfg.age_accel
        self.age_gyro = _direction(age) * cfg.age_gyro
        self.knock_t = float(age.uniform(*cfg.knock_day) * DAY) if days > cfg.knock_day[0] \
            else np.inf
        self.knock_accel = _direction(age) * age.uniform(*cfg.knock_accel)
        self.knock_gyro = _direction(age) * age.uniform(*cfg.knock_gyro)
        # restarts between stops
        r = _rng(seed, 'robot-month', 'restarts')
        self.restart_times = np.sort(r.uniform(0.05, 0.95, cfg.restarts) * days * DAY)
        self._noise = _rng(seed, 'robot-month', 'noise')

    # ------------------------------------------------------------------ truth
    def temperature(self, t):
        """Return the true sensor reading in degC at ``t`` (s since the start of the month)."""
        return np.interp(t, np.arange(len(self.temp_grid)) * self.grid_dt, self.temp_grid)

    def bias_change(self, t):
        """Return (accel (n, 3) m/s^2, gyro (n, 3) rad/s) added to the biases at ``t``."""
        t = np.atleast_1d(np.asarray(t, float))
        days = t[:, None] / DAY
        knocked = (t >= self.knock_t)[:, None]
        return (self.age_accel * days + knocked * self.knock_accel,
                self.age_gyro * days + knocked * self.knock_gyro)

    def true_calibration(self, t):
        """Return the exact Calibration at time ``t`` (s): device truth plus ageing."""
        dev = self.device
        da, dg = (x[0] for x in self.bias_change([t]))
        # raw = b(T) + k(T) S f + da: the bias term db0 carries the ageing
        thermal = dev.thermal.copy()
        thermal[:, 3] += da
        coeffs = dev.gyro_coeffs.copy()
        coeffs[0] += dg
        if dev.gyro_ideal:
            gyro = OffsetPolynomialModel(dev.t0, coeffs, sensor='gyro')
        else:
            om1 = np.linalg.inv(dev.gyro_m)
            gyro = WholeUnitGyroModel(dev.t0, coeffs, None, np.zeros(3), om1, None, None,
                                      -om1 @ dev.gyro_g)
        return Calibration(
            accel=FieldPolynomialModel(dev.t0, thermal, dev.k0, dev.b0, dev.s), gyro=gyro,
            inputs=[TemperatureInput('imu_temperature', self.config.temp_topic)],
            valid_range=np.array([[-20.0, 60.0]]), out_of_range='extrapolate',
            frame_id=self.config.frame_id, gravity=self.gravity,
            fit={'method': f'simulation truth (robot-month seed {self.seed}, t = {t:.0f} s)'})

    # ------------------------------------------------------------------ samples
    def segments(self, t_from=0.0, t_to=np.inf):
        """Yield a ``Segment`` per stop starting in [t_from, t_to), in time order."""
        for s in self.stops:
            if t_from <= s.t0 < t_to:
                yield self.segment(s)

    def segment(self, s):
        """Return the ``Segment`` of stop ``s`` (deterministic per seed and stop)."""
        cfg, dev = self.config, self.device
        rng = _rng(self.seed, 'robot-month', 'stop', s.index)
        dt = 1.0 / cfg.imu_rate
        t = np.arange(s.t0 - cfg.pad_s, s.t1 + cfg.pad_s, dt)
        n = len(t)
        still = (t >= s.t0) & (t < s.t1)
        if s.push is not None:
            still &= ~((t >= s.push[0]) & (t < s.push[1]))
        lat = cfg.latitude * DEG
        w_ie = EARTH_RATE * np.array([0.0, np.cos(lat), np.sin(lat)])
        f_n = np.tile([0.0, 0.0, self.gravity], (n, 1))
        w_n = np.zeros((n, 3))
        mv = ~still
        # driving / pushing: vibration and turning (random, band-limited enough at 10 Hz)
        f_n[mv] += rng.normal(0.0, 0.6, (mv.sum(), 3))
        w_n[mv] += rng.normal(0.0, 0.3, (mv.sum(), 3))
        c = s.c_nb
        f_b = f_n @ c          # C^T f for each row
        w_b = (w_n + w_ie) @ c
        temp = self.temperature(t)
        da, dg = self.bias_change(t)
        acc = accel_forward(f_b, np.repeat(temp[:, None], 3, 1), dev.t0, dev.k0, dev.b0,
                            dev.s, dev.thermal) + da
        gyr = gyro_forward(w_b, np.repeat(temp[:, None], 3, 1), dev.t0, dev.gyro_coeffs,
                           dev.gyro_m, dev.gyro_g, f_b) + dg
        spec = dev.spec
        acc += spec.accel_noise_density * np.sqrt(cfg.imu_rate) * rng.standard_normal((n, 3))
        gyr += spec.gyro_noise_density * np.sqrt(cfg.imu_rate) * rng.standard_normal((n, 3))
        acc = np.round(acc / spec.accel_lsb) * spec.accel_lsb
        gyr = np.round(gyr / spec.gyro_lsb) * spec.gyro_lsb
        stamp = self.start_ns + np.round(t * 1e9).astype(np.int64)
        tt = np.arange(np.ceil((s.t0 - cfg.pad_s) * cfg.temp_rate) / cfg.temp_rate,
                       s.t1 + cfg.pad_s, 1.0 / cfg.temp_rate)
        tv = self.temperature(tt) + cfg.temp_noise * rng.standard_normal(len(tt))
        tv = np.round(np.round(tv / cfg.temp_lsb) * cfg.temp_lsb, 9)
        temps = TemperatureColumns(self.start_ns + np.round(tt * 1e9).astype(np.int64), tv,
                                   cfg.frame_id)
        base = self.start_ns * 1e-9
        if s.blocked:     # the command says drive all along: the robot is blocked
            hints = [(base + x, False) for x in np.arange(t[0], t[-1], 0.5)]
        else:
            hints = ([(base + x, False) for x in np.arange(t[0], s.t0, 0.5)]
                     + [(base + s.t0, True)]
                     + [(base + x, False) for x in np.arange(s.t1, t[-1] + dt, 0.5)])
        return Segment(s, ImuColumns(stamp, acc, gyr, cfg.frame_id), temps, hints, f_b, w_b,
                       temp, still)

    def summary(self):
        """Return a plain dict describing the month."""
        n = sum(len(np.arange(s.t0 - self.config.pad_s, s.t1 + self.config.pad_s,
                              1.0 / self.config.imu_rate)) for s in self.stops)
        return {'scenario': self.config.name, 'seed': int(self.seed),
                'days': float(self.config.days), 'stops': len(self.stops),
                'stop_seconds': float(sum(s.t1 - s.t0 for s in self.stops)),
                'imu_samples': int(n), 'imu_rate_hz': self.config.imu_rate,
                'slopes': sum(s.slope_deg > 0 for s in self.stops),
                'pushes': sum(s.push is not None for s in self.stops),
                'blocked': sum(s.blocked for s in self.stops),
                'temperature_degC': [float(self.temp_grid.min()), float(self.temp_grid.max())],
                'knock_day': float(self.knock_t / DAY),
                'restart_days': [float(x / DAY) for x in self.restart_times]}


def robot_month(seed=0, **overrides):
    """Return the ``RobotMonth`` of ``seed`` with config fields replaced by ``overrides``."""
    return RobotMonth(int(seed), replace(RobotMonthConfig(), **overrides))


def _attitude(heading_deg, tilt_deg, azimuth):
    """Return C_nb (sensor to ENU) of a robot at a heading, tilted about a horizontal axis."""
    from scipy.spatial.transform import Rotation
    c = Rotation.from_rotvec([0.0, 0.0, heading_deg * DEG]).as_matrix()
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    return Rotation.from_rotvec(axis * tilt_deg * DEG).as_matrix() @ c


def _direction(rng):
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


#: ``simulate --scenario`` names this module provides (beyond ``sim.SCENARIOS``)
SCENARIOS = {'robot-month': RobotMonthConfig()}
CMD_VEL_TOPIC = '/cmd_vel'


def _twist_cdr(still):
    """Return the CDR bytes of a geometry_msgs/Twist: zero when still, else 0.5 m/s ahead."""
    import struct
    return b'\x00\x01\x00\x00' + struct.pack('<6d', 0.0 if still else 0.5, 0, 0, 0, 0, 0)


def write_robot_month(output, seed=0, storage='mcap', compression='zstd', **overrides):
    """Write the robot month as a log (IMU, temperature, cmd_vel) plus its side file.

    The log holds the sampled stops only (``segments``; the driving between them is not
    sampled), ``/cmd_vel`` (geometry_msgs/Twist, header-less: log time = the IMU stamp it
    belongs to) at 2 Hz around each stop and once at its start, zstd-compressed by default
    (a month is ~2 M IMU messages, ~100 MB). ``<output>.robot_month.yaml`` holds the
    summary, the stops, the knock and the restarts and the true calibration at the start;
    replay it through ``calibrator_node`` with ``lifelong: true`` and ``cmd_vel_topic:
    /cmd_vel``. Returns the paths and the summary.
    """
    import os
    import time
    import yaml
    from ..io import cdr
    from ..io.bag_writer import LogWriter
    from ..io.cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
    from ..io.output import staging_dir, write_atomic
    t_start = time.perf_counter()
    m = robot_month(seed, **overrides)
    cfg = m.config
    out = os.fspath(output).rstrip(os.sep)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    counts = {cfg.imu_topic: 0, cfg.temp_topic: 0, CMD_VEL_TOPIC: 0}
    with staging_dir(out) as tmp:
        with LogWriter(tmp, storage, compression=compression) as w:
            w.add_topic(cfg.imu_topic, IMU_MSGTYPE)
            w.add_topic(cfg.temp_topic, TEMPERATURE_MSGTYPE)
            w.add_topic(CMD_VEL_TOPIC, 'geometry_msgs/msg/Twist')
            for seg in m.segments():
                ev = [(int(s), 0, r) for s, r in zip(seg.imu.stamp_ns, cdr.encode_imu(seg.imu))]
                ev += [(int(s), 1, r) for s, r in zip(seg.temperature.stamp_ns,
                                                      cdr.encode_temperature(seg.temperature))]
                ev += [(int(round(t * 1e9)), 2, _twist_cdr(still)) for t, still in seg.hints]
                ev.sort(key=lambda e: (e[0], e[1]))
                topics = (cfg.imu_topic, cfg.temp_topic, CMD_VEL_TOPIC)
                for stamp, k, raw in ev:
                    w.write(topics[k], stamp, raw)
                    counts[topics[k]] += 1
    truth = m.true_calibration(0.0)
    side = f'{out}.robot_month.yaml'
    info = dict(m.summary(), messages=counts, seconds=round(time.perf_counter() - t_start, 1))
    write_atomic(side, yaml.safe_dump({
        'summary': info, 'knock_s': float(m.knock_t),
        'knock_accel_mps2': m.knock_accel.tolist(), 'knock_gyro_rad_s': m.knock_gyro.tolist(),
        'ageing_accel_mps2_per_day': m.age_accel.tolist(),
        'ageing_gyro_rad_s_per_day': m.age_gyro.tolist(),
        'restart_s': [float(x) for x in m.restart_times],
        'stops': [{'t0_s': float(s.t0), 't1_s': float(s.t1), 'slope_deg': float(s.slope_deg),
                   'push_s': [float(x) for x in s.push] if s.push else None,
                   'blocked': bool(s.blocked)}
                  for s in m.stops],
        'truth_at_start': truth.to_dict()}, sort_keys=False, width=100))
    return {'bag': out, 'side': side, 'summary': info}
