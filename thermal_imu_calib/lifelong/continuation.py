"""The gyro beyond its valid range: continued linearly only where the loop's history says so.

A robot's first calibrations span a few degC; the next days' stops often lie outside that
range. Clamped (the package's default), the gyro keeps the edge value there; continued
linearly (``out_of_range: linear_gyro``, the edge slope, capped at the range's width) it
follows the thermal trend, when the edge slope is right. On 13 simulated months seen while
building this, the continuation was better after the first day on 12, and on one month
(seed 43, a hysteresis gyro fitted over 3 degC) it was far worse (docs/lifelong.md).
So the loop decides it from its own held-out evidence:

* **Evidence.** Each new hold outside the *active* calibration's gyro range (a hold the
  active calibration never saw) is scored twice: with the active gyro clamped and
  continued. The row (time s, clamped error, continued error, standard error; rad/s,
  ``gate.hold_errors``) is kept in the loop's state; rows after a change alarm's cut are
  dropped (the sensor changed, not the thermal trend).
* **Verdict.** The swap gate's own gyro rule on all rows: the continued RMS error is lower
  by more than the margin (the larger of the noise and ``swap_sigmas`` times the standard
  error of the paired difference). Then every new estimate continues its gyro linearly;
  otherwise it clamps. With no rows (the first calibrations) it clamps: the standard
  behaviour is the floor.
* **Like for like** (``LifelongConfig.gyro_continuation`` 'span'). Each row also keeps the
  gyro span (degC, first input) of the calibration that scored it. A new estimate is
  judged only on the rows of calibrations spanning at least half its own span: what the
  first calibrations, fitted over a few degC, did beyond their edge says little about one
  fitted over weeks (docs/lifelong.md, "Seed 178's gyro beyond its range").

Only when the calibrate settings' policy is 'clamp' (the default) or 'linear_gyro'; any
other policy a user chose is left alone. ``LifelongConfig.gyro_continuation``. No ROS
import.
"""

from dataclasses import replace

import numpy as np

from . import gate

#: the policies this rule chooses between (``Calibration.out_of_range``)
CHOICES = ('clamp', 'linear_gyro')
#: most evidence rows kept, newest last (a memory bound: weeks of stops beyond the range)
MAX_ROWS = 2000
#: 'span': the rows judged are those of calibrations spanning at least this fraction of
#: the new estimate's gyro span
SPAN_FRACTION = 0.5


def span(cal):
    """Return the width (degC) of ``cal``'s gyro range on its first input (0: none)."""
    if cal is None or not cal.inputs:
        return 0.0
    lo, hi = np.asarray(cal.own_range('gyro'), float)[0]
    return float(hi - lo)


def outside_holds(cal, windows):
    """Return the hold ids of ``windows`` with a window outside ``cal``'s gyro range."""
    if cal is None or cal.gyro is None or not cal.inputs or not len(windows) \
            or not windows.n_inputs:
        return np.zeros(0, int)
    temps = windows.temp
    if cal.temperature_filter is not None:
        temps = cal.temperature_filter.window_temperatures(windows)
    _, oor = cal.axis_temperatures(temps, 'gyro')
    return np.unique(windows.hold[oor])


def rows(cal, windows, gravity, latitude=None):
    """Return [[t s, clamped error, continued error, standard error, span]], one per hold.

    Errors in rad/s; span: ``cal``'s gyro span (degC, ``span``). Holds of ``windows``
    outside ``cal``'s gyro range only; empty when ``cal``'s policy is not one of
    ``CHOICES``.
    """
    if cal is None or cal.out_of_range not in CHOICES:
        return []
    ids = outside_holds(cal, windows)
    if not len(ids):
        return []
    sub = windows.select(np.isin(windows.hold, ids))
    clamp = gate.hold_errors(replace(cal, out_of_range='clamp'), sub, gravity, latitude)
    cont = gate.hold_errors(replace(cal, out_of_range='linear_gyro'), sub, gravity, latitude)
    width = span(cal)
    return [[float(t), float(a), float(b), float(s), width] for t, a, b, s in
            zip(clamp['t'], np.abs(clamp['gyro']), np.abs(cont['gyro']), clamp['se_gyro'])]


def like(evidence, width):
    """Return the rows of calibrations spanning at least ``SPAN_FRACTION`` of ``width`` degC.

    Rows without a span (written before the column existed) stay.
    """
    return [r for r in evidence if len(r) < 5 or r[4] >= SPAN_FRACTION * width]


def add(state, new_rows):
    """Append rows to ``state['continuation']`` (created), keeping the newest ``MAX_ROWS``."""
    kept = (state.get('continuation') or []) + list(new_rows)
    state['continuation'] = kept[-MAX_ROWS:]


def cut(state, t_cut):
    """Drop the rows of holds that end at or after ``t_cut`` (s; a change alarm's cut)."""
    state['continuation'] = [r for r in state.get('continuation') or [] if r[0] < t_cut]


def verdict(evidence, sigmas, width=None):
    """Return (continue: bool, text) from evidence rows by the swap gate's rule (``compare``).

    ``width``: the new estimate's gyro span (degC); given, only the rows ``like`` keeps.
    """
    if width is not None:
        evidence = like(evidence, width)
    if len(evidence) < 2:
        return False, (f'gyro clamped beyond its range: {len(evidence)} hold'
                       f'{"" if len(evidence) == 1 else "s"} outside the earlier active '
                       'calibrations\' ranges so far, 2 needed to judge a continuation')
    r = np.asarray([x[:4] for x in evidence], float)
    f = gate.compare(r[:, 1], r[:, 2], gate.rms(r[:, 3]), sigmas)
    scale = np.degrees(1.0) * 1e3
    like_for_like = '' if width is None else \
        f' of calibrations spanning at least {SPAN_FRACTION * width:.3g} degC'
    figures = (f'on {len(r)} holds outside the earlier active calibrations\' ranges'
               f'{like_for_like}, '
               f'clamped {f["active_rms"] * scale:.3g} vs continued '
               f'{f["new_rms"] * scale:.3g} mdeg/s (margin {f["margin"] * scale:.2g})')
    if f['verdict'] == 'better':
        return True, 'gyro continued linearly beyond its range: ' + figures
    return False, 'gyro clamped beyond its range: ' + figures


def choose(cal, evidence, sigmas, like_for_like=False):
    """Return (calibration with the chosen gyro policy, text); others' policies untouched.

    ``like_for_like``: judged on the rows of calibrations like ``cal`` (``like``).
    """
    if cal.out_of_range not in CHOICES or cal.gyro is None:
        return cal, ''
    go, text = verdict(evidence, sigmas, span(cal) if like_for_like else None)
    return replace(cal, out_of_range='linear_gyro' if go else 'clamp'), text
