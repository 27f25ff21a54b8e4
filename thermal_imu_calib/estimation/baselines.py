"""PX4- and ArduPilot-style cubic offset-vs-temperature fits, as models for comparison.

Both autopilots calibrate the IMU's thermal drift as a cubic polynomial of the offset in
temperature relative to a reference, learnt from one static warm-up; we reproduce the
data handling of each at the level of our window statistics (5-s means):

* **PX4** (``Tools/process_sensor_caldata.py``, the offline fit behind the ``TC_A*/TC_G*``
  parameters): median filter of each axis (31 samples there; our windows are already
  5-s means, so a 3-window median, repeating the end values instead of scipy.signal's
  zero padding, which would bend the first and last of a few hundred windows), reference
  temperature ``TREF`` = middle of the
  recorded range, resampling into equal-width temperature bins (2000 across the range,
  mean of temperature and value per non-empty bin), ``numpy.polyfit`` of degree 3 of the
  offset against ``T - TREF`` (constant ``X0`` included).
* **ArduPilot** (``AP_InertialSensor_tempcal.cpp``, ``INS_TCALn_*``): samples are summed
  until the (low-passed) temperature has *risen* 0.5 degC above the last bin, the bin is
  placed at the mean of its start and end temperature, the accelerometer bins are taken
  relative to the first one, a cubic (``PolyFit<4>``) is fitted in ``T - 35 degC`` and
  stored without its constant (``TCAL_ACCn``, ``TCAL_GYRn`` in 1e-6 units there). Only
  rising temperature closes bins; below the last bin the learner restarts from the new
  minimum, so the heating legs of a chamber cycle are all learnt (on board it would sum
  a whole cooling leg into the next bin).

Each returns an ``OffsetPolynomialModel`` (order 3) whose coefficient stds come from the
Jacobian of the least-squares fit (the bins' residual scatter), plus a report.
"""

import numpy as np
from scipy.ndimage import median_filter

from ..models.polynomial import OffsetPolynomialModel
from .calibrate import CalibrationRefused, Estimate, register_estimator

#: ArduPilot's fixed reference temperature, degC (TEMP_REFERENCE)
ARDUPILOT_TREF = 35.0
#: ArduPilot closes a learning bin after this temperature rise, degC
ARDUPILOT_STEP = 0.5
#: PX4 resamples into this many equal-width temperature bins (resampleWithDeltaX)
PX4_BINS = 2000


def _cubic_ls(x, y):
    """Return (coeffs c0..c3, their 1-sigma std) of an unweighted cubic LS fit in x."""
    v = np.stack([x ** j for j in range(4)], 1)
    coef, *_ = np.linalg.lstsq(v, y, rcond=None)
    dof = max(len(y) - 4, 1)
    r = y - v @ coef
    s2 = float(r @ r) / dof
    cov = np.linalg.pinv(v.T @ v) * s2
    return coef, np.sqrt(np.maximum(np.diag(cov), 0.0))


def px4_fit(windows, axis_temps, signal, sensor, median_kernel=3, bins=PX4_BINS):
    """Fit the PX4-style cubic per axis; returns (OffsetPolynomialModel, report).

    The constant ``X0`` is kept for the gyroscope (bias) and dropped for a
    single-orientation accelerometer (it holds the gravity projection there).
    """
    order = np.argsort(windows.t0, kind='stable')
    temps = np.asarray(axis_temps, float)[order]
    y = getattr(windows, signal)[order]
    tref = 0.5 * (temps.min(0) + temps.max(0))
    coeffs = np.zeros((4, 3))
    std = np.zeros((4, 3))
    used = []
    for a in range(3):
        ya = median_filter(y[:, a], median_kernel, mode='nearest')
        rel = temps[:, a] - tref[a]
        lo, hi = rel.min(), rel.max()
        width = (hi - lo) / bins if hi > lo else 1.0
        idx = np.clip(((rel - lo) / width).astype(int), 0, bins - 1)
        cnt = np.bincount(idx, minlength=bins)
        keep = cnt > 0
        tb = np.bincount(idx, rel, bins)[keep] / cnt[keep]
        yb = np.bincount(idx, ya, bins)[keep] / cnt[keep]
        if len(tb) < 4:
            raise ValueError(f'PX4-style fit needs 4 distinct temperature bins, axis '
                             f'{"xyz"[a]} has {len(tb)}')
        coeffs[:, a], std[:, a] = _cubic_ls(tb, yb)
        used.append(int(len(tb)))
    include = sensor == 'gyro'
    model = OffsetPolynomialModel(tref, coeffs, sensor=sensor, include_constant=include,
                                  coeff_std=std)
    if not include:
        model.coeff_std[0] = 0.0
    return model, {'method': 'PX4-style cubic', 'TREF_degC': tref.tolist(),
                   'median_kernel_windows': median_kernel, 'bins_used': used}


def ardupilot_bins(n, temps, y, step=ARDUPILOT_STEP):
    """Return (bin temperatures, bin means) of ArduPilot's rising-temperature learning.

    Rows in time order; ``n`` are the sample counts of each row (its weight in the sum).
    A bin closes when the temperature is ``step`` above the last closed bin. When the
    temperature falls below the last bin, the learner restarts from the new minimum
    (on board it would keep summing through a cooling leg into one bin), so every heating
    leg of a cycle is learnt.
    """
    t_last = temps[0]
    acc = np.zeros(y.shape[1])
    cnt = 0.0
    tb, yb = [], []
    for i in range(len(temps)):
        if temps[i] < t_last:
            t_last = temps[i]
            acc[:] = 0.0
            cnt = 0.0
        acc += n[i] * y[i]
        cnt += n[i]
        if temps[i] - t_last < step:
            continue
        tb.append(0.5 * (temps[i] + t_last))
        yb.append(acc / cnt)
        acc = np.zeros(y.shape[1])
        cnt = 0.0
        t_last = temps[i]
    return np.asarray(tb), np.asarray(yb).reshape(-1, y.shape[1])


def ardupilot_fit(windows, axis_temps, signal, sensor, tref=ARDUPILOT_TREF,
                  step=ARDUPILOT_STEP):
    """Fit the ArduPilot-style cubic per axis; returns (OffsetPolynomialModel, report)."""
    order = np.argsort(windows.t0, kind='stable')
    temps = np.asarray(axis_temps, float)[order]
    y = getattr(windows, signal)[order]
    n = windows.n[order].astype(float)
    coeffs = np.zeros((4, 3))
    std = np.zeros((4, 3))
    used = []
    for a in range(3):
        tb, yb = ardupilot_bins(n, temps[:, a], y[:, a:a + 1], step)
        if len(tb) < 4:
            raise ValueError(f'ArduPilot-style fit needs the temperature to rise by '
                             f'{4 * step:g} degC; axis {"xyz"[a]} closed {len(tb)} bins')
        yb = yb[:, 0]
        if signal == 'accel':
            yb = yb - yb[0]          # the first accel bin is the zero baseline
        coeffs[:, a], std[:, a] = _cubic_ls(tb - tref, yb)
        used.append(int(len(tb)))
    coeffs[0] = 0.0                  # stored without the constant term
    std[0] = 0.0
    model = OffsetPolynomialModel(np.full(3, tref), coeffs, sensor=sensor,
                                  include_constant=False, coeff_std=std)
    return model, {'method': 'ArduPilot-style cubic', 'TREF_degC': tref, 'step_degC': step,
                   'bins_used': used}


def _baseline_estimate(ctx, fit, name):
    if ctx.k == 0:
        raise CalibrationRefused(f'the {name} fit needs a temperature input',
                                 'record the IMU temperature topic')
    w = ctx.windows
    try:
        accel, rep_a = fit(w, ctx.ta, 'accel', 'accel')
        gyro, rep_g = fit(w, ctx.tg, 'gyro', 'gyro')
    except ValueError as e:
        raise CalibrationRefused(str(e), 'record a warm-up from cold') from None
    notes = [f'{rep_a["method"]} offsets vs temperature, for comparison: drift relative to '
             f'the reference temperature{"" if ctx.n_orientations == 1 else " in one pose"}']
    if ctx.n_orientations > 1:
        notes.append(f'{ctx.n_orientations} orientations: an offset model cannot separate '
                     'the pose changes from the thermal drift; use --model auto or field')
    return Estimate(accel=accel, gyro=gyro, report={'accel_offset': rep_a, 'gyro_offset': rep_g},
                    fit={'pose': 'single orientation (offset-only)', 'method': rep_a['method']},
                    notes=notes)


@register_estimator('px4')
def estimate_px4(ctx):
    """Estimate PX4-style cubic offsets of accelerometer and gyroscope (for comparison)."""
    return _baseline_estimate(ctx, px4_fit, 'PX4-style')


@register_estimator('ardupilot')
def estimate_ardupilot(ctx):
    """Estimate ArduPilot-style cubic offsets of accelerometer and gyroscope (comparison)."""
    units = {getattr(ctx.options.inputs[i], 'unit', 'degC')
             for i in list(ctx.accel_input) + list(ctx.gyro_input)
             if i < len(ctx.options.inputs)}
    if units - {'degC'}:
        raise CalibrationRefused(
            f'the ArduPilot-style fit works in degC (0.5-degC bins, TREF 35 degC) but an '
            f'input is in {", ".join(sorted(units - {"degC"}))}',
            'use --model px4 (bins over the collected range) or auto for a thermal proxy')
    return _baseline_estimate(ctx, ardupilot_fit, 'ArduPilot-style')
