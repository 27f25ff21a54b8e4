"""The standard static accelerometer fit: imu_tk's (Tedaldi et al., ICRA 2014) on every hold.

Per stationary window w of hold h (mean raw specific force u_w in m/s^2, temperature T_w in
degC of each axis' input)::

    a_w = L (u_w - b(T_w)),   b(T) = b_0 + sum_{j=1..J} b_j o (T - T0)^j
    r_w = sqrt(q_w) (|a_w| - g),   q_w = 1 / (number of windows of hold h)

L is lower-triangular (3 scale factors, 3 misalignments: frame x = accelerometer x
sensing axis, frame y in the x-y sensing plane; a norm-only fit cannot see a rotation of
the whole triad, imu_tk fixes it the same way with an upper-triangular matrix). Every hold
weighs the same, as each static interval gives imu_tk one residual, and nothing is left
out or down-weighted: this is the floor every richer model must beat held out
(``selection/select.py``). With a temperature input the bias may follow a polynomial in T
(the flight stacks' form, PX4/ArduPilot, on several poses); ``bias_order`` 0 is imu_tk.

Solved by ``scipy.optimize.least_squares`` (trust region, analytic Jacobian). The result
is a seed 002 ``WholeUnitAccelModel`` (ct = bias polynomial, A1 = L, A0 = A2 = A3 = 0), so
the calibration file, the compensator and the exports need nothing new. A fit that does
not converge, or whose Jacobian does not determine every parameter (too few or too similar
poses), raises ``StandardFitError`` with what to collect: never a silent half-fit.
"""

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..models.whole_unit import WholeUnitAccelModel
from .observability import converged, DETERMINED_RATIO, ORDER_SPAN, posterior_ratio, Priors

#: lower-triangular entries of L (row, column): the three diagonal scale factors first
TRI = ((0, 0), (1, 1), (2, 2), (1, 0), (2, 0), (2, 1))
#: names of the misalignment entries of L (rows 3..5 of the parameter vector)
MISALIGNMENT = ('L[y,x]', 'L[z,x]', 'L[z,y]')
#: iterations of one least-squares stage before the fit counts as not converged
MAX_NFEV = 500
#: ``axis_lever`` an axis needs for its bias and scale to count as determined: one pose
#: with the axis 45 deg above horizontal and one 45 deg below give 0.71, two at +-37 deg
#: 0.5; poses on one side of horizontal only give far less (five faces without -x: 0.12)
MIN_AXIS_LEVER = 0.5
#: floor (fraction of g) of a hold mean's noise in the observability decision (10 ug)
MIN_NOISE = 1e-5
#: smallest singular value of the column-scaled Jacobian, relative to the largest, for the
#: parameters to count as determined (1e-6: the fit resolves each parameter to ~1e-6 of
#: its scale, far below any sensor's noise)
MIN_CONDITION = 1e-6
FRAME_CONVENTION = ('L lower-triangular: frame x = accelerometer x sensing axis, frame y in '
                    'the plane of the x and y sensing axes (a norm-only fit cannot see a '
                    'rotation of the whole triad; imu_tk fixes it likewise)')


class StandardFitError(ValueError):
    """The standard fit cannot be made from these holds; the message says what to collect."""


@dataclass
class StandardFit:
    """A standard fit: the model, its per-window residuals and how the solver ended."""

    model: WholeUnitAccelModel
    #: (m,) |a| - g per window (m/s^2), unweighted
    residual: np.ndarray
    #: RMS over holds of the hold-mean residual (m/s^2), the imu_tk figure
    rms: float
    bias_order: int
    nfev: int
    message: str
    #: misalignment entries the holds do not determine (fixed at 0; e.g. six clean faces)
    undetermined: tuple = ()


def _unpack(p, bias_order):
    L = np.zeros((3, 3))
    for (i, j), v in zip(TRI, p[:6]):
        L[i, j] = v
    b = p[6:].reshape(bias_order + 1, 3)
    return L, b


def _bias(b, dt):
    out = np.zeros_like(dt)
    for row in b[::-1]:
        out = out * dt + row
    return out


def hold_weights(hold):
    """Return per-window weights that give every hold the same total weight (1)."""
    _, inv, counts = np.unique(hold, return_inverse=True, return_counts=True)
    return 1.0 / counts[inv]


def fit_standard(raw, hold, gravity, temps=None, t0=None, bias_order=0, noise=None):
    """Fit the standard model to window means; return a ``StandardFit``.

    raw: (m, 3) mean raw specific force per window (m/s^2); hold: (m,) hold ids; gravity:
    m/s^2; temps: (m, 3) per-axis temperature (degC) or None; t0: (3,) reference (degC);
    bias_order: highest power of (T - T0) in the bias (0 without temperature); noise:
    standard error of a
    hold's mean |a| (m/s^2; None: ``MIN_NOISE`` g), what decides which misalignments the
    holds determine (posterior/prior std ratio below ``DETERMINED_RATIO``).
    """
    raw = np.asarray(raw, float)
    m = len(raw)
    t0 = np.zeros(3) if t0 is None else np.asarray(t0, float)
    if temps is None or bias_order == 0:
        bias_order, dt = 0, np.zeros((m, 3))
    else:
        dt = np.asarray(temps, float) - t0
    sw = np.sqrt(hold_weights(hold))
    n_par = 6 + 3 * (bias_order + 1)
    ids, inv = np.unique(hold, return_inverse=True)
    n_holds = len(ids)
    if n_holds < 6:
        raise StandardFitError(f'{n_holds} holds cannot determine the bias and scale of '
                               'three axes: hold each axis up and down (the six faces), and '
                               'some tilted poses for the misalignment')
    # the lever of the poses, one per hold (window sums point where the hold's mean does)
    per_hold = np.stack([np.bincount(inv, raw[:, i]) for i in range(3)], 1)
    weak = weak_axes(per_hold / np.linalg.norm(per_hold, axis=1)[:, None])
    if weak:
        raise StandardFitError(f'the bias and scale factor of axis {",".join(weak)} are not '
                               f'determined by the {n_holds} holds: each axis must be held '
                               'pointing up and pointing down (or tilted well above and '
                               'below horizontal)')
    scale = gravity / np.median(np.linalg.norm(raw, axis=1))
    x0 = np.concatenate([np.full(3, scale), np.zeros(3), np.zeros(3 * (bias_order + 1))])

    def fun(p):
        L, b = _unpack(p, bias_order)
        a = (raw - _bias(b, dt)) @ L.T
        return sw * (np.linalg.norm(a, axis=1) - gravity)

    def jac(p):
        L, b = _unpack(p, bias_order)
        v = raw - _bias(b, dt)
        a = v @ L.T
        u = a / np.linalg.norm(a, axis=1)[:, None]          # d|a|/da
        J = np.zeros((m, n_par))
        for k, (i, j) in enumerate(TRI):
            J[:, k] = u[:, i] * v[:, j]
        uL = u @ L                                           # d|a|/dv
        for o in range(bias_order + 1):
            J[:, 6 + 3 * o:9 + 3 * o] = -uL * dt ** o
        return sw[:, None] * J

    # bias and scale (and the bias' temperature terms) first: determined by any set of
    # poses with each axis up and down; then each misalignment the data determine
    free = np.ones(n_par, bool)
    free[3:6] = False
    res, p = _solve(fun, jac, x0, free)
    _require_determined(jac(p)[:, free], n_holds)
    noise = max(MIN_NOISE * gravity, 0.0 if noise is None else float(noise))
    prior = _prior_std(bias_order)
    cand = free.copy()
    cand[3:6] = True
    while True:
        idx = np.flatnonzero(cand)
        ratio = posterior_ratio(jac(p)[:, idx], prior[idx], noise)
        mis = [k for k, i in enumerate(idx) if 3 <= i < 6]
        worst = max(mis, key=lambda k: ratio[k]) if mis else None
        if worst is None or ratio[worst] < DETERMINED_RATIO:
            break
        cand[idx[worst]] = False
    undetermined = [MISALIGNMENT[i - 3] for i in range(3, 6) if not cand[i]]
    if cand[3:6].any():
        res, p = _solve(fun, jac, p, cand)
    J = jac(p)
    _require_determined(J[:, cand], n_holds)
    L, b = _unpack(p, bias_order)
    if np.linalg.det(L) <= 0:
        raise StandardFitError('the standard fit found a mirrored axis (negative scale): '
                               'check the sign conventions of the IMU data')
    model = _model(L, b, t0, res, J, cand, undetermined)
    r = np.linalg.norm(model.correct(raw, t0 + dt), axis=1) - gravity
    return StandardFit(model, r, _hold_rms(r, hold), bias_order, int(res.nfev), res.message,
                       undetermined)


def axis_lever(up):
    """Return per axis the smallest singular value of the rows [u_i, u_i^2] (unit vectors).

    The first-order information on an axis' bias and scale: u_i and u_i^2 are the
    derivatives of |a| with respect to them (up to g). A pose with the axis horizontal adds
    nothing; one up and one down pose give sqrt(2); poses on one side only, or close to
    horizontal, little. Several holds of the same pose add in quadrature.
    """
    up = np.asarray(up, float)
    return np.array([np.linalg.svd(np.stack([up[:, i], up[:, i] ** 2], 1),
                                   compute_uv=False)[-1] for i in range(3)])


def weak_axes(up):
    """Return the axes ('x', 'y', 'z') whose bias and scale the poses ``up`` do not separate."""
    return ['xyz'[i] for i, v in enumerate(axis_lever(up)) if v < MIN_AXIS_LEVER]


def _solve(fun, jac, x0, free):
    """Least squares over the ``free`` parameters (the others stay at ``x0``)."""
    idx = np.flatnonzero(free)

    def full(z):
        p = x0.copy()
        p[idx] = z
        return p

    res = least_squares(lambda z: fun(full(z)), x0[idx], jac=lambda z: jac(full(z))[:, idx],
                        method='trf', x_scale='jac', xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=MAX_NFEV)
    if not converged(res):
        raise StandardFitError(f'the standard fit did not converge ({res.message}, '
                               f'{res.nfev} evaluations): the holds may not be still, or the '
                               'data not in m/s^2')
    return res, full(res.x)


def _require_determined(J, n_holds):
    col = np.linalg.norm(J, axis=0)
    s = np.linalg.svd(J / np.where(col > 0, col, 1.0), compute_uv=False)
    if col.min() == 0 or s[-1] < MIN_CONDITION * s[0]:
        raise StandardFitError(f'the {n_holds} holds do not determine bias and scale of '
                               'every axis (their directions are too similar): add holds '
                               'with each axis up and down')


def _prior_std(bias_order):
    """Return the prior std of every parameter (physical units; observability.Priors)."""
    p = Priors()
    tc = (p.accel_bias,) + tuple(p.accel_offset_tc)
    return np.concatenate([np.full(3, p.accel_scale), np.full(3, p.accel_misalignment)]
                          + [np.full(3, tc[min(j, len(tc) - 1)]) for j in
                             range(bias_order + 1)])


def _hold_rms(r, hold):
    ids, inv = np.unique(hold, return_inverse=True)
    w = hold_weights(hold)
    per_hold = np.bincount(inv, r * w) / np.bincount(inv, w)
    return float(np.sqrt(np.mean(per_hold ** 2)))


def _model(L, b, t0, res, J, free, undetermined):
    """Return the WholeUnitAccelModel of the solution, std from the Gauss-Newton covariance."""
    idx = np.flatnonzero(free)
    dof = max(len(res.fun) - len(idx), 1)
    s2 = float(np.sum(res.fun ** 2) / dof)
    sd = np.zeros(J.shape[1])
    try:
        sd[idx] = np.sqrt(np.maximum(np.diag(np.linalg.inv(J[:, idx].T @ J[:, idx])) * s2,
                                     0.0))
    except np.linalg.LinAlgError:
        sd[idx] = np.nan
    a1_sd = np.zeros((3, 3))
    for (i, j), v in zip(TRI, sd[:6]):
        a1_sd[i, j] = v
    order = b.shape[0] - 1
    std = {'A0': np.zeros(3), 'A1': a1_sd, 'A2': np.zeros(3), 'A3': np.zeros(3),
           **{f'ct{j}': sd[6 + 3 * j:9 + 3 * j] for j in range(order + 1)}}
    a1_est = np.zeros((3, 3), bool)
    for k, (i, j) in enumerate(TRI):
        a1_est[i, j] = bool(free[k])
    est = {'A0': np.zeros(3, bool), 'A1': a1_est, 'A2': np.zeros(3, bool),
           'A3': np.zeros(3, bool), **{f'ct{j}': np.ones(3, bool) for j in range(order + 1)}}
    fixed = {'A0': 'convention: the bias is carried by ct0 (imu_tk: L (u - b))',
             'A2': 'standard fit: linear model', 'A3': 'standard fit: linear model',
             'A1': FRAME_CONVENTION + ('' if not undetermined else '; ' + ', '.join(
                 undetermined) + ' not determined by the holds (e.g. six clean faces): '
                 'fixed at 0')}
    return WholeUnitAccelModel(t0, b, None, np.zeros(3), L, np.zeros(3), np.zeros(3),
                               std=std, estimated=est, fixed=fixed,
                               convention=FRAME_CONVENTION)


# ------------------------------------------------------------------------ estimator
def hold_noise(windows, gravity):
    """Return the typical standard error of a hold's mean |a| (m/s^2) from the windows."""
    se = np.sqrt(np.median(windows.accel_var, axis=0).sum() / max(float(np.sum(windows.n)), 1))
    return max(float(se) * np.sqrt(len(windows.hold_ids)), MIN_NOISE * gravity)


def bias_order(ctx):
    """Return the bias polynomial order the temperature span of the accel inputs allows."""
    if not ctx.k:
        return 0
    span = float(np.max(np.ptp(ctx.ta, axis=0)))
    order = 0
    for j in sorted(ORDER_SPAN):
        if span >= ORDER_SPAN[j]:
            order = j
    return min(order, ctx.options.order)


def fit_standard_context(ctx, rows=None):
    """Run ``fit_standard`` on the accelerometer windows of a ``calibrate.Context``.

    ``rows``: bool mask of the windows to fit (default all of ``ctx.accel_rows``).
    """
    w = ctx.windows
    m = np.ones(len(w), bool) if ctx.accel_rows is None else np.asarray(ctx.accel_rows, bool)
    if rows is not None:
        m = m & rows
    sub = w.select(m)
    order = bias_order(ctx)
    return fit_standard(sub.accel, sub.hold, ctx.options.gravity,
                        ctx.ta[m] if order else None, ctx.t0, order,
                        noise=hold_noise(sub, ctx.options.gravity))


def calibrated_magnitudes(ctx):
    """Return |a| of each hold mean after the standard fit to every hold (None: no fit)."""
    if ctx.n_orientations < 2:
        return None
    try:
        model = fit_standard_context(ctx).model
    except StandardFitError:
        return None
    w = ctx.windows
    ids, means = w.hold_means()
    temps = np.stack([np.average(ctx.ta[w.hold == h], axis=0, weights=w.n[w.hold == h])
                      for h in ids])
    return np.linalg.norm(model.correct(means, temps), axis=1)


def _register():
    """Register the ``standard`` estimator (imported by calibrate.ESTIMATOR_MODULES)."""
    from .calibrate import CalibrationRefused, Estimate, HOLD_MAGNITUDES, register_estimator
    from .options import hold_seconds
    HOLD_MAGNITUDES[0] = calibrated_magnitudes

    @register_estimator('standard')
    def estimate_standard(ctx):
        """Fit the standard static model (imu_tk): bias, scale, misalignment on every hold."""
        try:
            fit = fit_standard_context(ctx)
        except StandardFitError as e:
            missing = ' '.join(ctx.coverage['missing'])
            raise CalibrationRefused(
                str(e).split(': ')[0] + (f' (faces missing: {missing})' if missing else ''),
                (f'hold each missing face ({missing}) still for at least '
                 f'{hold_seconds(ctx.options.min_hold_s)} s, or ' if missing else '')
                + str(e).split(': ', 1)[-1]) from None
        notes = ['standard static fit (imu_tk, Tedaldi et al. 2014): bias, scale and '
                 'misalignment per axis from |a| = g on every hold, each hold weighted the '
                 'same' + (f'; bias polynomial of order {fit.bias_order} in temperature (the '
                           'flight stacks\' form)' if fit.bias_order else
                           '; temperature-independent' + ('' if ctx.k else
                                                          ' (no temperature input)'))]
        if fit.undetermined:
            notes.append(f'accelerometer misalignment {", ".join(fit.undetermined)} not '
                         'determined by the holds (gravity on the axes only, e.g. six clean '
                         'faces): fixed at 0; add tilted poses to estimate it')
        stats = {'residual_rms': {'value': fit.rms, 'unit': 'm/s^2'},
                 'standard': {'bias_order': fit.bias_order, 'evaluations': fit.nfev,
                              'solver': fit.message,
                              'undetermined': list(fit.undetermined)}}
        return Estimate(accel=fit.model, notes=notes, fit=stats)

    return estimate_standard


estimate_standard = _register()
