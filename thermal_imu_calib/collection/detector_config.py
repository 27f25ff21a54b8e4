"""Stationary detector settings: the ones given, the ones derived from the log itself.

Nothing needs tuning: from the first samples of a log (``stationary.DERIVE_SAMPLES``) the
detector measures the sample rate and the quantisation step (LSB) of each sensor, and
``DetectorConfig.derive`` turns them into

* the *block*: ``block_n`` samples (about ``BLOCK_TARGET_S``, at least ``MIN_BLOCK_N``), so
  a 1 Hz chamber log and a 2 kHz IMU both get blocks with a defined variance;
* minimum hold, guard and window lengths from the block length (a 1 s hold at >= 50 Hz);
* variance factors from the chi-square spread of a block variance with that many samples
  (``BLOCK_FALSE_ALARM``, ``VARIANCE_MARGIN``), applied by the detector to its noise floor.

Settings given explicitly (not None / 0) are kept. ``format_settings`` renders what was
derived for people.
"""

import dataclasses
from dataclasses import dataclass
from typing import Optional

import numpy as np

#: target block duration (s) and fewest samples per block
BLOCK_TARGET_S = 0.1
MIN_BLOCK_N = 5
#: a still block's variance stays below its chi-square quantile (1 - BLOCK_FALSE_ALARM)
#: times VARIANCE_MARGIN (non-white noise, tremor) times the noise floor
BLOCK_FALSE_ALARM = 1e-3
VARIANCE_MARGIN = 3.0
#: the settings derived from the log when not given (None, or 0 but for guard_s)
DERIVED = ('block_s', 'window_s', 'min_hold_s', 'guard_s', 'accel_factor', 'gyro_factor')


class DetectorSettingsError(ValueError):
    """The settings derived from the IMU's sample rate are out of range (implausible stamps)."""


@dataclass
class DetectorConfig:
    """Stationary detector settings (seconds, dimensionless factors); None or 0: derived."""

    block_s: Optional[float] = None
    window_s: Optional[float] = None
    min_hold_s: Optional[float] = None
    guard_s: Optional[float] = None
    accel_factor: Optional[float] = None
    gyro_factor: Optional[float] = None
    mean_sigmas: float = 6.0
    noise_quantile: float = 0.05
    #: rotation rate (deg/s) below which the unit counts as held (hand tremor, slow drift)
    rotation_dps: float = 3.0
    #: absolute floors for the noise estimate (quantised sensors can read exactly constant)
    min_accel_var: float = 1e-10
    min_gyro_var: float = 1e-12

    def validate(self):
        """Raise ValueError with the offending field when a setting is out of range."""
        checks = [('block_s', 0.001, 60), ('window_s', 0.01, 3600), ('min_hold_s', 0.05, 36000),
                  ('guard_s', 0.0, 600), ('accel_factor', 1.0, 1e4), ('gyro_factor', 1.0, 1e4),
                  ('mean_sigmas', 1.0, 1000), ('noise_quantile', 0.001, 0.9),
                  ('rotation_dps', 0.001, 100)]
        for name, lo, hi in checks:
            v = getattr(self, name)
            if v is None or (name in DERIVED and v == 0 and name != 'guard_s'):
                continue
            if not lo <= v <= hi:
                raise ValueError(f'detector {name}={v} is outside [{lo}, {hi}]')
        if self.window_s and self.block_s and self.window_s < self.block_s:
            raise ValueError(f'window_s ({self.window_s}) must be >= block_s ({self.block_s})')

    def derive(self, rate_hz, accel_lsb=0.0, gyro_lsb=0.0):
        """Return (resolved DetectorConfig, block_n) for a log at ``rate_hz``."""
        given = {k: v for k, v in vars(self).items() if v is not None and
                 not (k in DERIVED and k != 'guard_s' and v == 0)}
        if 'block_s' in given:
            block_n = max(3, int(round(given['block_s'] * rate_hz)))
        else:
            block_n = max(MIN_BLOCK_N, int(round(BLOCK_TARGET_S * rate_hz)))
        block_s = block_n / rate_hz
        dof = 3 * (block_n - 1)
        factor = VARIANCE_MARGIN * float(chi2_ppf(1 - BLOCK_FALSE_ALARM, dof)
                                         / chi2_ppf(self.noise_quantile, dof))
        auto = {'block_s': block_s, 'min_hold_s': max(0.5, 5 * block_s),
                'guard_s': max(0.2, 2 * block_s), 'window_s': max(5.0, 2 * block_s),
                'accel_factor': factor, 'gyro_factor': factor}
        auto.update({k: v for k, v in given.items() if k in DERIVED})
        auto['window_s'] = max(auto['window_s'], block_s)
        return dataclasses.replace(self, **auto), block_n


def chi2_ppf(p, dof):
    """Return the chi-square quantile at ``p`` with ``dof`` degrees of freedom.

    What ``scipy.stats.chi2.ppf`` computes (``2 gammaincinv(dof/2, p)``, the same float),
    without importing scipy.stats (about 0.3 s of start-up); scipy.special itself is
    imported here, not with the module (another 0.5 s for a node that never derives a
    detector setting, e.g. the compensator).
    """
    from scipy.special import gammaincinv
    return 2 * gammaincinv(dof / 2, p)


def quantisation_step(x):
    """Return the LSB of each column (0 when the values are not on a regular grid)."""
    x = np.asarray(x, float)
    out = np.zeros(x.shape[1])
    for i in range(x.shape[1]):
        d = np.abs(np.diff(x[:, i]))
        d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(x[:, i]))))]
        if len(d) < 3:
            continue
        q = float(np.min(d))
        ratio = d / q
        if np.median(np.abs(ratio - np.round(ratio))) < 0.02:
            out[i] = q
    return out


def format_settings(settings):
    """Render derived detector settings (``StationaryDetector.settings``) in one line."""
    if not settings:
        return 'detector: no data'
    s = settings
    given = set(s.get('given', []))

    def mark(k):
        return '' if k in given else '*'

    pairs = (('accel', 'accel_lsb'), ('gyro', 'gyro_lsb'))
    lsb = ', '.join(f'{name} LSB {s[k]:.3g}' for name, k in pairs if s.get(k))
    noise = ''
    if 'accel_noise_std' in s:
        noise = (f', noise floor {s["accel_noise_std"]:.3g} m/s^2 / '
                 f'{s["gyro_noise_std"]:.3g} rad/s')
    return (f'detector ({s["rate_hz"]:.4g} Hz{", " + lsb if lsb else ""}{noise}): block '
            f'{s["block_samples"]} samples = {s["block_s"]:.3g} s{mark("block_s")}, min hold '
            f'{s["min_hold_s"]:.3g} s{mark("min_hold_s")}, guard {s["guard_s"]:.3g} s'
            f'{mark("guard_s")}, window {s["window_s"]:.3g} s{mark("window_s")}, variance '
            f'factors {s["accel_factor"]:.3g}{mark("accel_factor")}/{s["gyro_factor"]:.3g}'
            f'{mark("gyro_factor")}, rotation {s["rotation_dps"]:g} deg/s  (* derived)')
