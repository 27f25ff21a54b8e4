"""The standard method, in the bench and independent of the package: imu_tk's detector and fit.

Followed (BSD, Pretto et al., read from the sources, re-implemented here in numpy/scipy):

* ``staticIntervalsDetector`` (imu_tk ``src/filters.cpp``): for every sample i with a full
  centred window of ``win_size`` samples (odd, >= 11), the per-axis accel variance over
  [i - h, i + h] (``dataVariance``: n - 1); a still interval starts at the first i whose
  variance-vector norm is below the threshold and ends at the first i where it is not; an
  interval still open at the end ends at n - h - 1.
* the threshold (``MultiPosCalibration::calibrateAcc``, ``src/calibration.cpp``): a multiple
  ``th_mult`` of the norm of the accel variance over the initial still period
  (``DataInterval::initialInterval(samples, init_interval_duration_)``);
  ``extractIntervalsSamples`` (``include/imu_tk/base.h``) keeps intervals of at least
  ``interval_n_samples`` samples.
* the accelerometer model (``CalibratedTriad::unbiasNormalize`` with the lower misalignment
  terms zero, as ``MultiPosAccResidual``): calibrated = T K (raw - b),
  T = [[1, -yz, zy], [0, 1, -zx], [0, 0, 1]], K = diag(sx, sy, sz); residual g - |T K (a - b)|.

Settings used here (fixed for every recording, chosen before looking at any score): the
GetOverMassif fork's window for its ROS 2 sessions (``config/config_1.yaml``: win_size 51);
an initial still period of 5 s (the fork's config says 6.0 s, but two of its sessions are
still for only 5.1 and 5.8 s: 6 s lets the first motion into the reference variance); one
threshold multiplier, 4, the one imu_tk itself fixes where it does not search
(``apps/test_phone_calib.cpp``: ``staticIntervalsDetector(acc, 4*variance.norm(), ...)``),
instead of ``calibrateAcc``'s search for the least fit cost over 2..10, which would make
the scorer depend on a fit; and intervals of at least 25 samples (half the window;
imu_tk's ``interval_n_samples_`` of 100 would keep none of data1's ~1.1 s rests once the
51-sample window has eaten into both ends).

Differences from imu_tk kept on purpose: the fit is to one mean per interval (imu_tk fits
the first 100 samples of each), so every interval weighs the same as in the score.
"""

import numpy as np
from scipy.optimize import least_squares

UG = 9.80665e-6      # m/s^2 per micro-g
WIN_SIZE = 51
INIT_S = 5.0
TH_MULT = 4.0
MIN_SAMPLES = 25


def moving_variance(x, win):
    """Per-axis sample variance (n - 1) over centred windows of ``win``; (n - win + 1, 3)."""
    c = np.cumsum(np.vstack([np.zeros((1, 3)), x - x.mean(0)]), axis=0)
    c2 = np.cumsum(np.vstack([np.zeros((1, 3)), (x - x.mean(0)) ** 2]), axis=0)
    s, s2 = c[win:] - c[:-win], c2[win:] - c2[:-win]
    return (s2 - s * s / win) / (win - 1)


def detect_static(t, accel, win_size=WIN_SIZE, init_s=INIT_S, th_mult=TH_MULT,
                  min_samples=MIN_SAMPLES):
    """imu_tk-style still intervals of ``accel`` (n, 3) at times ``t`` (s from the first).

    Returns (start, end) sample index ranges, end exclusive (imu_tk's end_idx, the first
    index that is not still), of intervals with at least ``min_samples`` samples.
    """
    accel = np.asarray(accel, float)
    win_size = max(int(win_size), 11)
    win_size += 1 - win_size % 2
    h = win_size // 2
    n = len(accel)
    if win_size >= n:
        return []
    init = accel[t <= t[0] + init_s]
    th = th_mult * np.linalg.norm(init.var(0, ddof=1))
    norm = np.linalg.norm(moving_variance(accel, win_size), axis=1)   # at i = h .. n-h-1
    still = norm < th
    edges = np.diff(np.r_[0, still.astype(np.int8), 0])
    starts, ends = np.flatnonzero(edges == 1) + h, np.flatnonzero(edges == -1) + h
    if len(ends) and ends[-1] == n - h:            # open at the end: imu_tk ends at n-h-1
        ends[-1] = n - h - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends) if b - a + 1 >= min_samples]


def misalignment(p):
    """imu_tk's accelerometer T from (yz, zy, zx)."""
    yz, zy, zx = p
    return np.array([[1.0, -yz, zy], [0.0, 1.0, -zx], [0.0, 0.0, 1.0]])


def apply_params(p, accel):
    """calibrated = T K (raw - b) for the 9 parameters (yz, zy, zx, sx, sy, sz, bx, by, bz)."""
    return (misalignment(p[:3]) @ (np.diag(p[3:6]) @ (np.asarray(accel) - p[6:9]).T)).T


def fit_standard(means, g):
    """Fit imu_tk's 9 parameters to one |T K (mean - b)| - g residual per interval.

    Returns (params, info): scipy least_squares from T = I, K = I, b = 0 (inputs in SI).
    With fewer than 9 intervals the fit is underdetermined (``info['underdetermined']``).
    """
    means = np.asarray(means, float)

    def res(p):
        return np.linalg.norm(apply_params(p, means), axis=1) - g

    p0 = np.r_[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    # 'trf' also takes fewer residuals than parameters (six faces: 6 < 9, fitted exactly)
    r = least_squares(res, p0, method='trf', x_scale='jac', xtol=1e-15, ftol=1e-15,
                      gtol=1e-15, max_nfev=20000)
    return r.x, {'success': bool(r.success), 'nfev': int(r.nfev), 'message': r.message,
                 'n_intervals': len(means), 'n_params': 9,
                 'underdetermined': len(means) < 9}


def interval_means(accel, intervals):
    """Mean accel (m, 3) of each (start, end) interval."""
    return np.array([np.asarray(accel)[a:b].mean(0) for a, b in intervals])


def static_rms_ug(calibrated_means, g):
    """RMS over intervals of | |mean a| - g | in micro-g, and the largest, in micro-g."""
    r = np.abs(np.linalg.norm(calibrated_means, axis=1) - g) / UG
    return float(np.sqrt(np.mean(r ** 2))), float(r.max())


def load_imutk_calib(path):
    """Read an imu_tk .calib file: T (3x3), K (3x3), b (3,), blank-line separated."""
    vals = np.array(open(path).read().split(), float)
    return vals[:9].reshape(3, 3), vals[9:18].reshape(3, 3), vals[18:21]


def apply_imutk_calib(calib, accel):
    """calibrated = T K (raw - b) with a loaded .calib."""
    T, K, b = calib
    return (T @ K @ (np.asarray(accel) - b).T).T
