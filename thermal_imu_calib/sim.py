"""Realistic IMU recordings with temperature-induced errors, for demos, tests and benchmarks.

A scenario is a ``ScenarioConfig`` in ``SCENARIOS``; ``simulate(name, seed)`` turns it into a
``SimRecording`` that streams ``ImuColumns`` chunks (bounded memory, any length) and holds
the temperature series, the pose schedule, the true calibration and the lab prior.

Randomness has two independent sources:

* the *device* (true thermal parameters, lab prior, per-sensor warm-up shape) is drawn
  from ``(seed, device family)``, so ``nav-coldstart`` and ``nav-validation`` with the same
  seed are two cold starts of one and the same IMU;
* the *recording* (noise, hold schedule, tilts, headings, hand motion, start temperature,
  temperature sample phase) is drawn from ``(seed, scenario name)``.

Physics (body frame = accelerometer reference frame p, navigation frame ENU):

* accelerometer, seed 000 eq. (8), written out here independently of ``models.field``::

      raw_i = b0_i + db0_i + b1_i dT_i + b2_i dT_i^2
              + (k0_i + dk0_i + k1_i dT_i + k2_i dT_i^2) (S f^p)_i + noise,   dT_i = T_i - T0_i

  with f^p = C_nb^T (a^n - g^n) the specific force (gravity rotating during pose changes,
  plus the hand's translational acceleration);
* gyro, seed 002 eq. (3)-(4) written forward: raw = M w^b + G f^p + sum_j c_j dT^j + noise
  with w^b = w_nb^b + C_nb^T w_ie^n (earth rate at the configured latitude), M = I +
  scale errors + misalignment (3x3), G the g-sensitivity (rad/s per m/s^2); the 'nav'
  family has M = I, G = 0;
* temperature: per sensor a first-order warm-up T = T_amb + rise (1 - exp(-t / tau)) or a
  chamber cycle; the error is driven by the sensor reading itself or, with ``lag_s > 0``, by
  a first-order lagged copy of it (hysteresis between heating and cooling legs). Published
  readings are quantised and asynchronous to the IMU.

White noise per sample is density * sqrt(rate) (one-sided density in unit/sqrt(Hz)).
"""

import dataclasses
import os
import time
import zlib
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
from scipy.signal import lfilter, lfilter_zi
from scipy.spatial.transform import Rotation
import yaml

from .calibration import Calibration, TemperatureInput
from .thermal_input import ThermalFilter
from .gravity import normal_gravity
from .io.columns import ImuColumns, TemperatureColumns
from .models.field import FieldPolynomialModel
from .models.polynomial import OffsetPolynomialModel
from .models.whole_unit import WholeUnitGyroModel

G0 = 9.80665                 # m/s^2 per g, to convert datasheet densities
EARTH_RATE = 7.2921150e-5    # rad/s, WGS84
DEG = np.pi / 180.0
#: 2025-01-01T00:00:00Z; recordings start within 30 days of it
EPOCH_NS = 1_735_689_600 * 10 ** 9
FACES = {'+x': (1, 0, 0), '-x': (-1, 0, 0), '+y': (0, 1, 0),
         '-y': (0, -1, 0), '+z': (0, 0, 1), '-z': (0, 0, -1)}
SIX_FACES = ('+x', '-x', '+y', '-y', '+z', '-z')
#: pose label meaning "a cube corner up": all three axes see ~g/sqrt(3) (random corner)
TILTED = 'tilted'
#: order of the columns of ``DeviceParams.thermal`` (same as seed 000 eq. 9)
THERMAL_COLUMNS = ('dk0', 'k1', 'k2', 'db0', 'b1', 'b2')


# ---------------------------------------------------------------------------------- configs
@dataclass(frozen=True)
class DeviceSpec:
    """Distributions of the true parameters of one device family.

    Each distribution is a tuple: ``('const', v)``, ``('normal', sigma)``,
    ``('uniform', lo, hi)``, ``('uniform+-', lo, hi)`` (magnitude uniform, random sign) or
    ``('log+-', lo, hi)`` (magnitude log-uniform, random sign); drawn per axis.
    """

    name: str
    description: str
    #: 'lab': the prior holds the lab k0, b0, S (truth k0/b0/S = prior);
    #: 'nominal': no lab calibration, prior is k0 = 1, b0 = 0, S = I (truth S still skewed)
    prior: str
    t0: tuple                # reference temperature T0 of the lab calibration, degC
    k0_error: tuple          # lab scale factor k0 - 1
    b0: tuple                # lab bias, m/s^2
    s_offdiag: tuple         # S below-diagonal entries (rows normalised to unit length)
    dk0: tuple
    k1: tuple                # 1/degC
    k2: tuple                # 1/degC^2
    db0: tuple               # m/s^2
    b1: tuple                # m/s^2/degC
    b2: tuple                # m/s^2/degC^2
    gyro_c0: tuple           # rad/s
    gyro_c1: tuple           # rad/s/degC
    gyro_c2: tuple           # rad/s/degC^2
    accel_noise_density: float   # m/s^2/sqrt(Hz)
    gyro_noise_density: float    # rad/s/sqrt(Hz)
    accel_lsb: float = 0.0       # output quantisation, m/s^2 (0: none)
    gyro_lsb: float = 0.0        # rad/s
    #: per-sensor relative spread of the warm-up rise and time constant (device property)
    warmup_spread: float = 0.08
    #: gyro scale-factor errors (diagonal of M - I), 1
    gyro_scale: tuple = ('const', 0.0)
    #: gyro misalignment (off-diagonal of M, 6 elements), rad
    gyro_misalignment: tuple = ('const', 0.0)
    #: gyro g-sensitivity G (9 elements), rad/s per m/s^2
    gyro_g_sensitivity: tuple = ('const', 0.0)


DEVICES = {
    # Seed 000 Table 1: quartz-flexure accelerometer triad of a laser-gyro INS.
    'nav': DeviceSpec(
        name='nav', prior='lab',
        description='navigation-grade quartz accelerometers + ring-laser gyros (seed 000 '
                    'Table 1 magnitudes)',
        t0=('uniform', 29.0, 31.0),
        k0_error=('normal', 3e-4), b0=('normal', 1e-3), s_offdiag=('log+-', 1e-5, 1e-4),
        dk0=('normal', 1.2e-6), k1=('uniform', -60e-6, -40e-6),
        k2=('uniform+-', 0.08e-6, 0.25e-6), db0=('log+-', 1.5e-3, 1.4e-2),
        b1=('log+-', 1e-6, 7.5e-5), b2=('log+-', 5e-8, 3.2e-6),
        gyro_c0=('normal', 1e-7), gyro_c1=('log+-', 1e-9, 1e-8),
        gyro_c2=('log+-', 1e-11, 1e-10),
        accel_noise_density=5e-5 * G0,            # 5e-5 g/sqrt(Hz), seed 000 section 4
        gyro_noise_density=0.005 * DEG / 60.0,    # ARW 0.005 deg/sqrt(h)
        warmup_spread=0.08),
    # Consumer MEMS (BMI/ICM/LSM class), uncalibrated: the datasheet is the only prior.
    'mems': DeviceSpec(
        name='mems', prior='nominal',
        description='consumer MEMS 6-axis IMU, no lab calibration',
        t0=('const', 25.0),
        k0_error=('const', 0.0), b0=('const', 0.0), s_offdiag=('uniform+-', 2e-4, 8e-4),
        dk0=('uniform+-', 1e-3, 5e-3), k1=('uniform+-', 0.5e-4, 1.5e-4),
        k2=('uniform+-', 5e-7, 3e-6), db0=('uniform+-', 0.05, 0.3),
        b1=('uniform+-', 0.5e-3, 2e-3), b2=('uniform+-', 5e-6, 3e-5),
        gyro_c0=('uniform+-', 5e-4, 3e-3), gyro_c1=('uniform+-', 5e-5, 2e-4),
        gyro_c2=('uniform+-', 5e-7, 3e-6),
        accel_noise_density=150e-6 * G0,          # 150 ug/sqrt(Hz)
        gyro_noise_density=0.005 * DEG,           # 0.005 deg/s/sqrt(Hz)
        accel_lsb=8 * G0 / 65536,                 # +-4 g, 16 bit
        gyro_lsb=1000 * DEG / 65536,              # +-500 deg/s, 16 bit
        warmup_spread=0.05,
        # seed 002 Table 2 class: scale 0.1-0.4 %, misalignment 0.02-0.09 deg,
        # g-sensitivity 0.01-0.04 deg/s/g per element
        gyro_scale=('uniform+-', 1e-3, 4e-3), gyro_misalignment=('uniform+-', 3e-4, 1.5e-3),
        gyro_g_sensitivity=('uniform+-', 1.8e-5, 7e-5)),
}


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
    #: > 0: hand tremor, rotation-rate RMS in deg/s (sim_scenarios.tremor)
    tremor_dps: float = 0.0


SCENARIOS = {
    'nav-coldstart': ScenarioConfig(
        name='nav-coldstart', device='nav', imu_rate=100.0,
        description='navigation-grade cold start at ~20 degC as in seed 000: 5 x six-position '
                    'scheme over a ~2.5 h warm-up (45-min thermal time constant): a quick '
                    'first pass (60-90 s holds) so every face sees the cold start, then '
                    '5.5-6.5 min holds; per-accelerometer temperature sensors',
        faces=SIX_FACES, repetitions=5, hold_s=(330.0, 390.0), first_hold_s=(60.0, 90.0),
        transition_s=(4.0, 8.0), tilt_deg=(0.5, 4.0), t_amb=20.0, t_amb_jitter=0.2,
        rise=16.0, tau_s=2700.0,
        temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
        temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003),
    'nav-coldstart-uniform': ScenarioConfig(
        name='nav-coldstart-uniform', device='nav', imu_rate=100.0,
        description='nav-coldstart with every hold 5.5-6.5 min (no quick first pass: the '
                    'z faces first come up ~7 degC above the start temperature)',
        faces=SIX_FACES, repetitions=5, hold_s=(330.0, 390.0), transition_s=(4.0, 8.0),
        tilt_deg=(0.5, 4.0), t_amb=20.0, t_amb_jitter=0.2, rise=16.0, tau_s=2700.0,
        temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
        temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003),
    'nav-validation': ScenarioConfig(
        name='nav-validation', device='nav', imu_rate=100.0,
        description='second, independent ~3 h cold start of the nav-coldstart device: six '
                    'faces x 28-30 min holds for 300-s averages',
        faces=SIX_FACES, repetitions=1, shuffle=True, hold_s=(1680.0, 1800.0),
        transition_s=(4.0, 8.0), tilt_deg=(0.5, 4.0), t_amb=20.4, t_amb_jitter=0.2,
        rise=16.0, tau_s=2700.0,
        temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
        temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003),
    'nav-coldstart-short': ScenarioConfig(
        name='nav-coldstart-short', device='nav', imu_rate=100.0,
        description='a hurried variant of nav-coldstart: 5 x six faces with 3-4 min holds '
                    'over a 107-min warm-up (30-min time constant)',
        faces=SIX_FACES, repetitions=5, hold_s=(180.0, 240.0), transition_s=(4.0, 8.0),
        tilt_deg=(0.5, 4.0), t_amb=20.0, t_amb_jitter=0.2, rise=16.0, tau_s=1800.0,
        temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
        temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003),
    'nav-validation-short': ScenarioConfig(
        name='nav-validation-short', device='nav', imu_rate=100.0,
        description='validation for nav-coldstart-short: six faces x 20 min holds',
        faces=SIX_FACES, repetitions=1, shuffle=True, hold_s=(1200.0, 1260.0),
        transition_s=(4.0, 8.0), tilt_deg=(0.5, 4.0), t_amb=20.4, t_amb_jitter=0.2,
        rise=16.0, tau_s=1800.0,
        temp_topics=('/imu/temperature/x', '/imu/temperature/y', '/imu/temperature/z'),
        temp_rate=10.0, temp_lsb=0.01, temp_noise=0.003),
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


# ---------------------------------------------------------------------------------- models
def accel_forward(f, temps, t0, k0, b0, s, thermal):
    """Return raw accelerometer output (n, 3) for specific force ``f`` (n, 3) in frame p.

    Seed 000 eq. (8), per axis i with dT_i = T_i - T0_i and f^a = S f^p::

        raw_i = (b0_i + db0_i + b1_i dT_i + b2_i dT_i^2)
                + (k0_i + dk0_i + k1_i dT_i + k2_i dT_i^2) f^a_i

    ``thermal`` is (3, 6) with columns dk0, k1, k2, db0, b1, b2; ``temps`` (n, 3) degC.
    """
    th = np.asarray(thermal, float)
    dk0, k1, k2, db0, b1, b2 = (th[:, j] for j in range(6))
    d = np.asarray(temps, float) - np.asarray(t0, float)
    f_a = np.einsum('ij,nj->ni', np.asarray(s, float), np.asarray(f, float))
    bias = b0 + db0 + b1 * d + b2 * d ** 2
    scale = k0 + dk0 + k1 * d + k2 * d ** 2
    return bias + scale * f_a


def gyro_forward(w, temps, t0, coeffs, m=None, g=None, f=None):
    """Return raw gyro output (n, 3): M w + G f + the bias polynomial sum_j c_j dT^j.

    ``w`` (n, 3) rad/s true rate, ``temps`` (n, 3) degC; ``m`` (3, 3) scale/misalignment
    (None: identity), ``g`` (3, 3) g-sensitivity in rad/s per m/s^2 applied to the specific
    force ``f`` (n, 3) m/s^2 (None: none).
    """
    d = np.asarray(temps, float) - np.asarray(t0, float)
    w = np.asarray(w, float)
    out = w @ np.asarray(m, float).T if m is not None else w.copy()
    if g is not None:
        out += np.asarray(f, float) @ np.asarray(g, float).T
    for j, c in enumerate(np.asarray(coeffs, float)):
        out += c * d ** j
    return out


@dataclass
class DeviceParams:
    """The true parameters of one simulated device (drawn from ``(seed, family)``)."""

    spec: DeviceSpec
    t0: np.ndarray            # (3,) degC
    k0: np.ndarray            # (3,) lab scale factor
    b0: np.ndarray            # (3,) lab bias m/s^2
    s: np.ndarray             # (3, 3) true lower-triangular non-orthogonality
    thermal: np.ndarray       # (3, 6) dk0, k1, k2, db0, b1, b2
    gyro_coeffs: np.ndarray   # (3, 3) rows c0, c1, c2 (rad/s, /degC, /degC^2)
    rise_factor: np.ndarray   # (3,) per temperature sensor, multiplies the scenario rise
    tau_factor: np.ndarray    # (3,) per temperature sensor, multiplies the scenario tau
    #: (3, 3) gyro scale/misalignment M (raw = M w + ...), identity when ideal
    gyro_m: np.ndarray = field(default_factory=lambda: np.eye(3))
    #: (3, 3) gyro g-sensitivity G, rad/s per m/s^2
    gyro_g: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    @property
    def gyro_ideal(self):
        """Return True when the gyro has no scale, misalignment or g-sensitivity error."""
        return bool(np.all(self.gyro_m == np.eye(3)) and not np.any(self.gyro_g))

    def gyro_truth_model(self):
        """Return the true gyro calibration model (offset polynomial, or seed 002 form).

        raw = M w + G f + c(dT) inverts to w = Omega1 (raw - c(dT)) + C f with
        Omega1 = M^-1 and C = -M^-1 G (``models.whole_unit.WholeUnitGyroModel``).
        """
        if self.gyro_ideal:
            return OffsetPolynomialModel(self.t0, self.gyro_coeffs, sensor='gyro')
        om1 = np.linalg.inv(self.gyro_m)
        return WholeUnitGyroModel(self.t0, self.gyro_coeffs, None, np.zeros(3), om1, None,
                                  None, -om1 @ self.gyro_g)

    @property
    def prior_k0(self):
        """Return the scale factor a user's prior holds."""
        return self.k0 if self.spec.prior == 'lab' else np.ones(3)

    @property
    def prior_b0(self):
        """Return the bias a user's prior holds."""
        return self.b0 if self.spec.prior == 'lab' else np.zeros(3)

    @property
    def prior_s(self):
        """Return the non-orthogonality a user's prior holds."""
        return self.s if self.spec.prior == 'lab' else np.eye(3)


def _key(*parts):
    """Return a stable entropy list for SeedSequence from ints and strings."""
    return [p if isinstance(p, int) else zlib.crc32(str(p).encode()) for p in parts]


def _rng(*parts):
    return np.random.default_rng(np.random.SeedSequence(_key(*parts)))


def _draw(rng, dist, shape=3):
    kind, *a = dist
    if kind == 'const':
        return np.full(shape, float(a[0]))
    if kind == 'normal':
        return rng.normal(0.0, a[0], shape)
    if kind == 'uniform':
        return rng.uniform(a[0], a[1], shape)
    sign = rng.choice([-1.0, 1.0], shape)
    if kind == 'uniform+-':
        return sign * rng.uniform(a[0], a[1], shape)
    if kind == 'log+-':
        return sign * np.exp(rng.uniform(np.log(a[0]), np.log(a[1]), shape))
    raise ValueError(f'unknown distribution {kind!r}')


def draw_device(family, seed):
    """Draw the true parameters of device ``seed`` of ``family`` ('nav' or 'mems')."""
    spec = DEVICES[family] if isinstance(family, str) else family
    seed = int(seed)

    def p(name, shape=3):
        return _draw(_rng(seed, 'device', spec.name, name), getattr(spec, name), shape)

    t0 = p('t0')
    s = np.eye(3)
    s[np.tril_indices(3, -1)] = p('s_offdiag')
    s /= np.linalg.norm(s, axis=1, keepdims=True)   # rows are unit sensing-axis vectors
    thermal = np.stack([p(n) for n in THERMAL_COLUMNS], axis=1)
    gyro = np.stack([p('gyro_c0'), p('gyro_c1'), p('gyro_c2')])
    w = _rng(seed, 'device', spec.name, 'warmup')
    rise_f = 1.0 + spec.warmup_spread * np.clip(w.standard_normal(3), -2, 2)
    tau_f = 1.0 + spec.warmup_spread * np.clip(w.standard_normal(3), -2, 2)
    m = np.eye(3) + np.diag(p('gyro_scale'))
    m[~np.eye(3, dtype=bool)] = p('gyro_misalignment', 6)
    return DeviceParams(spec, t0, 1.0 + p('k0_error'), p('b0'), s, thermal, gyro,
                        rise_f, tau_f, m, p('gyro_g_sensitivity', (3, 3)))


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


# ---------------------------------------------------------------------------------- recording
@dataclass
class TruthChunk:
    """The noise-free truth behind one IMU chunk (for benchmarks and tests)."""

    stamp_ns: np.ndarray
    specific_force: np.ndarray   # (n, 3) m/s^2, sensor frame p
    angular_rate: np.ndarray     # (n, 3) rad/s, incl. earth rate
    temps: np.ndarray            # (n, k) degC, the error-driving temperature per input


@dataclass
class SimRecording:
    """A simulated recording: lazily generated IMU chunks plus everything known about it."""

    config: ScenarioConfig
    seed: int
    device: DeviceParams
    truth: Calibration
    prior: Calibration
    schedule: List[Hold]
    temperatures: Dict[str, TemperatureColumns]
    gravity: float
    start_ns: int
    duration: float
    n_samples: int
    meta: dict = field(default_factory=dict)
    imu_topic: str = '/imu/data_raw'
    frame_id: str = 'imu_link'
    _segments: Optional[_Segments] = field(default=None, repr=False)
    _thermal: Optional[_ThermalTrack] = field(default=None, repr=False)
    #: errors outside the model families (``sim_unmodelled``): ``fn(TruthChunk)`` returns
    #: (accel (n, 3) m/s^2, gyro (n, 3) rad/s) added to the raw output before quantisation
    extra_error: Optional[object] = field(default=None, repr=False)

    @property
    def name(self):
        """Return the scenario name."""
        return self.config.name

    @property
    def imu_rate(self):
        """Return the IMU sample rate in Hz."""
        return self.config.imu_rate

    @property
    def accel_noise_std(self):
        """Return the white accel noise 1-sigma per sample (3,), m/s^2, incl. quantisation."""
        return self.truth.accel_noise_std

    @property
    def gyro_noise_std(self):
        """Return the white gyro noise 1-sigma per sample (3,), rad/s, incl. quantisation."""
        return self.truth.gyro_noise_std

    def stamps(self, i0=0, i1=None):
        """Return the int64 ns IMU stamps of samples i0..i1."""
        i1 = self.n_samples if i1 is None else i1
        i = np.arange(i0, i1, dtype=np.int64)
        return self.start_ns + np.round(i * (1e9 / self.imu_rate)).astype(np.int64)

    def temperature_at(self, stamp_ns, which='drive'):
        """Return the exact (n, k) temperature per input at IMU stamps.

        ``which='drive'`` is the temperature the errors follow (the lagged one when the
        scenario has ``lag_s``), ``'read'`` what the sensor sees before quantisation.
        """
        t = (np.asarray(stamp_ns, np.int64) - self.start_ns) * 1e-9
        return self._thermal.at(t, which)

    def _ranges(self, chunk_size):
        step = int(chunk_size or self.config.chunk_size)
        return [(i, min(i + step, self.n_samples)) for i in range(0, self.n_samples, step)]

    def truth_chunks(self, chunk_size=None):
        """Yield ``TruthChunk`` aligned with ``imu_chunks`` (same chunk_size)."""
        lat = self.config.latitude * DEG
        w_ie = EARTH_RATE * np.array([0.0, np.cos(lat), np.sin(lat)])
        for i0, i1 in self._ranges(chunk_size):
            stamp = self.stamps(i0, i1)
            t = (stamp - self.start_ns) * 1e-9
            f_b, w_b = _kinematics(self._segments, t, self.gravity, w_ie)
            yield TruthChunk(stamp, f_b, w_b, self._thermal.at(t, 'drive'))

    def imu_chunks(self, chunk_size=None):
        """Yield the raw IMU recording as ``ImuColumns`` chunks (deterministic per seed).

        The noise stream does not depend on ``chunk_size``; each call starts afresh.
        """
        spec = self.device.spec
        rng = _rng(self.seed, 'recording', self.config.name, 'imu-noise')
        sig_a = spec.accel_noise_density * np.sqrt(self.imu_rate)
        sig_g = spec.gyro_noise_density * np.sqrt(self.imu_rate)
        dev, cal = self.device, self.truth
        for tc in self.truth_chunks(chunk_size):
            n = tc.stamp_ns.shape[0]
            noise = rng.standard_normal((n, 6))
            ta = tc.temps[:, cal.accel_input]
            tg = tc.temps[:, cal.gyro_input]
            acc = accel_forward(tc.specific_force, ta, dev.t0, dev.k0, dev.b0, dev.s,
                                dev.thermal) + sig_a * noise[:, :3]
            gyr = gyro_forward(tc.angular_rate, tg, dev.t0, dev.gyro_coeffs, dev.gyro_m,
                               dev.gyro_g, tc.specific_force) + sig_g * noise[:, 3:]
            if self.config.tremor_dps > 0:
                from .sim_scenarios import tremor
                acc, gyr = tremor(self, tc, acc, gyr)
            if self.extra_error is not None:
                da, dg = self.extra_error(tc)
                acc, gyr = acc + da, gyr + dg
            if spec.accel_lsb > 0:
                acc = np.round(acc / spec.accel_lsb) * spec.accel_lsb
            if spec.gyro_lsb > 0:
                gyr = np.round(gyr / spec.gyro_lsb) * spec.gyro_lsb
            yield ImuColumns(tc.stamp_ns, acc, gyr, self.frame_id)

    def imu(self):
        """Return the whole recording as one ``ImuColumns`` (only for short scenarios)."""
        return ImuColumns.concat(list(self.imu_chunks()))

    def summary(self):
        """Return a plain dict describing the recording."""
        return {
            'scenario': self.name, 'seed': self.seed, 'device': self.device.spec.name,
            'duration_s': round(float(self.duration), 3), 'imu_rate_hz': self.imu_rate,
            'imu_samples': self.n_samples, 'imu_topic': self.imu_topic,
            'holds': len(self.schedule),
            'temperature': {topic: {'samples': len(tc),
                                    'min': float(tc.temperature.min()),
                                    'max': float(tc.temperature.max())}
                            for topic, tc in self.temperatures.items()},
            'temperature_lag_s': float(self.config.lag_s),
        }

    def schedule_dict(self):
        """Return the schedule file content (metadata + holds) as plain types."""
        cfg = self.config
        return {
            'scenario': self.name, 'seed': self.seed, 'description': cfg.description,
            'imu_topic': self.imu_topic, 'frame_id': self.frame_id,
            'imu_rate_hz': float(cfg.imu_rate), 'imu_samples': int(self.n_samples),
            'start_stamp_ns': int(self.start_ns), 'duration_s': float(self.duration),
            'gravity': float(self.gravity), 'latitude_deg': float(cfg.latitude),
            'up_convention': 'up = unit specific force at rest in the sensor frame '
                             '(= -gravity direction)',
            'temperature': {'topics': list(cfg.temp_topics), 'rate_hz': float(cfg.temp_rate),
                            'lsb_degC': float(cfg.temp_lsb), 'noise_degC': float(cfg.temp_noise),
                            'lag_s': float(cfg.lag_s)},
            'simulation': _plain(self.meta),
            'holds': [h.to_dict() for h in self.schedule],
        }


def _plain(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            out[k] = v.tolist()
        elif isinstance(v, np.generic):
            out[k] = v.item()
        else:
            out[k] = v
    return out


def _config(name, overrides):
    cfg = name if isinstance(name, ScenarioConfig) else SCENARIOS.get(name)
    if cfg is None:
        raise KeyError(f'unknown scenario {name!r}; known: {", ".join(SCENARIOS)}')
    if overrides:
        cfg = dataclasses.replace(cfg, **overrides)
    if cfg.device not in DEVICES:
        raise ValueError(f'unknown device family {cfg.device!r}; known: {sorted(DEVICES)}')
    if cfg.profile == 'cycle' and cfg.repetitions * len(cfg.faces) != 1:
        raise ValueError('a chamber cycle is recorded in one pose: use one face, 1 repetition')
    if len(cfg.temp_topics) not in (1, 3):
        raise ValueError('temp_topics must be one shared topic or three per-axis topics')
    return cfg


def simulate(name, seed=0, **overrides):
    """Build the recording of scenario ``name`` (a ``SCENARIOS`` key or a ScenarioConfig).

    ``overrides`` replace config fields (e.g. ``repetitions=1`` for a short test run).
    Temperatures, schedule and calibrations are computed now; IMU samples only when
    ``imu_chunks()`` is iterated.
    """
    cfg = _config(name, overrides)
    seed = int(seed)
    dev = draw_device(cfg.device, seed)
    spec = dev.spec
    rec_rng = _rng(seed, 'recording', cfg.name, 'schedule')
    seg, hold_info, duration = _build_schedule(cfg, rec_rng)
    env = _rng(seed, 'recording', cfg.name, 'environment')
    t_amb = cfg.t_amb + env.uniform(-cfg.t_amb_jitter, cfg.t_amb_jitter)
    start_ns = EPOCH_NS + int(env.integers(0, 30 * 86400)) * 10 ** 9 \
        + int(env.integers(0, 10 ** 9 // 1000)) * 1000
    rate = float(cfg.imu_rate)
    n = int(np.floor(duration * rate)) + 1
    thermal = _thermal_track(cfg, dev, duration, t_amb)
    gravity = normal_gravity(cfg.latitude)

    # published temperature readings: asynchronous, noisy, quantised
    k = len(cfg.temp_topics)
    temps = {}
    period = 1.0 / cfg.temp_rate
    for i, topic in enumerate(cfg.temp_topics):
        tt = env.uniform(0, period) + np.arange(0.0, duration, period)
        tt = tt[tt <= duration]
        val = thermal.at(tt, 'read')[:, i] + cfg.temp_noise * env.standard_normal(tt.size)
        if cfg.temp_lsb > 0:
            val = np.round(np.round(val / cfg.temp_lsb) * cfg.temp_lsb, 9)
        temps[topic] = TemperatureColumns(start_ns + np.round(tt * 1e9).astype(np.int64),
                                          val, 'imu_link')

    idx = [0, 1, 2] if k == 3 else [0, 0, 0]
    inputs = [TemperatureInput(f't_{t.rstrip("/").split("/")[-1]}' if k == 3 else 't0', t)
              for t in cfg.temp_topics]
    valid = np.array([[temps[t].temperature.min(), temps[t].temperature.max()]
                      for t in cfg.temp_topics])
    sig_a = np.sqrt((spec.accel_noise_density ** 2 * rate) + spec.accel_lsb ** 2 / 12)
    sig_g = np.sqrt((spec.gyro_noise_density ** 2 * rate) + spec.gyro_lsb ** 2 / 12)
    meta = {'scenario': cfg.name, 'seed': seed, 'device': spec.name,
            'temperature_profile': cfg.profile, 'temperature_lag_s': float(cfg.lag_s),
            'accel_noise_density': spec.accel_noise_density,
            'gyro_noise_density': spec.gyro_noise_density,
            'accel_lsb': spec.accel_lsb, 'gyro_lsb': spec.gyro_lsb}
    if cfg.profile == 'warmup':
        meta.update(ambient_degC=round(float(t_amb), 4),
                    warmup_rise_degC=(cfg.rise * dev.rise_factor[:k]).round(4).tolist(),
                    warmup_tau_s=(cfg.tau_s * dev.tau_factor[:k]).round(2).tolist())
    else:
        meta.update(chamber_degC=[cfg.cycle_lo, cfg.cycle_hi], cycles=cfg.cycles,
                    ramp_degC_per_min=cfg.ramp_degc_per_min, dwell_s=cfg.dwell_s,
                    case_tau_s=(cfg.case_tau_s * dev.tau_factor[:k]).round(2).tolist())
    notes = [f'simulated truth: scenario {cfg.name}, seed {seed}, device {spec.name} '
             f'({spec.description})']
    if cfg.lag_s > 0:
        notes.append(f'the simulated errors follow the temperature reading through a '
                     f'first-order lag of {cfg.lag_s:g} s; this polynomial is in the lagged '
                     'temperature')
    if spec.prior == 'nominal':
        notes.append('the prior is nominal (k0 = 1, b0 = 0, S = I); the true S is skewed')
    if not dev.gyro_ideal:
        notes.append('gyro: seed 002 form with scale/misalignment Omega1 = M^-1 and '
                     'g-sensitivity C = -M^-1 G (rad/s per m/s^2)')
    truth = Calibration(
        accel=FieldPolynomialModel(dev.t0, dev.thermal, dev.k0, dev.b0, dev.s),
        gyro=dev.gyro_truth_model(),
        inputs=inputs, valid_range=valid, accel_input=idx, gyro_input=idx,
        frame_id='imu_link', gravity=gravity,
        gravity_source=f'WGS84 normal gravity at {cfg.latitude} deg, 0 m',
        accel_noise_std=np.full(3, sig_a), gyro_noise_std=np.full(3, sig_g),
        fit={'method': 'simulation truth', 'simulation': meta}, notes=notes,
        temperature_filter=ThermalFilter(np.full(k, cfg.lag_s)) if cfg.lag_s > 0 else None)
    lo = np.array([dev.t0[[a for a in range(3) if idx[a] == i]].min() - 0.5 for i in range(k)])
    hi = np.array([dev.t0[[a for a in range(3) if idx[a] == i]].max() + 0.5 for i in range(k)])
    prior = Calibration(
        accel=FieldPolynomialModel(dev.t0, np.zeros((3, 6)), dev.prior_k0, dev.prior_b0,
                                   dev.prior_s),
        inputs=list(inputs), valid_range=np.stack([lo, hi], 1), accel_input=idx,
        frame_id='imu_link', gravity=gravity, gravity_source=truth.gravity_source,
        fit={'method': 'lab calibration (simulated)' if spec.prior == 'lab'
             else 'nominal (no lab calibration)', 'simulation': meta},
        notes=[f'prior of simulated device {spec.name} seed {seed}: k0, b0, S at T0, no '
               'thermal terms; valid only near the lab temperature T0'])

    schedule = [Hold(i, label, t0, t1, start_ns + int(round(t0 * 1e9)),
                     start_ns + int(round(t1 * 1e9)), up, tilt, heading)
                for i, (label, t0, t1, up, tilt, heading) in enumerate(hold_info)]
    return SimRecording(cfg, seed, dev, truth, prior, schedule, temps, gravity, start_ns,
                        duration, n, meta, _segments=seg, _thermal=thermal)


def _sidecar(output, kind):
    return f'{os.fspath(output).rstrip(os.sep)}.{kind}.yaml'


def write_scenario(output, name, seed=0, storage='mcap', overwrite=False, compression='none',
                   transform=None, **overrides):
    """Simulate ``name`` and write the bag plus truth, prior and schedule files.

    ``output`` ending in ``.mcap`` becomes a bare MCAP file, anything else a rosbag2
    directory with the given storage ('mcap' or 'sqlite3'); the side files are
    ``<output>.truth.yaml``, ``<output>.prior.yaml`` and ``<output>.schedule.yaml``.
    ``compression='zstd'`` shrinks the log ~8x for ~50% more write time; ``overrides`` are
    passed to ``simulate``; ``transform`` (SimRecording -> SimRecording, e.g.
    ``sim_proxy.with_resonance_proxy``) edits the recording before it is written. Returns
    the paths and a summary dict.
    """
    from .io.bag import write_columns   # imported here: the simulator works without it

    t_start = time.perf_counter()
    rec = simulate(name, seed, **overrides)
    if transform is not None:
        rec = transform(rec)
    out = os.fspath(output).rstrip(os.sep)
    parent = os.path.dirname(os.path.abspath(out))
    os.makedirs(parent, exist_ok=True)
    cfg = rec.config
    var = cfg.temp_noise ** 2 + cfg.temp_lsb ** 2 / 12
    var = {t: rec.meta.get('temperature_variance', {}).get(t, var) for t in rec.temperatures}
    counts = write_columns(out, rec.imu_topic, rec.imu_chunks(), rec.temperatures,
                           storage=storage, overwrite=overwrite, compression=compression,
                           temperature_variance=var)
    paths = {'bag': out, 'truth': _sidecar(out, 'truth'), 'prior': _sidecar(out, 'prior'),
             'schedule': _sidecar(out, 'schedule')}
    rec.truth.save(paths['truth'])
    rec.prior.save(paths['prior'])
    with open(paths['schedule'], 'w') as f:
        yaml.safe_dump(rec.schedule_dict(), f, sort_keys=False, default_flow_style=None,
                       width=100)
    summary = rec.summary()
    summary['messages'] = counts
    summary['seconds'] = round(time.perf_counter() - t_start, 3)
    return {**paths, 'summary': summary}


def still_noise(n, rate_hz, density, random_walk=0.0, seed=0):
    """Return (n, 3) white noise plus a random-walk bias, as a still sensor's error.

    ``density`` N is the one-sided white-noise density (unit/sqrt(Hz): per-sample std
    N sqrt(rate)); ``random_walk`` K is the bias random walk (unit/s/sqrt(Hz): the bias
    moves by K sqrt(dt) per sample). Scalars or per-axis (3,) values. The Allan variance
    of the result is N^2/tau + K^2 tau/3 (IEEE 952), what ``estimation.allan`` reads back.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / float(rate_hz)
    white = rng.standard_normal((n, 3)) * (np.asarray(density, float) / np.sqrt(dt))
    walk = np.cumsum(rng.standard_normal((n, 3)), axis=0) * (
        np.asarray(random_walk, float) * np.sqrt(dt))
    return white + walk


from .sim_scenarios import SCENARIOS as _MORE  # noqa: E402 (needs ScenarioConfig above)
SCENARIOS.update(_MORE)
