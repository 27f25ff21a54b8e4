"""A simulated device with errors outside every model family (tests that the fit can fail).

``sim.simulate`` generates data with the field polynomial (seed 000 eq. 8) and the seed 002
gyro: the very models the estimators fit, so a test on it can never see what a real device
adds. ``with_unmodelled(rec)`` returns the same recording with, on top, additive errors no
model family describes (``Unmodelled`` holds their sizes, SI units):

* cubic drift: ``b3 (T - T0)^3`` on every accel and gyro axis;
* a second thermal time constant: ``b_slow (T_slow - T)`` where ``T_slow`` is the
  error-driving temperature through a further first-order lag of ``tau_slow`` seconds (the
  package and board heat more slowly than the die);
* per-axis temperature offsets: axis i sees ``T + kappa_i dT/dt`` (a gradient across the
  die while the temperature moves), through the device's own polynomial;
* bias hysteresis: ``h tanh((dT/dt) / rate0)``, a heating/cooling difference;
* 1/f bias wander: pink noise (power ~ 1/f, 1 s grid) of standard deviation ``pink_std``.

Everything is deterministic per ``(seed, scenario)``; ``rec.meta['unmodelled']`` records the
sizes. ``unmodelled_error(rec, stamps)`` returns the added accel error (the truth a test
compares against).
"""

import dataclasses

import numpy as np

from .devices import _rng, accel_forward
from .schedule import first_order_lag


@dataclasses.dataclass(frozen=True)
class Unmodelled:
    """Sizes of the unmodelled effects (0 turns one off). Defaults: a MEMS-class device."""

    accel_b3: float = 3e-6        # m/s^2/degC^3
    gyro_b3: float = 3e-8         # rad/s/degC^3
    tau_slow_s: float = 300.0     # s, second thermal time constant
    accel_b_slow: float = 4e-3    # m/s^2 per degC of (T_slow - T)
    gyro_b_slow: float = 4e-5     # rad/s per degC
    kappa_s: tuple = (20.0, -15.0, 30.0)   # s, per-axis temperature offset per degC/s
    accel_hysteresis: float = 3e-3   # m/s^2 at |dT/dt| >> rate0
    gyro_hysteresis: float = 3e-5    # rad/s
    rate0: float = 0.05              # degC/s
    accel_pink_std: float = 2e-3     # m/s^2
    gyro_pink_std: float = 2e-5      # rad/s


def _pink(rng, n, std):
    """Return n samples of 1/f noise (unit-spaced) scaled to standard deviation ``std``."""
    if std <= 0 or n < 4:
        return np.zeros(n)
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n)
    f[0] = f[1]
    x = np.fft.irfft(spec / np.sqrt(f), n)
    x -= x.mean()
    return std * x / x.std()


class _Effects:
    """The unmodelled errors of one recording on a 1 s grid, evaluated per truth chunk."""

    def __init__(self, rec, u):
        self.rec, self.u = rec, u
        dt = 1.0
        self.tg = np.arange(0.0, rec.duration + 2 * dt, dt)
        drive = rec._thermal.at(self.tg, 'drive')                # (m, k)
        idx = rec.truth.accel_input
        t_ax = drive[:, idx]                                       # (m, 3) per axis
        self.t_ax = t_ax
        self.slow = np.stack([first_order_lag(t_ax[:, i], dt, u.tau_slow_s)
                              for i in range(3)], 1) - t_ax
        self.rate = np.gradient(t_ax, dt, axis=0)                 # degC/s
        rng = _rng(rec.seed, 'recording', rec.config.name, 'unmodelled')
        m = self.tg.size
        self.pink_a = np.stack([_pink(rng, m, u.accel_pink_std) for _ in range(3)], 1)
        self.pink_g = np.stack([_pink(rng, m, u.gyro_pink_std) for _ in range(3)], 1)

    def _at(self, t, grid):
        return np.stack([np.interp(t, self.tg, grid[:, i]) for i in range(3)], 1)

    def accel(self, t, f):
        """Return the added accel error (n, 3) at times t (s) under specific force f."""
        u, dev = self.u, self.rec.device
        ta = self._at(t, self.t_ax)
        rate = self._at(t, self.rate)
        d = ta - dev.t0
        gradient = (accel_forward(f, ta + np.asarray(u.kappa_s) * rate, dev.t0, dev.k0,
                                  dev.b0, dev.s, dev.thermal)
                    - accel_forward(f, ta, dev.t0, dev.k0, dev.b0, dev.s, dev.thermal))
        return (u.accel_b3 * d ** 3 + u.accel_b_slow * self._at(t, self.slow) + gradient
                + u.accel_hysteresis * np.tanh(rate / u.rate0) + self._at(t, self.pink_a))

    def gyro(self, t):
        """Return the added gyro error (n, 3) at times t (s)."""
        u, dev = self.u, self.rec.device
        ta = self._at(t, self.t_ax)
        rate = self._at(t, self.rate)
        return (u.gyro_b3 * (ta - dev.t0) ** 3 + u.gyro_b_slow * self._at(t, self.slow)
                + u.gyro_hysteresis * np.tanh(rate / u.rate0) + self._at(t, self.pink_g))

    def __call__(self, tc):
        t = (tc.stamp_ns - self.rec.start_ns) * 1e-9
        return self.accel(t, tc.specific_force), self.gyro(t)


def with_unmodelled(rec, u=None):
    """Return a copy of ``rec`` (a ``SimRecording``) with the ``Unmodelled`` errors added."""
    u = Unmodelled() if u is None else u
    out = dataclasses.replace(rec, meta={**rec.meta, 'unmodelled': dataclasses.asdict(u)})
    out.extra_error = _Effects(out, u)
    return out


def unmodelled_error(rec, chunk_size=None):
    """Return (stamps, accel error (n, 3), gyro error (n, 3)) the recording's effects add."""
    stamps, da, dg = [], [], []
    for tc in rec.truth_chunks(chunk_size):
        a, g = rec.extra_error(tc)
        stamps.append(tc.stamp_ns)
        da.append(a)
        dg.append(g)
    return np.concatenate(stamps), np.concatenate(da), np.concatenate(dg)
