"""Seed 002: whole-unit model of a MEMS IMU (Dai, Li, Su, Shao, OPE 2011), accel and gyro.

Accelerometer triad, eqs. (1)-(2), per sample (U raw output in m/s^2, T per-axis degC)::

    dT = T - T0
    V  = (U - c(T)) / (1 + k(T))            c(T) = sum_{j>=0} ct_j dT^j      (eq. 2)
                                            k(T) = sum_{j>=1} kt_j dT^j      (extension)
    a  = A0 + A1 V + A2 o V^2 + A3 o V^3                                      (eq. 1)

Gyroscope triad, eqs. (3)-(4), with the corrected specific force a (m/s^2) of the same
instant (``aux['accel']``) and a thermal input X (degC, or a proxy such as the drive-mode
resonance frequency, unit in ``meta['input_unit']``)::

    W  = (U_w - cw(X)) / (1 + kw(X))         cw(X) = sum_{j>=0} cw_j dX^j    (eq. 4)
    w  = Omega0 + Omega1 W + Omega2 o W^2 + Omega3 o W^3 + C a               (eq. 3)

``o`` is the element-wise product: the 2nd and 3rd order matrices of the paper are
diagonal, so they are stored as 3-vectors. All 63 coefficients of the paper are
represented (accel: ct0..ct2, A0, A1, A2, A3 = 27; gyro: cw0..cw2, Omega0..Omega3, C = 36);
``kt``/``kw`` are optional scale-factor temperature terms (seed 000 has them, seed 002 does
not; order 0 means absent). The paper writes the temperature polynomials in T itself;
here they are in dT = T - T0 (T0 = 0 reproduces the paper exactly), which keeps the fit
well conditioned.

Two exact redundancies exist and are removed by convention, never estimated:

* ct0 (cw0) against A0 (Omega0): shifting V by a constant re-expands the cubic into new
  A0..A2, so a field fit stores ct0 = 0 and puts the bias in A0. Lab mode (seed 002 3.1)
  fixes ct0 by the chamber step instead.
* the frame: a norm-only (gravity magnitude) fit cannot see a rotation of the output, so
  the field fit makes A1 lower-triangular (frame x = accelerometer x sensing axis, frame
  y in the plane of the x and y sensing axes; the seed 000 convention). The gyro Omega1
  is a full 3x3 matrix: its rotation relative to that frame is observable.

Parameters that the data could not determine are stored at their prior value with
``meta['estimated'][name]`` False (per element) and the reason in ``meta['fixed']``;
their ``std`` is the prior standard deviation (0 for a convention).
"""

import numpy as np

from .base import highest_power, Param, register, SensorModel


def _per_input(u, iu, j):
    """Return the unit of a coefficient of dX^j in a quantity of unit u (input unit iu)."""
    if j == 0:
        return u
    return f'{u}/{iu}' if j == 1 else f'{u}/{iu}^{j}'


def _inv_power(u, j):
    """Return the unit of the coefficient of V^j when V and the output have unit u."""
    return '1' if j == 1 else (f'1/({u})' if j == 2 else f'1/({u})^{j - 1}')


class _WholeUnitTriad(SensorModel):
    """Shared maths of the seed 002 accel and gyro triads (see the module docstring)."""

    #: parameter name stems: offset polynomial, scale polynomial, output polynomial
    stems = ('ct', 'kt', 'A')
    has_coupling = False

    def __init__(self, t0, offset, scale=None, m0=None, m1=None, m2=None, m3=None,
                 coupling=None, std=None, estimated=None, fixed=None, input_unit='degC',
                 convention=''):
        self.t0 = np.asarray(t0, float).reshape(3)
        #: (no + 1, 3) offset coefficients, row j multiplies dX^j
        self.offset = np.atleast_2d(np.asarray(offset, float)).reshape(-1, 3)
        #: (ns, 3) scale coefficients, row j - 1 multiplies dX^j (may have 0 rows)
        self.scale = (np.zeros((0, 3)) if scale is None
                      else np.asarray(scale, float).reshape(-1, 3))
        self.m0 = np.zeros(3) if m0 is None else np.asarray(m0, float).reshape(3)
        self.m1 = np.eye(3) if m1 is None else np.asarray(m1, float).reshape(3, 3)
        self.m2 = np.zeros(3) if m2 is None else np.asarray(m2, float).reshape(3)
        self.m3 = np.zeros(3) if m3 is None else np.asarray(m3, float).reshape(3)
        if self.has_coupling:
            self.coupling = (np.zeros((3, 3)) if coupling is None
                             else np.asarray(coupling, float).reshape(3, 3))
        else:
            self.coupling = None
        d = np.linalg.det(self.m1)
        if not np.isfinite(d) or abs(d) < 1e-6:
            raise ValueError(f'{self.kind}: the 3x3 coupling matrix is singular (det {d:.3g})')
        self.input_unit = str(input_unit)
        self.convention = str(convention)
        self.std = {k: np.asarray(v, float) for k, v in (std or {}).items()}
        self.estimated = {k: np.asarray(v, bool) for k, v in (estimated or {}).items()}
        self.fixed = dict(fixed or {})

    # ----------------------------------------------------------------- names
    @property
    def offset_order(self):
        """Return the order of the offset polynomial in dX."""
        return self.offset.shape[0] - 1

    @property
    def scale_order(self):
        """Return the order of the scale polynomial in dX (0: no scale temperature terms)."""
        return self.scale.shape[0]

    def temperature_degree(self):
        """Return the highest power of dX with a non-zero offset or scale term (0: none)."""
        return max(highest_power(self.offset[1:]), highest_power(self.scale))

    @property
    def raw_unit(self):
        """Return the unit of the raw and corrected signal."""
        return self.unit

    @property
    def ref_name(self):
        """Return the name of the reference input value: T0 for degC, X0 for a proxy."""
        return 'T0' if self.input_unit == 'degC' else 'X0'

    def names(self):
        """Return the parameter names in file order."""
        co, cs, cm = self.stems
        out = [self.ref_name] + [f'{co}{j}' for j in range(self.offset_order + 1)]
        out += [f'{cs}{j}' for j in range(1, self.scale_order + 1)]
        out += [f'{cm}{j}' for j in range(4)]
        if self.has_coupling:
            out.append('C')
        return out

    def values(self):
        """Return name -> value array (no units)."""
        co, cs, cm = self.stems
        v = {self.ref_name: self.t0}
        for j, row in enumerate(self.offset):
            v[f'{co}{j}'] = row
        for j, row in enumerate(self.scale, start=1):
            v[f'{cs}{j}'] = row
        for j, m in enumerate((self.m0, self.m1, self.m2, self.m3)):
            v[f'{cm}{j}'] = m
        if self.has_coupling:
            v['C'] = self.coupling
        return v

    def units(self):
        """Return name -> unit string."""
        co, cs, cm = self.stems
        u, iu = self.unit, self.input_unit
        out = {self.ref_name: iu}
        for j in range(self.offset_order + 1):
            out[f'{co}{j}'] = _per_input(u, iu, j)
        for j in range(1, self.scale_order + 1):
            out[f'{cs}{j}'] = _per_input('1', iu, j)
        out[f'{cm}0'] = u
        for j in (1, 2, 3):
            out[f'{cm}{j}'] = _inv_power(u, j)
        if self.has_coupling:
            out['C'] = 'rad/s/(m/s^2)'
        return out

    def descriptions(self):
        """Return name -> one-line description."""
        co, cs, cm = self.stems
        sig = 'accelerometer' if self.sensor == 'accel' else 'gyroscope'
        out = {self.ref_name: f'reference value of the thermal input per axis ({self.input_unit})'}
        for j in range(self.offset_order + 1):
            out[f'{co}{j}'] = (f'raw {sig} offset, coefficient of dX^{j} (seed 002 eq. '
                               f'{2 if self.sensor == "accel" else 4})')
        for j in range(1, self.scale_order + 1):
            out[f'{cs}{j}'] = f'relative scale change per dX^{j} (extension, as seed 000 k{j})'
        eq = 1 if self.sensor == 'accel' else 3
        out[f'{cm}0'] = f'output bias at V = 0 (eq. {eq})'
        out[f'{cm}1'] = f'scale factor, cross coupling and misalignment, 3x3 (eq. {eq})'
        out[f'{cm}2'] = f'2nd order scale-factor nonlinearity per axis (eq. {eq})'
        out[f'{cm}3'] = f'3rd order scale-factor nonlinearity per axis (eq. {eq})'
        if self.has_coupling:
            out['C'] = 'g-sensitivity: rate error per unit corrected specific force (eq. 3)'
        return out

    # ----------------------------------------------------------------- maths
    def _dx(self, temps):
        return np.asarray(temps, float) - self.t0

    def thermal(self, temps):
        """Return (offset c(X), relative scale 1 + k(X)), each (n, 3), at inputs (n, 3)."""
        dx = self._dx(temps)
        c = np.zeros_like(dx)
        for row in self.offset[::-1]:
            c = c * dx + row
        k = np.zeros_like(dx)
        for row in self.scale[::-1]:
            k = (k + row) * dx
        return c, 1.0 + k

    def output_poly(self, v):
        """Return A0 + A1 V + A2 V^2 + A3 V^3 for (n, 3) V (without the coupling term)."""
        return self.m0 + v @ self.m1.T + self.m2 * v * v + self.m3 * v * v * v

    def _coupling_term(self, aux, n):
        if self.coupling is None or not np.any(self.coupling):
            return 0.0
        acc = None if aux is None else aux.get('accel')
        if acc is None:
            raise ValueError(f'{self.kind}: the g-sensitivity term needs the corrected '
                             'specific force (aux["accel"], m/s^2); apply it through '
                             'Calibration.apply with an accelerometer model')
        acc = np.asarray(acc, float).reshape(n, 3)
        return acc @ self.coupling.T

    def correct(self, raw, temps, aux=None):
        """Return the corrected (n, 3) output for raw (n, 3) at thermal inputs (n, 3)."""
        raw = np.asarray(raw, float)
        c, k = self.thermal(temps)
        out = self.output_poly((raw - c) / k)
        return out + self._coupling_term(aux, raw.shape[0])

    def forward(self, true, temps, aux=None, iterations=8):
        """Return the raw (n, 3) output for a true input (the inverse of ``correct``).

        The cubic is inverted by a vectorised Newton iteration from the linear solution;
        it converges in a few steps for any physical coefficient size.
        """
        true = np.asarray(true, float)
        target = true - self._coupling_term(aux, true.shape[0])
        m1_inv = np.linalg.inv(self.m1)
        v = (target - self.m0) @ m1_inv.T
        if np.any(self.m2) or np.any(self.m3):
            for _ in range(iterations):
                f = self.output_poly(v) - target
                jac = self.m1[None] + np.einsum('ni,ij->nij', 2 * self.m2 * v
                                                + 3 * self.m3 * v * v, np.eye(3))
                step = np.linalg.solve(jac, f[..., None])[..., 0]
                v = v - step
                if np.max(np.abs(step)) < 1e-13 * max(1.0, float(np.max(np.abs(v)))):
                    break
        c, k = self.thermal(temps)
        return v * k + c

    def predict_std(self, temps):
        """Return the (n, 3) 1-sigma thermal-term and bias uncertainty (no correlations)."""
        co, cs, cm = self.stems
        names = [f'{co}{j}' for j in range(self.offset_order + 1)] + \
            [f'{cs}{j}' for j in range(1, self.scale_order + 1)] + [f'{cm}0']
        if not all(n in self.std for n in names):
            return None
        dx = self._dx(temps)
        full = 9.80665 if self.sensor == 'accel' else 1.0
        var = np.zeros_like(dx) + self.std[f'{cm}0'] ** 2
        for j in range(self.offset_order + 1):
            var += (self.std[f'{co}{j}'] * dx ** j) ** 2
        for j in range(1, self.scale_order + 1):
            var += (self.std[f'{cs}{j}'] * full * dx ** j) ** 2
        return np.sqrt(var)

    # ----------------------------------------------------------------- file
    def params(self):
        """Return every parameter with its unit, std and description."""
        units, desc = self.units(), self.descriptions()
        out = {}
        for name, value in self.values().items():
            std = self.std.get(name)
            out[name] = Param(np.asarray(value, float), units[name],
                              None if std is None else np.asarray(std, float), desc[name])
        return out

    def estimated_mask(self, name):
        """Return the per-element 'estimated from data' mask of a parameter (default True)."""
        shape = np.shape(self.values()[name])
        m = self.estimated.get(name)
        return np.ones(shape, bool) if m is None else np.broadcast_to(m, shape).copy()

    def meta(self):
        """Return orders, input unit, convention and the estimated/fixed bookkeeping."""
        est = {}
        for name in self.names():
            if name == self.ref_name:
                continue
            m = self.estimated_mask(name)
            est[name] = m.tolist()
        return {'paper': 'seed 002 (Dai, Li, Su, Shao 2011) eqs. '
                         + ('(1)-(2)' if self.sensor == 'accel' else '(3)-(4)'),
                'input_unit': self.input_unit, 'offset_order': self.offset_order,
                'scale_order': self.scale_order, 'convention': self.convention,
                'estimated': est, 'fixed': dict(self.fixed)}

    @classmethod
    def from_params(cls, params, meta):
        """Rebuild from file parameters and meta; raises ValueError naming what is wrong."""
        w = cls.kind
        co, cs, cm = cls.stems
        iu = str(meta.get('input_unit', 'degC'))
        ref = 'T0' if iu == 'degC' else 'X0'
        no = int(meta.get('offset_order', 2))
        ns = int(meta.get('scale_order', 0))

        def get(name, shape):
            if name not in params:
                raise ValueError(f'{w}: missing parameter {name!r}')
            v = params[name].value
            if v.shape != shape:
                raise ValueError(f'{w}: parameter {name!r} has shape {v.shape}, expected '
                                 f'{shape}')
            return v

        offset = np.stack([get(f'{co}{j}', (3,)) for j in range(no + 1)])
        scale = (np.stack([get(f'{cs}{j}', (3,)) for j in range(1, ns + 1)]) if ns
                 else np.zeros((0, 3)))
        ms = [get(f'{cm}0', (3,)), get(f'{cm}1', (3, 3)), get(f'{cm}2', (3,)),
              get(f'{cm}3', (3,))]
        coupling = get('C', (3, 3)) if cls.has_coupling else None
        std = {k: p.std for k, p in params.items() if p.std is not None}
        est = {k: np.asarray(v, bool) for k, v in (meta.get('estimated') or {}).items()}
        return cls(get(ref, (3,)), offset, scale, *ms, coupling=coupling, std=std,
                   estimated=est, fixed=meta.get('fixed') or {}, input_unit=iu,
                   convention=str(meta.get('convention', '')))

    def count(self):
        """Return (estimated, fixed) element counts over the seed 002 coefficients."""
        n_est = n_fix = 0
        for name in self.names():
            if name == self.ref_name:
                continue
            m = self.estimated_mask(name)
            n_est += int(m.sum())
            n_fix += int(m.size - m.sum())
        return n_est, n_fix


@register
class WholeUnitAccelModel(_WholeUnitTriad):
    """Seed 002 accelerometer triad: offset polynomial, 3x3 coupling, 2nd/3rd order terms."""

    kind = 'whole_unit_accel'
    sensor = 'accel'
    stems = ('ct', 'kt', 'A')
    has_coupling = False


@register
class WholeUnitGyroModel(_WholeUnitTriad):
    """Seed 002 gyroscope triad: offset polynomial, 3x3 coupling, nonlinearity, g-sensitivity C."""

    kind = 'whole_unit_gyro'
    sensor = 'gyro'
    stems = ('cw', 'kw', 'Omega')
    has_coupling = True
