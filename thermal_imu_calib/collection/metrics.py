"""Static-error metrics on stationary windows, before and after compensation.

Every label (raw, or a calibration) is a Windows table with the same holds and window
boundaries, so the numbers compare like with like:

* gravity residual per hold: |mean f| - g in micro-g;
* averaged-window gravity residual: consecutive windows of a hold merged into blocks of
  ``average_s`` seconds (300 s by default, as a navigation-grade check), max and RMS;
* drift vs temperature per axis: the slope of each axis' window means against temperature
  within each hold that spans at least ``MIN_DRIFT_SPAN`` (micro-g/degC), RMS over holds;
* gyro: RMS of the per-hold mean rate (rad/s) — the residual bias plus earth rate.
"""

from dataclasses import replace

import numpy as np

#: a hold needs this temperature span (degC) before its drift slope is meaningful
MIN_DRIFT_SPAN = 1.0


class WindowAccumulator:
    """Accumulate sums of any (n, 3) signal into given [t0, t1] windows (for a second pass)."""

    def __init__(self, t0, t1):
        order = np.argsort(t0)
        self.t0 = np.asarray(t0, float)[order]
        self.t1 = np.asarray(t1, float)[order]
        self.order = order
        self.sum = {}
        self.count = np.zeros(len(self.t0))

    def add(self, t, signals):
        """Add samples at times t (s); ``signals`` maps a name to its (n, 3) values."""
        t = np.asarray(t, float)
        idx = np.searchsorted(self.t0, t, side='right') - 1
        ok = idx >= 0
        ok[ok] &= t[ok] <= self.t1[idx[ok]]
        if not np.any(ok):
            return
        idx = idx[ok]
        self.count += np.bincount(idx, minlength=len(self.t0))
        for name, x in signals.items():
            x = np.asarray(x, float)[ok]
            acc = self.sum.setdefault(name, np.zeros((len(self.t0), x.shape[1])))
            for j in range(x.shape[1]):
                acc[:, j] += np.bincount(idx, weights=x[:, j], minlength=len(self.t0))

    def means(self, name):
        """Return the per-window means of a signal, in the windows' original order."""
        out = np.empty_like(self.sum[name])
        out[self.order] = self.sum[name] / np.maximum(self.count, 1)[:, None]
        return out


def with_signals(windows, accel, gyro):
    """Return a copy of ``windows`` with other accel/gyro window means (same boundaries)."""
    return replace(windows, accel=np.asarray(accel), gyro=np.asarray(gyro))


def static_metrics(windows, gravity, average_s=300.0, axis_temp_input=0):
    """Compute the metrics above for one label; returns a plain dict (micro-g, rad/s).

    ``axis_temp_input``: the temperature column (degC) the drift slope is taken against;
    None (e.g. only proxy inputs) skips the drift.
    """
    g = gravity
    holds = []
    avg_res = []
    slopes = []
    for h in windows.hold_ids:
        m = windows.hold == h
        w = windows.n[m].astype(float)
        a = windows.accel[m]
        mean = np.average(a, 0, w)
        rec = {'hold': int(h), 't_start': float(windows.t0[m][0]),
               't_end': float(windows.t1[m][-1]),
               'gravity_residual_ug': float((np.linalg.norm(mean) - g) / g * 1e6),
               'gyro_mean': np.average(windows.gyro[m], 0, w).tolist()}
        if windows.n_inputs and axis_temp_input is not None:
            temp = windows.temp[m, axis_temp_input]
            rec['temp_range'] = [float(temp.min()), float(temp.max())]
            if np.ptp(temp) >= MIN_DRIFT_SPAN and m.sum() >= 3:
                tt = temp - np.average(temp, weights=w)
                sl = (tt * w) @ (a - mean) / max(float((tt * w) @ tt), 1e-12)
                rec['drift_ug_per_degC'] = (sl / g * 1e6).tolist()
                slopes.append(sl / g * 1e6)
        holds.append(rec)
        # merge consecutive windows into ~average_s blocks
        t0 = windows.t0[m]
        block = np.floor((t0 - t0[0]) / average_s).astype(int)
        for b in np.unique(block):
            sel = block == b
            dur = windows.t1[m][sel][-1] - t0[sel][0]
            if dur < 0.8 * average_s:
                continue  # a short tail would be noisier than the others
            mb = np.average(a[sel], 0, w[sel])
            avg_res.append((np.linalg.norm(mb) - g) / g * 1e6)
    gr = np.array([h['gravity_residual_ug'] for h in holds])
    gyro = np.array([h['gyro_mean'] for h in holds]) if holds else np.zeros((0, 3))
    out = {
        'holds': len(holds),
        'gravity_residual_ug': {'rms': _rms(gr), 'max': _amax(gr)},
        'averaged_residual_ug': {'window_s': average_s, 'count': len(avg_res),
                                 'rms': _rms(avg_res), 'max': _amax(avg_res)},
        'gyro_rate_rms': {'value': _rms(np.linalg.norm(gyro, axis=1)) if len(gyro) else 0.0,
                          'unit': 'rad/s'},
        'per_hold': holds,
    }
    if slopes:
        s = np.array(slopes)
        out['drift_ug_per_degC_rms'] = np.sqrt(np.mean(s ** 2, axis=0)).tolist()
    return out


def _rms(x):
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float('nan')


def _amax(x):
    x = np.asarray(x, float)
    return float(np.max(np.abs(x))) if x.size else float('nan')
