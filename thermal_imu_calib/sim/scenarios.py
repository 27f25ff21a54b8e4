"""Simulated sessions that fail the way real recordings did (registered in ``sim.SCENARIOS``).

* ``hand-held``: a consumer MEMS unit held by hand, 1-6 s rests with tremor (rotation-rate
  RMS ``tremor_dps``), pose changes between them, some of them pure turns about gravity
  (the same face twice in a row: only the heading changes);
* ``imutk-procedure``: the imu_tk procedure, a 50 s initial rest then 40 short rests
  (1-4 s) on the six faces and tilted (corner-up) poses, no temperature change to speak of;
* ``chamber-2hz``: one pose in a climate chamber, -20..75 degC at 1 degC/min with dwells,
  the errors following the temperature through a 300 s lag (hysteresis), logged at 2 Hz.

Every sensor is quantised like a 16-bit part: the ``mems`` device's accel (+-4 g) and gyro
(+-500 deg/s) LSBs, and the temperature at 1/512 degC (BMI270 / ICM class).
"""

import numpy as np

from .devices import _rng
from .schedule import ScenarioConfig, SIX_FACES, TILTED

#: temperature LSB of a 16-bit die-temperature register, degC
TEMP_LSB_16BIT = 1.0 / 512.0
#: tremor: three sinusoids per axis between these frequencies, Hz
TREMOR_HZ = (3.0, 9.0)

_HAND = ('+z', '+z', '-z', '+x', '+x', '-x', '+y', '-y', TILTED, TILTED)
_IMUTK = (SIX_FACES + (TILTED,) * 3) * 4 + ('+z', '-z', TILTED, '+x')

SCENARIOS = {
    'hand-held': ScenarioConfig(
        name='hand-held', device='mems', imu_rate=100.0,
        description='hand-held MEMS session: 3 x 10 poses held 1-6 s with 1 deg/s tremor, '
                    '0.8-2 s pose changes (some only turn about gravity), 16-bit sensors',
        faces=_HAND, repetitions=3, hold_s=(1.0, 6.0), transition_s=(0.8, 2.0),
        tilt_deg=(0.5, 5.0), t_amb=22.0, rise=4.0, tau_s=600.0, temp_rate=10.0,
        temp_lsb=TEMP_LSB_16BIT, temp_noise=0.01, tremor_dps=1.0),
    'imutk-procedure': ScenarioConfig(
        name='imutk-procedure', device='mems', imu_rate=100.0,
        description='imu_tk procedure: 50 s initial rest, then 39 rests of 1-4 s (six faces '
                    'and tilted corner-up poses), 1-2 s pose changes, 16-bit sensors',
        faces=_IMUTK, repetitions=1, hold_s=(1.0, 4.0), transition_s=(1.0, 2.0),
        initial_hold_s=50.0, tilt_deg=(0.5, 5.0), t_amb=22.0, rise=2.0, tau_s=900.0,
        temp_rate=10.0, temp_lsb=TEMP_LSB_16BIT, temp_noise=0.01, tremor_dps=0.3),
    'chamber-2hz': ScenarioConfig(
        name='chamber-2hz', device='mems', imu_rate=2.0,
        description='one pose in a climate chamber logged at 2 Hz (flight-stack log): '
                    '-20..75 degC at 1 degC/min with 10-min dwells, errors through a 300-s '
                    'lag (hysteresis), 16-bit sensors',
        faces=('+z',), repetitions=1, tilt_deg=(0.2, 1.0), profile='cycle', cycle_lo=-20.0,
        cycle_hi=75.0, ramp_degc_per_min=1.0, dwell_s=600.0, cycles=1, case_tau_s=60.0,
        lag_s=300.0, temp_rate=2.0, temp_lsb=TEMP_LSB_16BIT, temp_noise=0.01),
}


def tremor(rec, tc, accel, gyro):
    """Add hand tremor to raw samples of one chunk; returns (accel, gyro).

    A small body rotation theta(t) (three sinusoids per axis in ``TREMOR_HZ``, scaled so
    the rate RMS is ``tremor_dps``): the gyro sees d theta / dt, the accelerometer the
    specific force turned by theta (f - theta x f). Deterministic per seed and time.
    """
    rng = _rng(rec.seed, 'recording', rec.config.name, 'tremor')
    freq = rng.uniform(*TREMOR_HZ, (3, 3))
    phase = rng.uniform(0, 2 * np.pi, (3, 3))
    t = (tc.stamp_ns - rec.start_ns) * 1e-9
    w = 2 * np.pi * freq                                  # (axis, component)
    arg = w[None] * t[:, None, None] + phase[None]
    # rate amplitude per component so that the rate RMS over the three axes is tremor_dps
    amp = np.radians(rec.config.tremor_dps) / np.sqrt(3 * 3 / 2)
    theta = np.sum(amp / w[None] * np.sin(arg), axis=2)   # (n, 3) rad
    rate = np.sum(amp * np.cos(arg), axis=2)              # (n, 3) rad/s
    f = tc.specific_force
    return accel - np.cross(theta, f), gyro + rate
