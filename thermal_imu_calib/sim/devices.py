"""Simulated devices: IMU families, their true thermal parameters and forward models.

A device (true thermal parameters, lab prior, per-sensor warm-up shape) is drawn
from ``(seed, device family)`` (``draw_device``), so two scenarios with the same
seed see one and the same IMU. Forward models (body frame = accelerometer
reference frame p):

* accelerometer, seed 000 eq. (8), written out independently of ``models.field``::

      raw_i = b0_i + db0_i + b1_i dT_i + b2_i dT_i^2
              + (k0_i + dk0_i + k1_i dT_i + k2_i dT_i^2) (S f^p)_i + noise

* gyro, seed 002 eq. (3)-(4) written forward: raw = M w^b + G f^p + sum_j c_j dT^j
  + noise, M = I + scale errors + misalignment, G the g-sensitivity
  (rad/s per m/s^2); the 'nav' family has M = I, G = 0.

White noise per sample is density * sqrt(rate) (one-sided density in unit/sqrt(Hz)).
"""

import zlib
from dataclasses import dataclass, field

import numpy as np

from ..models.polynomial import OffsetPolynomialModel
from ..models.whole_unit import WholeUnitGyroModel


G0 = 9.80665                 # m/s^2 per g, to convert datasheet densities
EARTH_RATE = 7.2921150e-5    # rad/s, WGS84
DEG = np.pi / 180.0


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
