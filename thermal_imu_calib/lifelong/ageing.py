"""Gyro bias ageing in a lifelong collection: a trend in time, told apart from temperature.

A robot's stops span weeks. The gyro bias ages (a slow trend), and the season moves the
temperature the same way, so an offset model fitted to weeks of stops takes part of the
ageing for a temperature slope, and centres its constant on the collection's mean age
instead of today. ``trend`` estimates per axis the ageing rate jointly with a cubic in the
first thermal input (the nuisance), by sample-weighted least squares over the fit's windows
at their mean times (a compacted bin at its sample-weighted mean time), with a standard
error clustered by hold (the windows of one hold share its heading's earth rate and its
state). ``detrended`` moves every window's gyro mean to the time ``now`` along the rates
that are resolved (more than ``RESOLVED_SIGMAS`` standard errors). The lifelong estimate
fits with and without it and keeps the detrended fit only when the held-out holds say it
is better by more than their noise, the swap gate's rule (``variants.with_ageing``).
Units: rad/s, s; rates in rad/s per day. No ROS import.
"""

from dataclasses import dataclass, replace

import numpy as np

from ..calibration.base import DAY_S
#: a rate is applied only when it is this many standard errors from zero
RESOLVED_SIGMAS = 2.0
#: fewer holds than this: no trend is estimated
MIN_HOLDS = 10
#: a shorter span (days): no trend is estimated. Within a day or two, time and the diurnal
#: temperature cycle move together, and any misfit of the thermal model reads as a trend
MIN_SPAN_DAYS = 2.0


@dataclass
class Trend:
    """Per-axis gyro ageing rate (rad/s per day) and its standard error, and what it used."""

    rate: np.ndarray
    std: np.ndarray
    holds: int
    span_days: float

    @property
    def resolved(self):
        """Return the (3,) mask of the axes whose rate is resolved."""
        return np.abs(self.rate) > RESOLVED_SIGMAS * self.std

    @property
    def applied(self):
        """Return the rates that are applied, rad/s per day: resolved axes only, else 0."""
        return np.where(self.resolved, self.rate, 0.0)

    def text(self):
        """Return the rates for a decision log (mdeg/s per day)."""
        r = np.degrees(self.rate) * 1e3
        s = np.degrees(self.std) * 1e3
        axes = ', '.join(f'{a} {v:+.2f} +- {e:.2f}{"" if ok else " (not resolved)"}'
                         for a, v, e, ok in zip('xyz', r, s, self.resolved))
        return (f'gyro ageing {axes} mdeg/s per day over {self.holds} holds, '
                f'{self.span_days:.1f} days')


def trend(windows, times, now):
    """Return the gyro ``Trend`` of windows at mean ``times`` (s), or None when too little.

    The design is [1, x, x^2, x^3, (t - now) / day] per axis (x: the first thermal input,
    centred and scaled; without one, [1, (t - now) / day]), weighted by the window's
    samples. The standard error is the hold-clustered sandwich estimate.
    """
    if not len(windows):
        return None
    holds = windows.hold
    ids, hold_index = np.unique(holds, return_inverse=True)
    tau = (np.asarray(times, float) - now) / DAY_S
    if len(ids) < MIN_HOLDS or np.ptp(tau) < MIN_SPAN_DAYS:
        return None
    cols = [np.ones(len(tau))]
    if windows.n_inputs:
        temp = windows.temp[:, 0]
        scale = max(float(np.std(temp)), 1e-6)
        x = (temp - float(np.mean(temp))) / scale
        cols += [x, x ** 2, x ** 3]
    cols.append(tau)
    a = np.stack(cols, 1)
    w = windows.n.astype(float)
    sw = np.sqrt(w)[:, None]
    aw = a * sw
    bread = np.linalg.pinv(aw.T @ aw)
    coef = bread @ (aw.T @ (windows.gyro * sw))             # (p, 3)
    resid = windows.gyro - a @ coef                          # (n, 3)
    rate, std = coef[-1], np.zeros(3)
    p = a.shape[1]
    g = len(ids)
    for j in range(3):
        # per hold: sum of w a r (the score); the sandwich with the small-sample factor
        score = np.zeros((g, p))
        np.add.at(score, hold_index, a * (w * resid[:, j])[:, None])
        meat = score.T @ score * g / max(g - 1, 1)
        std[j] = np.sqrt(max((bread @ meat @ bread)[-1, -1], 0.0))
    return Trend(rate, std, g, float(np.ptp(tau)))


def detrended(windows, times, now, found):
    """Return the windows with their gyro means moved to ``now`` along the resolved rates."""
    tau = (np.asarray(times, float) - now) / DAY_S
    return replace(windows, gyro=windows.gyro - tau[:, None] * found.applied[None, :])
