"""A unit's accelerometer non-orthogonality S, pooled over its calibrations, for the alarms.

Without a lab prior the alarm yardstick estimates S with the bias and scale terms
(``estimation/alarm_yardstick.py``), which keeps the drift alarms honest when the part's
cross-axis terms are large, at a price: on six-face logs S is known only to its prior
(+-2 %), and the terms' stds carry that (on simulated fleets the weakest drift's z fell from
22-26 to 3.9-9.5 sigma, one slow drift of 80 missed; docs/fleet.md). But S is the same in
all of a unit's calibrations. Each yardstick stores its terms given S (stds ``b_std_s``,
gains ``b_ds`` on S's three terms, ``field_estimator.SCondition``) and what its data say
about S (information ``s_info`` and vector ``s_eta``, prior removed). So the alarms:

* pool S over the unit's calibrations: information = prior's (1 / ``S_PRIOR_STD``^2) +
  the sum of the data's, S* = information^-1 (sum of the vectors), Cov(S*) its inverse;
* carry each calibration's terms to S*: value + gain (S* - its own S), std given S; the
  bias (``POOLED``) always, the scale factor at T0 also with its curvature on S
  (+ (S* - S)' H (S* - S) / 2, ``alarm_yardstick.K_CURVATURE``) when stored, its gain
  then taken at S* (``can_pool``);
* test a change (or a trend) with the variance given S plus the part of S*'s error that
  does not cancel between the calibrations: (G1 - G0) Cov(S*) (G1 - G0)^T, G the gains at
  the test's temperature. Between logs with similar poses G1 ~ G0 and the S part cancels.

In the linearised fits each log's terms given S are independent of what the other logs
say about S, so these variances are exact to first order. Index columns (``columns``):
``accel.alarm_b0.x_std_s`` .., ``accel.alarm_b0.x_ds.s10`` .., ``accel.alarm_s.s10``,
``accel.alarm_s_eta.s10``, ``accel.alarm_s_info.s10.s20``, ``accel.alarm_k0.x_dss.s10.s20``
... No ROS import.
"""

import numpy as np

from ..estimation.alarm_yardstick import K_CURVATURE
from ..estimation.field_estimator import S_PRIOR_STD, S_TERM_NAMES

AXES = 'xyz'
STEM = 'accel.alarm_'
#: the parameters whose terms given S are stored ('b' bias, 'k' scale factor)
NAMES = ('b', 'k')
#: the parameters tested at the pooled S with their gains alone. Not the scale factor: it
#: depends on S to second order (a face's reading is |S v| g, the tilt taking up the cross
#: terms), which the gains at each log's own S (left near the prior by six-face logs) do
#: not follow: on stable simulated units (``bench/alarm_truth_z.py --fleet-seed 103``) its
#: truth-removed change z on x had std 1.20 (largest 4.36) at the pooled S with the
#: design's S, 1.23 (4.75) with a datasheet's. With its curvature (fleet seed 108, unseen):
#: 0.95 / 0.95 on x, 0.88-1.10 on every axis (docs/fleet.md). The bias, read from opposite
#: faces where that part cancels: 0.93-1.06 at the pooled S on both.
POOLED = ('b',)


def columns(terms):
    """Return the index columns of a yardstick's terms given S ({} without them).

    ``terms``: ``alarm_yardstick.terms_of`` output.
    """
    if 'b_ds' not in terms:
        return {}
    out = {}
    if K_CURVATURE in terms:
        for i, a in enumerate(AXES):
            for m, n in PAIRS:
                out[_dss_column(a, m, n)] = float(terms[K_CURVATURE][i, m, n])
    for m, t in enumerate(S_TERM_NAMES):
        out[f'{STEM}s.{t}'] = float(terms['s'][m])
        out[f'{STEM}s_eta.{t}'] = float(terms['s_eta'][m])
        for n, u in enumerate(S_TERM_NAMES):
            out[f'{STEM}s_info.{t}.{u}'] = float(terms['s_info'][m, n])
    for name in NAMES:
        for i, a in enumerate(AXES):
            for j in range(3):
                out[f'{STEM}{name}{j}.{a}_std_s'] = float(terms[f'{name}_std_s'][i, j])
                for m, t in enumerate(S_TERM_NAMES):
                    out[f'{STEM}{name}{j}.{a}_ds.{t}'] = float(terms[f'{name}_ds'][i, j, m])
    return out


#: S's term pairs (m <= n) of the scale factor's stored curvature
PAIRS = tuple((m, n) for m in range(len(S_TERM_NAMES)) for n in range(m, len(S_TERM_NAMES)))


def _dss_column(axis, m, n):
    """Return the index column of d^2 k0 / d (s_m, s_n) on ``axis``."""
    return f'{STEM}k0.{axis}_dss.{S_TERM_NAMES[m]}.{S_TERM_NAMES[n]}'


def cell(row, key):
    """Return an index row's cell as a float (NaN when missing, empty or not a number)."""
    try:
        return float(row.get(key, ''))
    except ValueError:
        return np.nan


def has_given_s(row):
    """Return True when an index row has S's fit (``columns``), without parsing the rest."""
    return np.isfinite(cell(row, f'{STEM}s.{S_TERM_NAMES[0]}'))


def row_s(row):
    """Return a row's terms given S, or None (written without them, or not finite).

    {'q' (3,), 'info' (3, 3), 'eta' (3,), 'b_std_s', 'k_std_s' (3 axes, 3 orders),
    'b_ds', 'k_ds' (3, 3, 3)}.
    """
    if not has_given_s(row):
        return None
    out = {'q': np.array([cell(row, f'{STEM}s.{t}') for t in S_TERM_NAMES]),
           'eta': np.array([cell(row, f'{STEM}s_eta.{t}') for t in S_TERM_NAMES]),
           'info': np.array([[cell(row, f'{STEM}s_info.{t}.{u}') for u in S_TERM_NAMES]
                             for t in S_TERM_NAMES])}
    for name in NAMES:
        out[f'{name}_std_s'] = np.array([[cell(row, f'{STEM}{name}{j}.{a}_std_s')
                                          for j in range(3)] for a in AXES])
        out[f'{name}_ds'] = np.array([[[cell(row, f'{STEM}{name}{j}.{a}_ds.{t}')
                                        for t in S_TERM_NAMES] for j in range(3)]
                                      for a in AXES])
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        return None
    curv = np.zeros((len(AXES), len(S_TERM_NAMES), len(S_TERM_NAMES)))
    for i, a in enumerate(AXES):
        for m, n in PAIRS:
            curv[i, m, n] = curv[i, n, m] = cell(row, _dss_column(a, m, n))
    if np.all(np.isfinite(curv)):            # rows written before it have none
        out[K_CURVATURE] = curv
    return out


def can_pool(name, parts):
    """Return True when ``name``'s terms of rows with terms given S (``row_s``) go to S*.

    The bias always (``POOLED``); the scale factor when every row has its curvature on S.
    """
    return (all(p is not None for p in parts)
            and (name in POOLED or (name == 'k' and all(K_CURVATURE in p for p in parts))))


def row_s_memo(row, memo):
    """Return ``row_s(row)``, read once per row into ``memo`` (``alarms._terms_memo``)."""
    if memo is None:
        return row_s(row)
    key = (id(row), 'given S')
    if key not in memo:
        memo[key] = row_s(row)
    return memo[key]


def unit_pools(rows, family, memo=None):
    """Return {family(row): (S*, Cov(S*))} over a unit's rows with terms given S.

    ``family``: a row's chain of alarm terms (``alarms.accel_family``); ``memo``: see
    ``row_s_memo``.
    """
    by = {}
    for r in rows:
        part = row_s_memo(r, memo)
        if part is not None:
            by.setdefault(family(r), []).append(part)
    return {f: pool(parts) for f, parts in by.items()}


def pool(parts):
    """Return (S* (3,), Cov(S*) (3, 3)) from ``row_s`` of a unit's calibrations.

    The prior's information once, plus each calibration's data information.
    """
    info = np.eye(len(S_TERM_NAMES)) / S_PRIOR_STD ** 2 + sum(p['info'] for p in parts)
    eta = sum(p['eta'] for p in parts)
    cov = np.linalg.inv(info)
    return cov @ eta, (cov + cov.T) / 2


def at_temperature(c, part, name, t_ref, t0, s_star):
    """Return (value (3,), std given S (3,), gain (3 axes, 3 terms)) at ``t_ref`` and S*.

    ``c``: the row's (3 axes, 3 orders) coefficients of ``name`` about ``t0`` (3,) degC
    (``alarms.row_terms``); ``part``: its ``row_s``.
    """
    pw = (np.asarray(t_ref, float) - t0)[:, None] ** np.arange(3)             # (3, 3)
    gain = np.einsum('ajm,aj->am', part[f'{name}_ds'], pw)
    ds = s_star - part['q']
    value = np.sum(c * pw, axis=1) + gain @ ds
    if name == 'k' and K_CURVATURE in part:      # second order, and the gain at S*
        curv = part[K_CURVATURE]
        value = value + 0.5 * np.einsum('amn,m,n->a', curv, ds, ds)
        gain = gain + curv @ ds
    std = np.sqrt(np.sum((part[f'{name}_std_s'] * pw) ** 2, axis=1))
    return value, std, gain


def is_given_s_column(key):
    """Return True for an index column of ``columns`` (the terms given S, S's fit)."""
    return ('_ds.' in key or '_dss.' in key or key.endswith('_std_s')
            or key.startswith((f'{STEM}s.', f'{STEM}s_')))


def without_given_s(rows):
    """Return copies of index rows without ``columns``: as a registry written before them.

    Their tests then use the terms' own (marginal) stds; the benches judge both ways on the
    same calibrations.
    """
    return [{k: v for k, v in r.items() if not is_given_s_column(k)} for r in rows]
