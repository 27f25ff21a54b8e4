"""Seed 003: Relevance Vector Machine thermal model (Ning et al.), per axis.

Per axis i with normalised input ``x = 2 (T_i - x_min_i) / (x_max_i - x_min_i) - 1``
(eq. 34) and the mixed kernel of eq. 33, the RVM output in normalised units is::

    y_n = w0 + sum_j w_j K(x, rv_j)  +  u (v0 + sum_j v_j K(x, rs_j))

(eqs. 7, 30) where ``rv``/``rs`` are the relevance vectors of the bias- and scale-type
parts (in the input unit: degC, or a proxy's unit such as Hz) and ``u`` the axis' share
of gravity; ``y = y_min + (y_n + 1) (y_max - y_min)/2``.
Two modes:

* ``offset`` (single orientation, gyro bias): only the bias part; ``corrected = raw -
  (y(T) - y(T_ref))`` when the constant is not observable (``offset_only``), else
  ``raw - y(T)``;
* ``bias_scale`` (multi-position data, seed 003 sect. 3 generalised): with the prior
  ``k0, b0, S`` (seed 000 notation) ``raw_i = (k0_i + dk_i(T)) (S f)_i + b0_i + b_i(T)``,
  ``b_i(T) = y_min + (1 + bias part) h``, ``dk_i(T) = h (scale part) / g``, h the half range;
  the correction inverts it exactly.

``cov_<axis>`` is the posterior covariance of the normalised weights (eq. 16) over the
columns ``[w0, w_j..., v0, v_j...]``; the predictive variance of the mean function is
``h^2 phi^T cov phi`` (eq. 31 without the noise term, which ``noise_std`` holds).
``predict_std`` adds ``misfit_std``, the part of the training residual that white noise
does not explain. Evaluated vectorised at IMU rate: on the distinct temperatures of a
chunk, or on a 0.001-degC grid (a proxy: 5e-5 of its normalisation range) with linear
interpolation when that is fewer points.
"""

import numpy as np

from ..input_units import is_temperature
from .base import input_unit_of, Param, register, require, SensorModel, with_input_unit

AXES = 'xyz'
KERNEL_TEXT = 'lambda exp(-|x - xi|^2 / (2 sigma2)) + (1 - lambda) (x xi + 1)^d, x in [-1, 1]'
MODES = ('offset', 'bias_scale')
#: long chunks are evaluated on this temperature grid and interpolated (see _per_axis)
GRID_STEP_DEGC = 1e-3
#: the same for a proxy input, as a fraction of the axis' normalisation range x_max - x_min
GRID_STEP_FRACTION = 5e-5


def kernel(x, c, sigma2, d, lam):
    """Return the (n, m) mixed kernel of eq. 33 at normalised inputs and centres."""
    x = np.asarray(x, float)[:, None]
    c = np.asarray(c, float)[None, :]
    out = np.zeros((x.shape[0], c.shape[1]))
    if lam > 0:
        diff = x - c
        out += lam * np.exp(diff * diff * (-0.5 / sigma2))
    if lam < 1:
        base = x * c + 1.0
        poly = base.copy()
        for _ in range(int(d) - 1):       # integer power by products (faster than **)
            poly *= base
        out += (1.0 - lam) * poly
    return out


class RvmAxis:
    """One axis: relevance vectors (input unit), normalised weights and their covariance."""

    def __init__(self, rv_bias, w_bias, rv_scale=None, w_scale=None, cov=None):
        self.rv_bias = np.asarray(rv_bias, float).reshape(-1)
        self.w_bias = np.asarray(w_bias, float).reshape(-1)     # [w0, w_j...]
        if self.w_bias.shape[0] != self.rv_bias.shape[0] + 1:
            raise ValueError('w_bias needs one weight per bias relevance vector plus w0')
        self.has_scale = rv_scale is not None
        self.rv_scale = np.zeros(0) if rv_scale is None else np.asarray(rv_scale,
                                                                        float).reshape(-1)
        self.w_scale = np.zeros(0) if w_scale is None else np.asarray(w_scale,
                                                                      float).reshape(-1)
        if self.has_scale and self.w_scale.shape[0] != self.rv_scale.shape[0] + 1:
            raise ValueError('w_scale needs one weight per scale relevance vector plus v0')
        p = self.w_bias.shape[0] + self.w_scale.shape[0]
        self.cov = np.zeros((p, p)) if cov is None else np.asarray(cov, float).reshape(p, p)

    def features(self, xn, norm_rv, kern):
        """Return (bias design (n, 1+mb), scale design (n, 1+ms)) at normalised inputs."""
        rb, rs = norm_rv
        n = xn.shape[0]
        fb = np.concatenate([np.ones((n, 1)), kernel(xn, rb, *kern)], 1)
        fs = np.concatenate([np.ones((n, 1)), kernel(xn, rs, *kern)], 1) if self.has_scale \
            else np.zeros((n, 0))
        return fb, fs


@register
class RvmModel(SensorModel):
    """Per-axis RVM of bias (and scale factor) vs temperature; units follow the sensor."""

    kind = 'rvm'

    def __init__(self, axes, x_range, y_range, kernels, mode='offset', sensor='accel',
                 offset_only=False, t_ref=None, k0=None, b0=None, s=None, noise_std=None,
                 misfit_std=None, gravity=9.80665, input_unit='degC'):
        self.input_unit = str(input_unit)
        if mode not in MODES:
            raise ValueError(f'RVM mode {mode!r} is not one of {MODES}')
        if len(axes) != 3:
            raise ValueError('an RVM model needs three axes')
        self.axes = list(axes)
        self.x_range = np.asarray(x_range, float).reshape(3, 2)    # input unit
        self.y_range = np.asarray(y_range, float).reshape(3, 2)    # sensor unit
        self.kernels = np.asarray(kernels, float).reshape(3, 3)     # sigma2, d, lambda
        if np.any(self.kernels[:, 0] <= 0) or np.any((self.kernels[:, 2] < 0)
                                                     | (self.kernels[:, 2] > 1)):
            raise ValueError('kernel sigma2 must be > 0 and lambda in [0, 1]')
        self.mode = mode
        self.sensor = sensor
        self.offset_only = bool(offset_only)
        self.t_ref = np.zeros(3) if t_ref is None else np.asarray(t_ref, float).reshape(3)
        self.k0 = np.ones(3) if k0 is None else np.asarray(k0, float).reshape(3)
        self.b0 = np.zeros(3) if b0 is None else np.asarray(b0, float).reshape(3)
        self.s = np.eye(3) if s is None else np.asarray(s, float).reshape(3, 3)
        self._s_inv = np.linalg.inv(self.s)
        self.noise_std = np.zeros(3) if noise_std is None else np.asarray(noise_std,
                                                                          float).reshape(3)
        self.misfit_std = np.zeros(3) if misfit_std is None else np.asarray(misfit_std,
                                                                            float).reshape(3)
        self.gravity = float(gravity)
        if mode == 'bias_scale' and not all(a.has_scale for a in self.axes):
            raise ValueError('bias_scale mode needs scale weights on every axis')

    # ------------------------------------------------------------------ evaluation
    @property
    def t0(self):
        """Return the reference temperature (used when a calibration has no inputs)."""
        return self.t_ref

    @property
    def kernel_list(self):
        """Return the per-axis kernels as (sigma2, d, lambda) tuples (to refit weights)."""
        return [(float(k[0]), int(k[1]), float(k[2])) for k in self.kernels]

    @property
    def half_range(self):
        """Return h = (y_max - y_min) / 2 per axis (target unit)."""
        return 0.5 * (self.y_range[:, 1] - self.y_range[:, 0])

    def _norm(self, a, temps):
        lo, hi = self.x_range[a]
        span = hi - lo if hi > lo else 1.0
        return 2.0 * (np.asarray(temps, float) - lo) / span - 1.0

    def _axis_eval(self, a, t):
        """Return (bias (n,), scale change dk (n,), variance pieces) on distinct temps t."""
        ax = self.axes[a]
        kern = (self.kernels[a, 0], int(self.kernels[a, 1]), self.kernels[a, 2])
        xn = self._norm(a, t)
        fb, fs = ax.features(xn, (self._norm(a, ax.rv_bias), self._norm(a, ax.rv_scale)), kern)
        h = self.half_range[a]
        bias = self.y_range[a, 0] + h * (1.0 + fb @ ax.w_bias)
        dk = h * (fs @ ax.w_scale) / self.gravity if ax.has_scale else np.zeros(len(t))
        return bias, dk, fb, fs

    def _per_axis(self, temps, fn):
        """Evaluate ``fn(axis, temperatures)`` per axis on distinct values or a fine grid.

        Long chunks of slowly varying (e.g. lagged, all distinct) temperatures are
        evaluated on a GRID_STEP_DEGC grid and linearly interpolated: the error is
        step^2/8 times the curvature, below 1e-9 of the output for these kernels.
        """
        temps = np.asarray(temps, float)
        out = []
        for a in range(3):
            col = temps[:, a]
            lo, hi = (float(col.min()), float(col.max())) if len(col) else (0.0, 0.0)
            step = (GRID_STEP_DEGC if is_temperature(self.input_unit) else
                    max(GRID_STEP_FRACTION * float(np.ptp(self.x_range[a])), 1e-12))
            m = int((hi - lo) / step) + 2
            if m < len(col) // 2:
                grid = lo + np.arange(m) * step
                out.append(tuple(np.interp(col, grid, r) for r in fn(a, grid)))
                continue
            uniq, inv = np.unique(col, return_inverse=True)
            res = fn(a, uniq)
            out.append(tuple(r[inv] for r in res))
        return out

    def bias_scale(self, temps):
        """Return (bias (n, 3) in the sensor unit, scale change dk (n, 3)) at inputs (n, 3)."""
        res = self._per_axis(temps, lambda a, t: self._axis_eval(a, t)[:2])
        bias = np.stack([r[0] for r in res], 1)
        dk = np.stack([r[1] for r in res], 1)
        if self.offset_only:
            ref = self._per_axis(self.t_ref[None, :], lambda a, t: self._axis_eval(a, t)[:2])
            bias = bias - np.array([r[0][0] for r in ref])
        return bias, dk

    def correct(self, raw, temps, aux=None):
        """Return the corrected (n, 3) signal for raw (n, 3) at per-axis thermal inputs (n, 3)."""
        bias, dk = self.bias_scale(temps)
        raw = np.asarray(raw, float)
        if self.mode == 'offset':
            return raw - bias
        return ((raw - self.b0 - bias) / (self.k0 + dk)) @ self._s_inv.T

    def forward(self, true, temps, aux=None):
        """Return the raw output (n, 3) this model predicts for a true input (n, 3)."""
        bias, dk = self.bias_scale(temps)
        true = np.asarray(true, float)
        if self.mode == 'offset':
            return true + bias
        return (self.k0 + dk) * (true @ self.s.T) + self.b0 + bias

    def _axis_var(self, a, t):
        """Return the variance (n,) of the modelled error at distinct temps, worst pose."""
        ax = self.axes[a]
        _, _, fb, fs = self._axis_eval(a, t)
        if self.offset_only:
            _, _, fr, _ = self._axis_eval(a, self.t_ref[a:a + 1])
            fb = fb - fr
        h = self.half_range[a]
        nb = fb.shape[1]
        cb = ax.cov[:nb, :nb]
        var = np.sum((fb @ cb) * fb, axis=1)
        if ax.has_scale:   # |u| <= 1: the worse sign of the bias/scale cross term
            cs = ax.cov[nb:, nb:]
            cx = ax.cov[:nb, nb:]
            cross = np.sum((fb @ cx) * fs, axis=1)
            var = var + np.sum((fs @ cs) * fs, axis=1) + 2 * np.abs(cross)
        return (h * h * np.maximum(var, 0.0) + self.misfit_std[a] ** 2,)

    def predict_std(self, temps):
        """Return the (n, 3) 1-sigma uncertainty of the modelled error (mean + misfit).

        The white noise of single samples is not included (the calibration adds it).
        """
        res = self._per_axis(temps, self._axis_var)
        return np.sqrt(np.stack([r[0] for r in res], 1))

    def predictive_std(self, temps):
        """Return eq. 31: the std of a new training-like observation (adds noise_std)."""
        return np.sqrt(self.predict_std(temps) ** 2 + self.noise_std ** 2)

    # ------------------------------------------------------------------ file
    def params(self):
        """Return normalisation, kernel, relevance vectors, weights and covariances."""
        u, iu = self.unit, self.input_unit
        out = {
            'x_min': Param(self.x_range[:, 0], iu, description='input normalisation '
                           'minimum per axis (eq. 34)'),
            'x_max': Param(self.x_range[:, 1], iu, description='input normalisation '
                           'maximum per axis (eq. 34)'),
            'y_min': Param(self.y_range[:, 0], u, description='target normalisation minimum'),
            'y_max': Param(self.y_range[:, 1], u, description='target normalisation maximum'),
            'sigma2': Param(self.kernels[:, 0], '1', description='Gaussian kernel width '
                            'sigma^2 on normalised input (eq. 33)'),
            'd': Param(self.kernels[:, 1], '1', description='polynomial kernel degree'),
            'lambda': Param(self.kernels[:, 2], '1', description='kernel mixing weight'),
            'noise_std': Param(self.noise_std, u, description='RVM noise sigma_MP of a '
                               'training point (eq. 27)'),
            'misfit_std': Param(self.misfit_std, u, description='training residual not '
                                'explained by white noise (model error)'),
            'T_ref': Param(self.t_ref, iu, description=('reference temperature' if iu == 'degC'
                                                        else f'reference input ({iu})')
                           + ' (offset only: the drift is relative to the output here)'),
        }
        if self.mode == 'bias_scale':
            out['k0'] = Param(self.k0, '1', description='prior scale factor')
            out['b0'] = Param(self.b0, u, description='prior bias')
            out['S'] = Param(self.s, '1', description='prior non-orthogonality')
        for a, ax in zip(AXES, self.axes):
            nb = ax.w_bias.shape[0]
            std = np.sqrt(np.maximum(np.diag(ax.cov), 0.0))
            out[f'rv_bias_{a}'] = Param(ax.rv_bias, iu,
                                        description=f'bias relevance vectors, axis {a}')
            out[f'w_bias_{a}'] = Param(ax.w_bias, '1', std[:nb], description=f'normalised '
                                       f'bias weights [w0, w_j], axis {a}')
            if ax.has_scale:
                out[f'rv_scale_{a}'] = Param(ax.rv_scale, iu,
                                             description=f'scale relevance vectors, axis {a}')
                out[f'w_scale_{a}'] = Param(ax.w_scale, '1', std[nb:], description=f'normalised'
                                            f' scale weights [v0, v_j], axis {a}')
            out[f'cov_{a}'] = Param(ax.cov, '1', description=f'posterior covariance of the '
                                    f'normalised weights (eq. 16), axis {a}')
        return out

    def meta(self):
        """Return the mode, the kernel formula and the paper reference."""
        return with_input_unit({'mode': self.mode, 'offset_only': self.offset_only,
                                'kernel': KERNEL_TEXT, 'gravity': self.gravity,
                                'paper': 'seed 003 eqs. (7), (16), (30)-(34)'}, self.input_unit)

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters."""
        w = cls.kind
        mode = str(meta.get('mode', 'offset'))
        axes = []
        for a in AXES:
            if f'rv_bias_{a}' not in params or f'w_bias_{a}' not in params:
                raise ValueError(f'{w}: missing relevance vectors or weights of axis {a}')
            rb = params[f'rv_bias_{a}'].value
            wb = require(params, f'w_bias_{a}', (rb.shape[0] + 1,), w)
            rs = ws = None
            if mode == 'bias_scale':
                rs = params[f'rv_scale_{a}'].value if f'rv_scale_{a}' in params else None
                if rs is None:
                    raise ValueError(f'{w}: missing scale relevance vectors of axis {a}')
                ws = require(params, f'w_scale_{a}', (rs.shape[0] + 1,), w)
            p = wb.shape[0] + (0 if ws is None else ws.shape[0])
            cov = require(params, f'cov_{a}', (p, p), w) if f'cov_{a}' in params else None
            axes.append(RvmAxis(rb, wb, rs, ws, cov))
        x_range = np.stack([require(params, 'x_min', (3,), w), require(params, 'x_max', (3,), w)],
                           1)
        y_range = np.stack([require(params, 'y_min', (3,), w), require(params, 'y_max', (3,), w)],
                           1)
        kern = np.stack([require(params, n, (3,), w) for n in ('sigma2', 'd', 'lambda')], 1)
        opt = {}
        for name in ('k0', 'b0', 'noise_std', 'misfit_std'):
            if name in params:
                opt[name] = require(params, name, (3,), w)
        if 'S' in params:
            opt['s'] = require(params, 'S', (3, 3), w)
        t_ref = require(params, 'T_ref', (3,), w) if 'T_ref' in params else None
        return cls(axes, x_range, y_range, kern, mode=mode,
                   offset_only=bool(meta.get('offset_only', False)), t_ref=t_ref,
                   gravity=float(meta.get('gravity', 9.80665)),
                   input_unit=input_unit_of(params, meta, 'x_min'), **opt)
