"""Seed 002 whole-unit accelerometer fit from static poses of unknown orientation.

Residual (one per stationary window w, whitened by its standard error)::

    r_w = (|a(U_w, T_w)| - g) / sigma_w,    a = A0 + A1 V + A2 o V^2 + A3 o V^3,
                                            V = (U - c(T)) / (1 + k(T))

solved with ``scipy.optimize.least_squares`` (analytic Jacobian) and a robust
loss (``outliers.robust_least_squares``), so one bumped hold loses its weight
instead of dragging the fit. Observability is decided from the data
(``observability``): e.g. misalignment is refused for six clean faces (|a| is
flat to first order in a misalignment when gravity lies on an axis) and the
3rd-order terms for 1-g data. Optional terms are then kept only when
leave-holds-out cross-validation supports them (``_select_by_cv``).
"""

from dataclasses import dataclass, field

import numpy as np

from ..models.whole_unit import WholeUnitAccelModel
from .field_estimator import kkt_unit_tilt_batch
from ..collection.outliers import group_outliers, robust_scale

from .observability import (CONVENTION, converged, decide_determined, DETERMINED_RATIO,
                            fit_free, FitNotConverged, Layout, NOT_CONVERGED_KEY, Priors,
                            StoppedFolds)


#: the accel frame convention of the field fit (A1 lower-triangular)
FRAME_CONVENTION = ('A1 lower-triangular: frame x = accelerometer x sensing axis, frame y in '
                    'the plane of the x and y sensing axes (seed 000 convention); a norm-only '
                    'fit cannot see a rotation of the whole triad')


#: folds and parsimony tolerance of the leave-holds-out selection of optional terms
CV_FOLDS = 5
CV_TOLERANCE = 0.01
#: evaluations of one least-squares fit (``fit_free``'s ``max_nfev``)
MAX_NFEV = 200
#: reason stored for a determined parameter that cross-validation drops
CV_REASON = ('determined, but leave-holds-out cross-validation does not support it: fixed at '
             'its prior')
#: residual forms of the accelerometer fit
RESIDUALS = ('norm', 'vector')


# ------------------------------------------------------------------------ accel fit
def accel_layout(priors, offset_order, scale_order, has_temperature):
    """Return the Layout of the accel field fit (conventions already fixed)."""
    pm = priors.accel_mean
    lay = Layout()
    lay.add('A0', (3,), 0.0, 0.0, CONVENTION + ': A0 = 0, the bias is carried by ct0 (raw '
            'domain, subtracted before the scale-factor terms as in seed 000; ct0 and A0 '
            'are exactly redundant without scale temperature terms)')
    a1_std = np.full((3, 3), priors.accel_misalignment)
    np.fill_diagonal(a1_std, priors.accel_scale)
    lay.add('A1', (3, 3), pm.get('A1', np.eye(3)), a1_std)
    lay.fix('A1', [1, 2, 5], CONVENTION + ': ' + FRAME_CONVENTION)
    lay.add('A2', (3,), pm.get('A2', 0.0), priors.accel_nonlin2)
    lay.add('A3', (3,), pm.get('A3', 0.0), priors.accel_nonlin3)
    lay.add('ct0', (3,), pm.get('ct0', 0.0), priors.accel_bias)
    tc = 'no temperature input' if not has_temperature else None
    for j in range(1, offset_order + 1):
        lay.add(f'ct{j}', (3,), pm.get(f'ct{j}', 0.0), priors.accel_offset_tc[j - 1], tc)
    for j in range(1, scale_order + 1):
        lay.add(f'kt{j}', (3,), pm.get(f'kt{j}', 0.0), priors.accel_scale_tc[j - 1], tc)
    return lay


def _unpack(lay, p, no, ns):
    offset = np.stack([lay.get(p, f'ct{j}') for j in range(no + 1)])
    scale = (np.stack([lay.get(p, f'kt{j}') for j in range(1, ns + 1)]) if ns
             else np.zeros((0, 3)))
    return offset, scale, lay.get(p, 'A0'), lay.get(p, 'A1'), lay.get(p, 'A2'), \
        lay.get(p, 'A3')


def _accel_and_jac(lay, p, raw, dt, no, ns, want_jac=False):
    """Return corrected a (m, 3) and, optionally, da/dp (m, 3, layout.size)."""
    offset, scale, m0, m1, m2, m3 = _unpack(lay, p, no, ns)
    c = np.zeros_like(dt)
    for row in offset[::-1]:
        c = c * dt + row
    k = np.zeros_like(dt)
    for row in scale[::-1]:
        k = (k + row) * dt
    k = 1.0 + k
    v = (raw - c) / k
    a = m0 + v @ m1.T + m2 * v * v + m3 * v ** 3
    if not want_jac:
        return a, None
    m = raw.shape[0]
    eye = np.eye(3)
    jac = np.zeros((m, 3, lay.size))
    jac[:, :, lay.slices['A0']] = eye
    jac[:, :, lay.slices['A1']] = np.einsum('ij,nk->nijk', eye, v).reshape(m, 3, 9)
    jac[:, :, lay.slices['A2']] = np.einsum('ij,nj->nij', eye, v * v)
    jac[:, :, lay.slices['A3']] = np.einsum('ij,nj->nij', eye, v ** 3)
    d = m1[None] + np.einsum('ni,ij->nij', 2 * m2 * v + 3 * m3 * v * v, eye)   # da/dV
    for j in range(no + 1):
        jac[:, :, lay.slices[f'ct{j}']] = -d * (dt ** j / k)[:, None, :]
    for j in range(1, ns + 1):
        jac[:, :, lay.slices[f'kt{j}']] = -d * (v * dt ** j / k)[:, None, :]
    return a, jac


def _norm_residual(lay, p, raw, dt, sigma, gravity, no, ns, want_jac=False):
    """Whitened |a| - g per window and, optionally, its Jacobian w.r.t. the full vector."""
    a, da = _accel_and_jac(lay, p, raw, dt, no, ns, want_jac)
    na = np.linalg.norm(a, axis=1)
    r = (na - gravity) / sigma
    if not want_jac:
        return r, a
    u = a / na[:, None] / sigma[:, None]                     # d r / d a
    return r, np.einsum('ni,nip->np', u, da)


def _vector_residual(lay, p, raw, dt, weight, hold_idx, nh, gravity, no, ns, want_jac=False):
    """Whitened a - g c_h per window and axis, c_h eliminated (variable projection).

    c_h, the unit up direction of hold h, is the constrained least-squares optimum for the
    current parameters (Newton-KKT, seed 000 eqs. 20-27); the Jacobian is projected onto
    the complement of the tangent directions of c_h (Kaufman), so the hold directions
    are nuisances that never appear as parameters.
    """
    a, da = _accel_and_jac(lay, p, raw, dt, no, ns, want_jac)
    w2 = weight ** 2
    mm = np.zeros((nh, 3, 3))
    vv = np.zeros((nh, 3))
    np.add.at(mm, hold_idx, gravity ** 2 * np.einsum('ni,ij->nij', w2, np.eye(3)))
    np.add.at(vv, hold_idx, gravity * w2 * a)
    c0 = vv / np.linalg.norm(vv, axis=1, keepdims=True)
    c, _, _ = kkt_unit_tilt_batch(mm, vv, c0)
    r = weight * (a - gravity * c[hold_idx])
    if not want_jac:
        return r.ravel(), a
    j = weight[:, :, None] * da                                   # (m, 3, P)
    ref = np.eye(3)[np.argmin(np.abs(c), axis=1)]
    e1 = np.cross(c, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(c, e1)
    b = -gravity * weight[:, :, None] * np.stack([e1[hold_idx], e2[hold_idx]], axis=2)
    btb = np.zeros((nh, 2, 2))
    btj = np.zeros((nh, 2, lay.size))
    np.add.at(btb, hold_idx, np.einsum('nia,nib->nab', b, b))
    np.add.at(btj, hold_idx, np.einsum('nia,nip->nap', b, j))
    coef = np.linalg.solve(btb, btj)                              # (nh, 2, P)
    j = j - np.einsum('nia,nap->nip', b, coef[hold_idx])
    return r.ravel(), j.reshape(-1, lay.size)


@dataclass
class AccelFit:
    """Result of ``fit_whole_unit_accel``."""

    model: WholeUnitAccelModel
    residual_rms: float            # m/s^2, RMS of |a| - g over windows
    chi2_dof: float
    robust_scale: float            # whitened units
    outlier_holds: list
    determined: dict               # label -> posterior ratio (all candidates)
    fixed: dict                    # name -> reason
    notes: list
    nfev: int
    cv: dict = field(default_factory=dict)   # held-out mean squared whitened residual


def window_sigma(windows):
    """Return the (m,) standard error of |mean accel| per window (m/s^2)."""
    u = windows.accel / np.linalg.norm(windows.accel, axis=1, keepdims=True)
    var = np.sum(u * u * np.maximum(windows.accel_var, 1e-30), axis=1) / windows.n
    return np.sqrt(var)


def fit_whole_unit_accel(windows, axis_temps, gravity, t0, priors=None, order=2,
                         scale_order=None, ratio=DETERMINED_RATIO, robust=True,
                         sigma_floor=0.0, select=True, cv_tolerance=CV_TOLERANCE,
                         residual='norm'):
    """Estimate the seed 002 accelerometer model from stationary windows (norm residual).

    windows: estimation.segments.Windows; axis_temps: (m, 3) degC (None: no temperature);
    gravity: m/s^2; t0: (3,) degC reference. ``order``/``scale_order``: maximum offset and
    scale polynomial orders in dT (candidates; the data decide which are determined).
    ``sigma_floor`` (m/s^2) is added in quadrature to each window's standard error (model
    error allowance). ``select``: drop optional terms (nonlinearity, 2nd-order and scale
    temperature terms) that leave-holds-out cross-validation does not support.
    ``residual``: 'norm' (|a| - g per window, the default) or 'vector' (a - g c_h per window
    and axis with the hold direction c_h eliminated: also uses that the direction of a
    hold does not change while its temperature does). Returns an AccelFit.
    """
    priors = priors or Priors()
    has_t = axis_temps is not None
    scale_order = order if scale_order is None else scale_order
    no, ns = (order, scale_order) if has_t else (0, 0)
    raw = np.asarray(windows.accel, float)
    dt = (np.asarray(axis_temps, float) - np.asarray(t0, float)) if has_t else \
        np.zeros_like(raw)
    if residual not in RESIDUALS:
        raise ValueError(f'residual must be one of {RESIDUALS}, not {residual!r}')
    sigma = np.sqrt(window_sigma(windows) ** 2 + sigma_floor ** 2)
    weight = 1.0 / np.sqrt(np.maximum(windows.accel_var, 1e-30) / windows.n[:, None]
                           + sigma_floor ** 2)
    lay = accel_layout(priors, no, ns, has_t)
    chains = [[lay.slices[f'ct{j}'].start + i for j in range(no + 1)] for i in range(3)] + \
        [[lay.slices[f'kt{j}'].start + i for j in range(1, ns + 1)] for i in range(3)]
    per_window = 3 if residual == 'vector' else 1

    def resid(p, rows=None, want_jac=False):
        """Whitened residuals (and Jacobian) of the selected windows (None: all)."""
        sl = np.arange(len(raw)) if rows is None else np.flatnonzero(rows)
        if residual == 'norm':
            r, j = _norm_residual(lay, p, raw[sl], dt[sl], sigma[sl], gravity, no, ns,
                                  want_jac)
        else:
            _, hidx = np.unique(windows.hold[sl], return_inverse=True)
            r, j = _vector_residual(lay, p, raw[sl], dt[sl], weight[sl], hidx,
                                    int(hidx.max()) + 1, gravity, no, ns, want_jac)
        return (r, j) if want_jac else r

    def run(free, base, with_prior, loss_robust, rows=None):
        return fit_free(lambda p, want_jac=False: resid(p, rows, want_jac), lay.std, base,
                        free, with_prior, loss_robust, max_nfev=MAX_NFEV,
                        **({'x_scale': 1.0} if loss_robust else {}))

    # 1. prior-regularised fit of every candidate: a point to judge observability at
    p1, res1 = run(lay.candidates, lay.mean, True, False)
    r1, jac1 = resid(p1, None, True)
    s = max(robust_scale(r1), 1.0)
    # 2. decide what the data determine
    free, ratios = decide_determined(lay, jac1, s, ratio, chains=chains)
    # 3. keep the optional terms only where held-out holds support them
    cv = {}
    if select:
        free, cv = _select_by_cv(lay, free, p1, run, resid, windows, ns, no, cv_tolerance)
    # 4. final fit of the determined parameters only, robust loss, no prior rows
    p0 = lay.mean.copy()
    p0[free] = p1[free]
    p, res = run(free, p0, False, robust)
    for what, result in (('prior-regularised', res1), ('final', res)):
        if not converged(result):
            raise FitNotConverged(
                f'the whole-unit accelerometer fit ({what}) did not converge in {MAX_NFEV} '
                f'evaluations ({result.message}) on {len(windows.hold_ids)} holds',
                'the holds do not determine its parameters well: use the standard fit '
                '(--model standard), or hold more poses, tilted ones included')
    r, jac = resid(p, None, True)
    scale = robust_scale(r) if robust else float(np.sqrt(np.mean(r * r)))
    idx = np.flatnonzero(free)
    dof = max(len(r) - len(idx), 1)
    chi2 = float(np.sum(r * r) / dof)
    jf = jac[:, idx]
    w = np.ones(len(r))
    if robust:
        w = (np.abs(r) <= getattr(res, 'f_scale', np.inf)).astype(float)
    try:
        cov = np.linalg.inv((jf * w[:, None]).T @ jf) * max(scale, 1.0) ** 2
        sd = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sd = np.full(len(idx), np.nan)
    std = lay.posterior_std(free, idx, sd)
    offset, scl, m0, m1, m2, m3 = _unpack(lay, p, no, ns)
    est = lay.masks(free)
    fixed = lay.reasons(free)
    model = WholeUnitAccelModel(
        t0, offset, scl, m0, m1, m2, m3,
        std={n: lay.get(std, n) for n in lay.names}, estimated=est, fixed=fixed,
        convention=FRAME_CONVENTION)
    holds_bad = group_outliers(r, np.repeat(windows.hold, per_window),
                               max(scale, 1.0)) if robust else []
    notes = _notes(lay, free, ratios, holds_bad)
    if NOT_CONVERGED_KEY in cv:
        notes.append(f'optional terms (A2, A3, kt, order >= 2) chosen by cross-validation in '
                     f'which {cv[NOT_CONVERGED_KEY]} fold fits stopped at {MAX_NFEV} '
                     'evaluations before converging: their held-out errors are taken where '
                     'they stopped, so that choice is uncertain')
    resid = (np.linalg.norm(model.correct(raw, np.asarray(t0) + dt), axis=1) - gravity)
    return AccelFit(model, float(np.sqrt(np.mean(resid ** 2))), chi2, float(scale),
                    holds_bad, {lay.label(i): v for i, v in ratios.items()}, fixed, notes,
                    int(getattr(res, 'nfev', 0) + res1.nfev), cv)


def hold_folds(windows, k=CV_FOLDS):
    """Return a fold id per window: holds in time order dealt round-robin into k folds."""
    ids, start = windows.hold_starts()
    order = np.argsort(start)
    fold_of = {int(ids[j]): r % k for r, j in enumerate(order)}
    return np.array([fold_of[int(h)] for h in windows.hold])


def _select_by_cv(lay, free, p1, run, resid, windows, ns, no, tol):
    """Backward selection of optional term groups by leave-holds-out cross-validation.

    A group (A2, A3, the scale temperature terms kt, the 2nd and higher order thermal
    terms) is dropped when the held-out mean squared whitened residual without it is not
    worse than with it by more than ``tol`` (relative): the simpler model wins ties.
    """
    n_holds = len(windows.hold_ids)
    if n_holds < 6:
        return free, {}
    folds = hold_folds(windows, min(CV_FOLDS, n_holds))
    idx_of = {n: np.arange(lay.slices[n].start, lay.slices[n].stop) for n in lay.names}
    groups = {'A2': idx_of['A2'], 'A3': idx_of['A3'],
              'kt': np.concatenate([idx_of[f'kt{j}'] for j in range(1, ns + 1)] or
                                   [np.zeros(0, int)]),
              'order>=2': np.concatenate([idx_of[f'ct{j}'] for j in range(2, no + 1)]
                                         + [idx_of[f'kt{j}'] for j in range(2, ns + 1)]
                                         or [np.zeros(0, int)])}
    groups = {g: i[free[i]] for g, i in groups.items() if np.any(free[i])}

    stopped = StoppedFolds()

    def cv_error(fr):
        base = lay.mean.copy()
        base[fr] = p1[fr]
        err = 0.0
        for f in np.unique(folds):
            test = folds == f
            p, res = run(fr, base, False, False, rows=~test)
            stopped.add(res)
            r = resid(p, test)
            err += float(np.sum(r * r))
        return err / len(folds)

    current = free.copy()
    best = cv_error(current)
    scores = {'all determined': best}
    while groups:
        trials = {}
        for g, i in groups.items():
            fr = current.copy()
            fr[i] = False
            trials[g] = cv_error(fr)
            scores[f'without {g}'] = trials[g]
        g = min(trials, key=trials.get)
        if trials[g] > best * (1.0 + tol):
            break
        current[groups.pop(g)] = False
        for i in np.flatnonzero(free & ~current):
            if lay.reason[i] is None:
                lay.reason[i] = CV_REASON
        best = min(best, trials[g])
    stopped.record(scores)
    return current, scores


def _notes(lay, free, ratios, holds_bad):
    """Human notes: which seed 002 parameters were fixed at their prior, and why."""
    notes = []
    groups = {}
    for i in range(lay.size):
        r = lay.reason[i]
        if free[i] or r is None or r.startswith(CONVENTION) or r == 'no temperature input':
            continue
        name, _ = lay.block_of(i)
        groups.setdefault((name, r == CV_REASON), []).append(lay.label(i))
    advice = {'A1': 'misalignment needs poses off the six faces (tilted / corner-up holds)',
              'A2': 'needs inputs of several magnitudes on each axis (1 g only spans '
                    '-g..+g; use tilted poses, or lab mode)',
              'A3': 'needs large inputs (a centrifuge, lab mode) to separate from scale',
              'ct0': 'hold each axis up and down', }
    for (name, by_cv), labels in groups.items():
        if by_cv:
            notes.append(f'accelerometer {", ".join(labels)}: determined, but held-out holds '
                         'do not support it (leave-holds-out cross-validation): fixed at the '
                         'prior')
            continue
        adv = advice.get(name, 'needs a wider temperature span seen in several poses'
                         if name.startswith(('ct', 'kt')) else '')
        notes.append(f'accelerometer {", ".join(labels)} not determined by the data: fixed at '
                     f'the prior ({adv})')
    if holds_bad:
        notes.append(f'holds {holds_bad} disagree with the others (bumped or moving?): '
                     'down-weighted by the robust loss')
    return notes
