"""Noise model from still data: overlapping Allan deviation and its IEEE-952 terms.

Per axis the overlapping Allan deviation (``allantools.oadev``, rate data) is computed on
log-spaced cluster times tau. The Allan variance of the usual noise terms is::

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

(quantisation Q, white noise N, bias instability B, random walk K, rate ramp R). Q, N, K
and R are fitted at once by non-negative weighted least squares on AVAR (relative weights
from the number of independent clusters), so each asymptote is a *fitted* line; B is not
fitted (its flat term would take variance from N and K: on 2-h simulated records K comes
out 4 % low with it, unbiased without):

* white noise ``N`` is read at tau = 1 s on the fitted slope -1/2 line (``N / sqrt(tau)``);
* random walk ``K`` is read at tau = 3 s on the fitted slope +1/2 line (``K sqrt(tau/3)``);
* bias instability ``B`` is the flat minimum of the measured deviation divided by 0.664
  (sqrt(2 ln2 / pi)), reported with the tau of that minimum.

Units (SI, one-sided densities): accelerometer N in m/s^2/sqrt(Hz), K in m/s^3/sqrt(Hz),
B in m/s^2; gyro N in rad/s/sqrt(Hz), K in rad/s^2/sqrt(Hz), B in rad/s. A per-sample
white-noise std at rate f is ``N sqrt(f)``.

Samples from several stationary holds (a calibration log) are combined by averaging the
Allan variances of the holds at each tau, weighted by their number of clusters.
"""

from dataclasses import dataclass

import numpy as np

#: sqrt(2 ln2 / pi): the flat floor of the Allan deviation of bias instability B
BIAS_INSTABILITY_FACTOR = 0.664
#: tau (s) at which white noise N and random walk K are read on their fitted lines
TAU_N, TAU_K = 1.0, 3.0
#: K is reported only when the data reach this multiple of the N/K crossover tau
K_REACH = 3.0
UNITS = {
    'accel': {'N': 'm/s^2/sqrt(Hz)', 'K': 'm/s^3/sqrt(Hz)', 'B': 'm/s^2', 'adev': 'm/s^2'},
    'gyro': {'N': 'rad/s/sqrt(Hz)', 'K': 'rad/s^2/sqrt(Hz)', 'B': 'rad/s', 'adev': 'rad/s'},
}


@dataclass
class AllanCurve:
    """Allan deviation of one axis: tau (s), deviation (sensor unit) and cluster counts."""

    tau: np.ndarray
    adev: np.ndarray
    #: number of independent (non-overlapping) clusters behind each point, summed over holds
    clusters: np.ndarray


@dataclass
class AxisNoise:
    """The noise terms of one axis read off its Allan deviation (SI units, see module)."""

    N: float
    K: float
    B: float
    tau_B: float
    #: fitted coefficients (Q, N, 0, K, R) of the AVAR model (B is read, not fitted)
    coeffs: np.ndarray
    curve: AllanCurve
    #: False when the data are too short to see the random-walk slope (K not reported)
    k_observable: bool

    def model_adev(self, tau):
        """Return the fitted Allan deviation at ``tau`` (s)."""
        return np.sqrt(_design(np.asarray(tau, float)) @ self.coeffs ** 2)

    def line_n(self, tau):
        """Return the fitted slope -1/2 line N / sqrt(tau)."""
        return self.N / np.sqrt(np.asarray(tau, float))

    def line_k(self, tau):
        """Return the fitted slope +1/2 line K sqrt(tau / 3)."""
        return self.K * np.sqrt(np.asarray(tau, float) / 3.0)


def log_taus(rate_hz, n, per_decade=12, max_fraction=0.1):
    """Return log-spaced cluster sizes m (samples) from 1 up to ``max_fraction`` of n."""
    top = max(int(n * max_fraction), 1)
    m = np.unique(np.round(np.logspace(0, np.log10(top), max(
        int(np.log10(top) * per_decade) + 1, 2))).astype(int))
    return m[m >= 1]


def allan_curve(segments, rate_hz, per_decade=12, max_fraction=0.1):
    """Return the overlapping Allan deviation of one axis over one or more still segments.

    ``segments`` is a list of 1-D arrays (samples at ``rate_hz``, sensor unit); each must be
    continuous. The Allan variances of the segments are averaged per tau, weighted by their
    cluster counts; a tau is kept only where some segment has >= 2 clusters.
    """
    import allantools
    segments = [np.asarray(s, float) for s in segments if len(s) >= 8]
    if not segments:
        raise ValueError('no still segment of at least 8 samples to compute an Allan deviation')
    longest = max(len(s) for s in segments)
    m_all = log_taus(rate_hz, longest, per_decade, max_fraction)
    num = np.zeros(len(m_all))
    den = np.zeros(len(m_all))
    for s in segments:
        m_ok = m_all[m_all <= max(len(s) * max_fraction, 1)]
        if not len(m_ok):
            continue
        tau, dev, _, _ = allantools.oadev(s, rate=rate_hz, data_type='freq', taus=m_ok / rate_hz)
        idx = np.searchsorted(m_all, np.round(np.asarray(tau) * rate_hz).astype(int))
        idx = np.clip(idx, 0, len(m_all) - 1)
        w = np.floor(len(s) / m_all[idx])
        num[idx] += w * np.asarray(dev) ** 2
        den[idx] += w
    keep = den >= 2
    return AllanCurve(m_all[keep] / rate_hz, np.sqrt(num[keep] / den[keep]), den[keep])


def _design(tau):
    tau = np.asarray(tau, float)
    return np.stack([3.0 / tau ** 2, 1.0 / tau, np.full_like(tau, 2 * np.log(2) / np.pi),
                     tau / 3.0, tau ** 2 / 2.0], axis=-1)


def fit_curve(curve):
    """Fit the five-term AVAR model to a curve and read N, K, B; returns AxisNoise."""
    from scipy.optimize import nnls
    avar = curve.adev ** 2
    # relative std of an AVAR point ~ 1/sqrt(independent clusters); floor for the
    # shortest taus, where the overlap makes the count optimistic
    rel = np.sqrt(1.0 / np.maximum(curve.clusters - 1, 1) + 1e-4)
    cols = [0, 1, 3, 4]
    a = _design(curve.tau)[:, cols] / (avar * rel)[:, None]
    scale = np.abs(a).max(0)
    scale[scale == 0] = 1
    x, _ = nnls(a / scale, 1.0 / rel)
    coeffs = np.zeros(5)
    coeffs[cols] = np.sqrt(np.maximum(x / scale, 0))
    n, k = float(coeffs[1]), float(coeffs[3])
    i = int(np.argmin(curve.adev))
    observable = bool(k > 0 and n > 0 and curve.tau.max() >= K_REACH * np.sqrt(3) * n / k)
    return AxisNoise(N=n, K=k if observable else float('nan'),
                     B=float(curve.adev[i] / BIAS_INSTABILITY_FACTOR), tau_B=float(curve.tau[i]),
                     coeffs=coeffs, curve=curve, k_observable=observable)


def noise_model(accel_segments, gyro_segments, rate_hz, **kw):
    """Return {'accel': [AxisNoise x3], 'gyro': [AxisNoise x3]} for (n_i, 3) still segments."""
    out = {}
    for name, segs in (('accel', accel_segments), ('gyro', gyro_segments)):
        segs = [np.asarray(s, float).reshape(-1, 3) for s in segs]
        out[name] = [fit_curve(allan_curve([s[:, j] for s in segs], rate_hz, **kw))
                     for j in range(3)]
    return out


def worst(axes, key):
    """Return the largest finite value of ``key`` over the axes (NaN when none is finite)."""
    vals = np.array([getattr(a, key) for a in axes], float)
    vals = vals[np.isfinite(vals)]
    return float(vals.max()) if len(vals) else float('nan')


def white_density(var, rate_hz):
    """Return the white-noise density N (unit/sqrt(Hz)) of a per-sample variance at a rate."""
    return np.sqrt(np.asarray(var, float) / float(rate_hz))


def window_noise(windows):
    """Return the white-noise part of the noise model from window statistics.

    N per axis = sqrt(median within-window variance) / sqrt(rate), rate from the windows'
    sample counts; ``rate_hz`` is stored with it. No random walk: windows are too short to
    show it (``noise.add_random_walk`` adds K from the raw holds of a long log).
    """
    if not len(windows):
        return {}
    dur = windows.t1 - windows.t0
    ok = (dur > 0) & (windows.n > 1)
    if not ok.any():
        return {}
    rate = float(np.median((windows.n[ok] - 1) / dur[ok]))
    return {'accel_noise_density': white_density(np.median(windows.accel_var, axis=0), rate),
            'gyro_noise_density': white_density(np.median(windows.gyro_var, axis=0), rate),
            'rate_hz': round(rate, 3)}
