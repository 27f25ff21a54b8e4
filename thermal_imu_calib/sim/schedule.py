"""Simulated scenarios: hold schedules, pose kinematics and temperature tracks.

A scenario is a ``ScenarioConfig`` in ``SCENARIOS``. From ``(seed, scenario name)``
the recording draws its hold schedule, tilts, headings and hand motion
(``_build_schedule``, ``_kinematics``) and its temperature: per sensor a
first-order warm-up T = T_amb + rise (1 - exp(-t / tau)) or a chamber cycle,
optionally seen through a first-order lag (``first_order_lag``).
"""

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
from scipy.signal import lfilter, lfilter_zi
from scipy.spatial.transform import Rotation

from .devices import DEG


FACES = {'+x': (1, 0, 0), '-x': (-1, 0, 0), '+y': (0, 1, 0),
         '-y': (0, -1, 0), '+z': (0, 0, 1), '-z': (0, 0, -1)}
SIX_FACES = ('+x', '-x', '+y', '-y', '+z', '-z')
#: pose label meaning "a cube corner up": all three axes see ~g/sqrt(3) (random corner)
TILTED = 'tilted'


@dataclass(frozen=True)
class ScenarioConfig:
    """Everything that defines a scenario except the seed.

    Poses: ``repetitions`` x ``faces`` holds (``'+x'`` .. ``'-z'`` = that axis up, ``'tilted'``
    = a random cube corner up), each held ``hold_s`` (uniform range) and joined by
    hand-made pose changes lasting ``transition_s``. Holds are tilted by ``tilt_deg``
    (uniform magnitude, random horizontal axis) and get a random heading.

    Temperature: ``profile`` 'warmup' (per sensor ``t_amb + rise (1 - exp(-t / tau))``) or
    'cycle' (chamber air between ``cycle_lo`` and ``cycle_hi`` at ``ramp_degc_per_min`` with
    ``dwell_s`` plateaus, seen by the sensor through a ``case_tau_s`` lag). ``lag_s`` > 0
    drives the IMU errors by a first-order lagged copy of the sensor reading.
    """

    name: str
    description: str
    device: str = 'mems'
    imu_rate: float = 200.0
    faces: Tuple[str, ...] = SIX_FACES
    repetitions: int = 1
    shuffle: bool = False
    hold_s: Tuple[float, float] = (60.0, 90.0)
    #: hold range of the first repetition (None: as ``hold_s``); a quick first pass puts
    #: every face into the fastest, coldest part of a warm-up
    first_hold_s: Optional[Tuple[float, float]] = None
    #: repetitions that use ``first_hold_s``
    first_repetitions: int = 1
    transition_s: Tuple[float, float] = (2.0, 4.0)
    tilt_deg: Tuple[float, float] = (0.5, 4.0)
    lift_m: Tuple[float, float] = (0.02, 0.08)
    jitter_mps2: float = 0.15
    profile: str = 'warmup'
    t_amb: float = 22.0
    t_amb_jitter: float = 0.3
    rise: float = 17.0
    tau_s: float = 600.0
    cycle_lo: float = 10.0
    cycle_hi: float = 50.0
    ramp_degc_per_min: float = 2.0
    dwell_s: float = 900.0
    cycles: int = 2
    case_tau_s: float = 60.0
    lag_s: float = 0.0
    temp_topics: Tuple[str, ...] = ('/imu/temperature',)
    temp_rate: float = 1.0
    temp_lsb: float = 0.125
    temp_noise: float = 0.03
    latitude: float = 45.0
    chunk_size: int = 60_000
    #: > 0: the first hold lasts this long (s; an imu_tk-style initial rest)
    initial_hold_s: float = 0.0
    #: > 0: hand tremor, rotation-rate RMS in deg/s (sim.scenarios.tremor)
    tremor_dps: float = 0.0


#: what every navigation-device scenario shares: the device, its 100 Hz output, per-axis
#: 10 Hz temperature topics (0.01 degC LSB), six faces with 4-8 s pose changes
_NAV = dict(device='nav', imu_rate=100.0, faces=SIX_FACES, transition_s=(4.0, 8.0),
            tilt_deg=(0.5, 4.0), t_amb_jitter=0.2,
            temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
            temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003)

SCENARIOS = {
    'nav-coldstart': ScenarioConfig(
        name='nav-coldstart', **_NAV,
        description='navigation-grade cold start at ~20 degC as in seed 000: 5 x six-position '
                    'scheme over a ~2.5 h warm-up (45-min thermal time constant): a quick '
                    'first pass (60-90 s holds) so every face sees the cold start, then '
                    '5.5-6.5 min holds; per-accelerometer temperature sensors',
        repetitions=5, hold_s=(330.0, 390.0), first_hold_s=(60.0, 90.0), t_amb=20.0,
        rise=16.0, tau_s=2700.0),
    'nav-coldstart-uniform': ScenarioConfig(
        name='nav-coldstart-uniform', **_NAV,
        description='nav-coldstart with every hold 5.5-6.5 min (no quick first pass: the '
                    'z faces first come up ~7 degC above the start temperature)',
        repetitions=5, hold_s=(330.0, 390.0), t_amb=20.0, rise=16.0, tau_s=2700.0),
    'nav-validation': ScenarioConfig(
        name='nav-validation', **_NAV,
        description='second, independent ~3 h cold start of the nav-coldstart device: six '
                    'faces x 28-30 min holds for 300-s averages',
        repetitions=1, shuffle=True, hold_s=(1680.0, 1800.0), t_amb=20.4, rise=16.0,
        tau_s=2700.0),
    'nav-coldstart-short': ScenarioConfig(
        name='nav-coldstart-short', **_NAV,
        description='a hurried variant of nav-coldstart: 5 x six faces with 3-4 min holds '
                    'over a 107-min warm-up (30-min time constant)',
        repetitions=5, hold_s=(180.0, 240.0), t_amb=20.0, rise=16.0, tau_s=1800.0),
    'nav-validation-short': ScenarioConfig(
        name='nav-validation-short', **_NAV,
        description='validation for nav-coldstart-short: six faces x 20 min holds',
        repetitions=1, shuffle=True, hold_s=(1200.0, 1260.0), t_amb=20.4, rise=16.0,
        tau_s=1800.0),
    'mems-coldstart': ScenarioConfig(
        name='mems-coldstart', device='mems', imu_rate=200.0,
        description='consumer MEMS cold start: 3 x (six faces + 2 tilted poses), 60-90 s '
                    'holds, one 1-Hz die temperature topic',
        faces=SIX_FACES + (TILTED, TILTED), repetitions=3, shuffle=True, hold_s=(60.0, 90.0),
        transition_s=(2.0, 4.0), tilt_deg=(0.5, 5.0), t_amb=22.0, rise=17.0, tau_s=540.0,
        temp_rate=1.0),
    'mems-coldstart-poses': ScenarioConfig(
        name='mems-coldstart-poses', device='mems', imu_rate=200.0,
        description='consumer MEMS cold start for the whole-unit model (seed 002): 13 x (six '
                    'faces + 4 corner-up poses), 15-20 s holds for the first three rounds '
                    '(many poses while the temperature moves fast), then 25-35 s holds; '
                    '~65 min, 130 holds, one 1-Hz die temperature topic',
        faces=SIX_FACES + (TILTED,) * 4, repetitions=13, hold_s=(25.0, 35.0),
        first_hold_s=(15.0, 20.0), first_repetitions=3, transition_s=(2.0, 4.0),
        tilt_deg=(0.5, 5.0), t_amb=22.0, rise=17.0, tau_s=540.0, temp_rate=1.0),
    'mems-validation': ScenarioConfig(
        name='mems-validation', device='mems', imu_rate=200.0,
        description='second cold start of the mems-coldstart device: six faces + 2 tilted '
                    'poses x 5.5-6 min holds for 300-s averages',
        faces=SIX_FACES + (TILTED, TILTED), repetitions=1, shuffle=True,
        hold_s=(330.0, 360.0), transition_s=(2.0, 4.0), tilt_deg=(0.5, 5.0), t_amb=22.5,
        rise=17.0, tau_s=540.0, temp_rate=5.0),
    'single-warmup': ScenarioConfig(
        name='single-warmup', device='mems', imu_rate=200.0,
        description='MEMS on a robot mount, one pose, 1 h cold start (offset-only model)',
        faces=('+z',), repetitions=1, hold_s=(3600.0, 3600.0), tilt_deg=(0.5, 2.0),
        t_amb=21.0, rise=18.0, tau_s=900.0, temp_rate=2.0),
    'demo': ScenarioConfig(
        name='demo', device='mems', imu_rate=100.0,
        description='short MEMS cold start for `make demo`: 2 x six faces, 15-20 s holds',
        faces=SIX_FACES, repetitions=2, hold_s=(15.0, 20.0), transition_s=(2.0, 3.0),
        tilt_deg=(0.5, 4.0), t_amb=22.0, rise=15.0, tau_s=90.0, temp_rate=10.0),
    'demo-validation': ScenarioConfig(
        name='demo-validation', device='mems', imu_rate=100.0,
        description='second short cold start of the demo device: six faces, 30-40 s holds',
        faces=SIX_FACES, repetitions=1, shuffle=True, hold_s=(30.0, 40.0),
        transition_s=(2.0, 3.0), tilt_deg=(0.5, 4.0), t_amb=22.3, rise=15.0, tau_s=90.0,
        temp_rate=10.0),
    'chamber-cycle': ScenarioConfig(
        name='chamber-cycle', device='mems', imu_rate=50.0,
        description='one pose in a climatic chamber, 2 cycles 10..50 degC at 1 degC/min with '
                    '10-min dwells; the errors follow the sensor reading through a 300-s lag '
                    '(hysteresis between heating and cooling legs)',
        faces=('+z',), repetitions=1, tilt_deg=(0.2, 1.0), profile='cycle', cycle_lo=10.0,
        cycle_hi=50.0, ramp_degc_per_min=1.0, dwell_s=600.0, cycles=2, case_tau_s=60.0,
        lag_s=300.0, temp_rate=2.0),
    'lag-warmup': ScenarioConfig(
        name='lag-warmup', device='mems', imu_rate=100.0,
        description='single-warmup with the errors driven by a 240-s lagged temperature',
        faces=('+z',), repetitions=1, hold_s=(3600.0, 3600.0), tilt_deg=(0.5, 2.0),
        t_amb=21.0, rise=18.0, tau_s=900.0, lag_s=240.0, temp_rate=2.0),
}


# ---------------------------------------------------------------------------------- poses
@dataclass
class Hold:
    """One stationary pose of the schedule.

    ``up`` is the unit specific force at rest in the sensor (p) frame, i.e. the opposite
    of the gravity direction: a stationary ideal accelerometer reads ``gravity * up``.
    """

    index: int
    face: str
    t_start: float            # s since the first IMU sample
    t_end: float
    stamp_start_ns: int
    stamp_end_ns: int
    up: np.ndarray
    tilt_deg: float
    heading_deg: float

    @property
    def gravity_dir(self):
        """Return the unit gravity direction (pointing down) in the sensor frame."""
        return -self.up

    @property
    def duration(self):
        """Return the hold length in seconds."""
        return self.t_end - self.t_start

    def to_dict(self):
        """Return plain types for YAML."""
        return {'index': self.index, 'face': self.face, 't_start': float(self.t_start),
                't_end': float(self.t_end), 'stamp_start_ns': int(self.stamp_start_ns),
                'stamp_end_ns': int(self.stamp_end_ns),
                'up': [float(v) for v in self.up],
                'gravity_dir': [float(-v) for v in self.up],
                'tilt_deg': float(self.tilt_deg), 'heading_deg': float(self.heading_deg)}


def _rot_between(a, b):
    """Return the rotation matrix taking unit vector a onto unit vector b (shortest arc)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = np.cross(a, b)
    sn, cs = np.linalg.norm(axis), float(np.dot(a, b))
    if sn < 1e-12:
        if cs > 0:
            return np.eye(3)
        perp = np.eye(3)[np.argmin(np.abs(a))]
        axis = np.cross(a, perp)
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    return Rotation.from_rotvec(axis / sn * np.arctan2(sn, cs)).as_matrix()


def _pose(rng, face, tilt_range):
    """Return (C_nb, face label, tilt deg, heading deg) of one hand-placed hold."""
    if face == TILTED:
        corner = rng.choice([-1.0, 1.0], 3)
        label = ''.join(f'{"+" if c > 0 else "-"}{a}' for c, a in zip(corner, 'xyz'))
        up_nominal = corner / np.sqrt(3.0)
    else:
        label, up_nominal = face, np.asarray(FACES[face], float)
    heading = rng.uniform(0.0, 360.0)
    tilt = rng.uniform(*tilt_range) if tilt_range[1] > 0 else 0.0
    az = rng.uniform(0.0, 2 * np.pi)
    c = _rot_between(up_nominal, [0.0, 0.0, 1.0])                  # nominal face up
    c = Rotation.from_rotvec([0.0, 0.0, heading * DEG]).as_matrix() @ c
    tilt_axis = np.array([np.cos(az), np.sin(az), 0.0])
    c = Rotation.from_rotvec(tilt_axis * tilt * DEG).as_matrix() @ c
    return c, label, tilt, heading


@dataclass
class _Segments:
    """The timeline as arrays: holds (angle 0) and pose changes (min-jerk rotations)."""

    t0: np.ndarray        # (m,) start s
    dur: np.ndarray       # (m,)
    c0: np.ndarray        # (m, 3, 3) C_nb at segment start
    axis: np.ndarray      # (m, 3) body-frame rotation axis
    angle: np.ndarray     # (m,) rad (0 for holds)
    moving: np.ndarray    # (m,) bool
    lift: np.ndarray      # (m, 3) nav-frame peak displacement of the hand, m
    jit_amp: np.ndarray   # (m, J, 3) m/s^2
    jit_freq: np.ndarray  # (m, J) Hz
    jit_phase: np.ndarray  # (m, J, 3) rad


def _build_schedule(cfg, rng):
    """Draw holds and transitions; return (_Segments, [pose dicts], duration)."""
    faces = []
    for _ in range(cfg.repetitions):
        rep = list(cfg.faces)
        if cfg.shuffle:
            rep = [rep[i] for i in rng.permutation(len(rep))]
        faces.extend(rep)
    poses = [_pose(rng, f, cfg.tilt_deg) for f in faces]
    if cfg.profile == 'cycle':
        total = _cycle_knots(cfg)[0][-1]
        holds_s = np.array([total])
    else:
        holds_s = rng.uniform(*cfg.hold_s, len(poses))
        if cfg.first_hold_s is not None:
            n_first = len(cfg.faces) * cfg.first_repetitions
            holds_s[:n_first] = rng.uniform(*cfg.first_hold_s, min(n_first, len(poses)))
        if cfg.initial_hold_s > 0:
            holds_s[0] = cfg.initial_hold_s
    trans_s = rng.uniform(*cfg.transition_s, max(len(poses) - 1, 0))
    nj = 3
    rows, t, hold_info = [], 0.0, []
    for i, (c, label, tilt, heading) in enumerate(poses):
        rows.append(dict(t0=t, dur=holds_s[i], c0=c, axis=np.array([1.0, 0, 0]), angle=0.0,
                         moving=False, lift=np.zeros(3), jit_amp=np.zeros((nj, 3)),
                         jit_freq=np.ones(nj), jit_phase=np.zeros((nj, 3))))
        hold_info.append((label, t, t + holds_s[i], c[2].copy(), tilt, heading))
        t += holds_s[i]
        if i + 1 < len(poses):
            rv = Rotation.from_matrix(c.T @ poses[i + 1][0]).as_rotvec()
            ang = float(np.linalg.norm(rv))
            lift_dir = np.array([*rng.normal(0, 0.3, 2), 1.0])
            lift = rng.uniform(*cfg.lift_m) * lift_dir / np.linalg.norm(lift_dir)
            amp = cfg.jitter_mps2 / np.sqrt(nj) * rng.uniform(0.5, 1.5, (nj, 3))
            rows.append(dict(t0=t, dur=trans_s[i], c0=c,
                             axis=rv / ang if ang > 0 else np.array([1.0, 0, 0]), angle=ang,
                             moving=True, lift=lift, jit_amp=amp,
                             jit_freq=rng.uniform(0.7, 4.0, nj),
                             jit_phase=rng.uniform(0, 2 * np.pi, (nj, 3))))
            t += trans_s[i]
    seg = _Segments(**{k: np.array([r[k] for r in rows]) for k in rows[0]})
    return seg, hold_info, t


def _kinematics(seg, t, gravity, w_ie_n):
    """Return true specific force and angular rate (n, 3) in the body frame at times t."""
    n = t.shape[0]
    idx = np.clip(np.searchsorted(seg.t0, t, side='right') - 1, 0, len(seg.t0) - 1)
    c = seg.c0[idx]
    w_nb = np.zeros((n, 3))
    a_n = np.zeros((n, 3))
    mv = seg.moving[idx]
    if np.any(mv):
        j = idx[mv]
        dur = seg.dur[j]
        tm = np.clip((t[mv] - seg.t0[j]) / dur, 0.0, 1.0)
        s = tm ** 3 * (10 - 15 * tm + 6 * tm * tm)                      # minimum jerk
        sdot = 30 * tm * tm * (1 - tm) ** 2 / dur
        c[mv] = c[mv] @ Rotation.from_rotvec(seg.axis[j] * (seg.angle[j] * s)[:, None]
                                             ).as_matrix()
        w_nb[mv] = seg.axis[j] * (seg.angle[j] * sdot)[:, None]
        # hand lifts the unit (bell 64 tau^3 (1-tau)^3, peak = lift) and shakes a little
        bell_dd = 64 * (6 * tm - 36 * tm ** 2 + 60 * tm ** 3 - 30 * tm ** 4) / dur ** 2
        win = np.sin(np.pi * tm) ** 2
        phase = (2 * np.pi * seg.jit_freq[j][:, :, None] * t[mv][:, None, None]
                 + seg.jit_phase[j])
        a_n[mv] = (seg.lift[j] * bell_dd[:, None]
                   + win[:, None] * np.sum(seg.jit_amp[j] * np.sin(phase), axis=1))
    f_n = a_n + np.array([0.0, 0.0, gravity])        # specific force = a - g, g = -g e_up
    f_b = np.einsum('nji,nj->ni', c, f_n)
    w_b = w_nb + np.einsum('nji,j->ni', c, w_ie_n)
    return f_b, w_b


# ---------------------------------------------------------------------------------- thermal
def first_order_lag(u, dt, tau):
    """Filter a uniformly sampled signal by a first-order lag (exact for piecewise-linear u).

    Starts in equilibrium (y[0] = u[0]); ``tau`` <= 0 returns a copy of ``u``.
    """
    u = np.asarray(u, float)
    if tau <= 0:
        return u.copy()
    a = np.exp(-dt / tau)
    c0 = 1.0 - tau * (1.0 - a) / dt
    b = np.array([c0, (1.0 - a) - c0])
    den = np.array([1.0, -a])
    y, _ = lfilter(b, den, u, zi=lfilter_zi(b, den) * u[0])
    return y


def _cycle_knots(cfg):
    """Return (times, temps) of the piecewise-linear chamber air temperature."""
    ramp = (cfg.cycle_hi - cfg.cycle_lo) / cfg.ramp_degc_per_min * 60.0
    tk, vk = [0.0, cfg.dwell_s], [cfg.cycle_lo, cfg.cycle_lo]
    for _ in range(cfg.cycles):
        for v in (cfg.cycle_hi, cfg.cycle_lo):
            tk += [tk[-1] + ramp, tk[-1] + ramp + cfg.dwell_s]
            vk += [v, v]
    return np.array(tk), np.array(vk)


@dataclass
class _ThermalTrack:
    """Sensor-reading and error-driving temperatures per input on a fine uniform grid."""

    grid_dt: float
    read: np.ndarray     # (k, m) degC, what the sensor measures (before quantisation/noise)
    drive: np.ndarray    # (k, m) degC, what the IMU errors follow

    def at(self, t, which='drive'):
        """Return (n, k) temperatures at times t (s) by linear interpolation."""
        src = self.drive if which == 'drive' else self.read
        tg = np.arange(src.shape[1]) * self.grid_dt
        return np.stack([np.interp(t, tg, row) for row in src], axis=1)


def _thermal_track(cfg, dev, duration, t_amb, grid_dt=0.25):
    k = len(cfg.temp_topics)
    tg = np.arange(0.0, duration + 2 * grid_dt, grid_dt)
    if cfg.profile == 'warmup':
        rise = cfg.rise * dev.rise_factor[:k, None]
        tau = cfg.tau_s * dev.tau_factor[:k, None]
        read = t_amb + rise * (1.0 - np.exp(-tg / tau))
    elif cfg.profile == 'cycle':
        tk, vk = _cycle_knots(cfg)
        air = np.interp(tg, tk, vk)
        read = np.stack([first_order_lag(air, grid_dt, cfg.case_tau_s * dev.tau_factor[i])
                         for i in range(k)])
    else:
        raise ValueError(f'unknown temperature profile {cfg.profile!r}')
    drive = np.stack([first_order_lag(r, grid_dt, cfg.lag_s) for r in read])
    return _ThermalTrack(grid_dt, read, drive)
