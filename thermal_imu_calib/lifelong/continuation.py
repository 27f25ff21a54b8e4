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
* **Explained rows only** (``explained``, ``LifelongConfig.gyro_continuation``
  'explained'). Each row also keeps the change alarm's gyro limit of its hold (rad/s,
  ``gate.limit``: the alarm factor times the active's held-out RMS, at least the floor
  times the hold's standard error; infinite before the loop has a reference). A hold that
  both policies miss by that limit (the active calibration did not explain it at all,
  e.g. a first calibration fitted over a few degC and hours) says nothing about which
  policy continues the trend, yet its squared error outweighs every other row in the
  RMS; it is left out of the verdict.

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


def rows(cal, windows, gravity, latitude=None, reference=None):
    """Return [[t s, clamped error, continued error, standard error, limit]], one per hold.

    Errors in rad/s. Holds of ``windows`` outside ``cal``'s gyro range only; empty when
    ``cal``'s policy is not one of ``CHOICES``. ``reference``: (gyro RMS rad/s, factor,
    floor) of the change alarm (``gate.limit``), the limit column; None: infinite (no
    reference yet).
    """
    if cal is None or cal.out_of_range not in CHOICES:
        return []
    ids = outside_holds(cal, windows)
    if not len(ids):
        return []
    sub = windows.select(np.isin(windows.hold, ids))
    clamp = gate.hold_errors(replace(cal, out_of_range='clamp'), sub, gravity, latitude)
    cont = gate.hold_errors(replace(cal, out_of_range='linear_gyro'), sub, gravity, latitude)
    lim = np.full(len(clamp['t']), np.inf) if reference is None else \
        gate.limit(clamp, 'gyro', *reference)
    return [[float(t), float(a), float(b), float(s), float(m)] for t, a, b, s, m in
            zip(clamp['t'], np.abs(clamp['gyro']), np.abs(cont['gyro']), clamp['se_gyro'],
                lim)]


def reference(state, config):
    """Return the change alarm's (gyro RMS rad/s, factor, floor) for ``rows``, None: none yet.

    ``state``: the loop's counters (``active_gyro_rms``); ``config``: its ``LifelongConfig``.
    """
    rms = state.get('active_gyro_rms')
    return None if rms is None else (rms, config.alarm_factor, config.alarm_floor)


def explained(evidence):
    """Return (the rows at least one policy explains, how many were left out).

    A row is left out when both its errors exceed its limit (the fifth column); rows
    without one (written before the column existed) stay.
    """
    kept = [r for r in evidence if len(r) < 5 or min(r[1], r[2]) <= r[4]]
    return kept, len(evidence) - len(kept)


def add(state, new_rows):
    """Append rows to ``state['continuation']`` (created), keeping the newest ``MAX_ROWS``."""
    kept = (state.get('continuation') or []) + list(new_rows)
    state['continuation'] = kept[-MAX_ROWS:]


def cut(state, t_cut):
    """Drop the rows of holds that end at or after ``t_cut`` (s; a change alarm's cut)."""
    state['continuation'] = [r for r in state.get('continuation') or [] if r[0] < t_cut]


def verdict(evidence, sigmas, only_explained=False):
    """Return (continue: bool, text) from evidence rows by the swap gate's rule (``compare``).

    ``only_explained``: judged on the rows ``explained`` keeps.
    """
    dropped = ''
    if only_explained:
        evidence, n = explained(evidence)
        dropped = (f' ({n} hold{"" if n == 1 else "s"} both missed by the change alarm\'s '
                   'limit left out)') if n else ''
    if len(evidence) < 2:
        return False, (f'gyro clamped beyond its range: {len(evidence)} hold'
                       f'{"" if len(evidence) == 1 else "s"} outside the earlier active '
                       'calibrations\' ranges so far, 2 needed to judge a continuation'
                       + dropped)
    r = np.asarray([x[:4] for x in evidence], float)
    f = gate.compare(r[:, 1], r[:, 2], gate.rms(r[:, 3]), sigmas)
    scale = np.degrees(1.0) * 1e3
    figures = (f'on {len(r)} holds outside the earlier active calibrations\' ranges, '
               f'clamped {f["active_rms"] * scale:.3g} vs continued '
               f'{f["new_rms"] * scale:.3g} mdeg/s (margin {f["margin"] * scale:.2g})'
               + dropped)
    if f['verdict'] == 'better':
        return True, 'gyro continued linearly beyond its range: ' + figures
    return False, 'gyro clamped beyond its range: ' + figures


def choose(cal, evidence, sigmas, only_explained=False):
    """Return (calibration with the chosen gyro policy, text); others' policies untouched."""
    if cal.out_of_range not in CHOICES or cal.gyro is None:
        return cal, ''
    go, text = verdict(evidence, sigmas, only_explained)
    return replace(cal, out_of_range='linear_gyro' if go else 'clamp'), text
