"""What every exporter shares: number formatting, the affine map of a model, refit samples.

Nothing here imports ROS. Units are SI throughout (m/s^2, rad/s, degC); losses are
reported in micro-g (accel, 1 ug = 9.80665e-6 m/s^2) and deg/h (gyro).
"""

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..calibration import CalibrationError
from ..gravity import STANDARD_GRAVITY
from ..models.field import FieldPolynomialModel
from ..models.polynomial import OffsetPolynomialModel
from ..models.whole_unit import _WholeUnitTriad

UG = STANDARD_GRAVITY * 1e-6          # m/s^2 per micro-g
DEG_PER_H = np.pi / 180.0 / 3600.0    # rad/s per deg/h
SIX_FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                     float)


class ExportRefused(CalibrationError):
    """The calibration cannot be written in the requested format; the message says why."""


@dataclass
class Exported:
    """Result of an exporter: file name suffix -> text, plus notes and the refit loss."""

    files: dict
    notes: List[str] = field(default_factory=list)
    #: per sensor: {'rms': x, 'max': y, 'unit': 'ug'|'deg/h', 'samples': n, 'what': ...}
    loss: dict = field(default_factory=dict)


def num(x, digits=15):
    """Return ``x`` rounded to ``digits`` significant digits, as text ('-0' becomes '0')."""
    s = f'{float(x):.{digits}g}'
    return '0' if s in ('-0', '0') else s


def rounded(a, digits=15):
    """Return an array rounded to ``digits`` significant digits of its largest element.

    Small elements (off-diagonal terms) are rounded at the same decimal as the largest, so
    an export -> import -> export round trip, whose arithmetic moves every element by a few
    ulp of the largest, writes the same text.
    """
    a = np.asarray(a, float)
    top = float(num(np.max(np.abs(a)) if a.size else 0.0, 6))
    if top == 0.0:
        return np.zeros_like(a)
    decimals = int(digits - 1 - np.floor(np.log10(top)))
    return np.round(a, decimals) + 0.0


def loss_unit(which):
    """Return (scale to the loss unit, unit name) for 'accel' or 'gyro'."""
    return (1.0 / UG, 'ug') if which == 'accel' else (1.0 / DEG_PER_H, 'deg/h')


def summarize_loss(which, diff, what):
    """Return the loss dict of an (n, 3) difference in SI units."""
    scale, unit = loss_unit(which)
    d = np.abs(np.asarray(diff, float)) * scale
    return {'rms': float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0,
            'max': float(d.max()) if d.size else 0.0, 'unit': unit, 'samples': int(len(d)),
            'what': what}


def parse_params(text, columns, name_col, value_col, form):
    """Return {name: float} of a parameter file; ``columns(line)`` splits a line (no comment).

    Lines that are empty or start with '#' are skipped; a line with fewer than
    ``max(name_col, value_col) + 1`` fields raises ValueError quoting ``form``.
    """
    out = {}
    need = max(name_col, value_col) + 1
    for ln, line in enumerate(text.splitlines(), 1):
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        parts = columns(line)
        if len(parts) < need:
            raise ValueError(f'line {ln} is not {form}')
        try:
            out[parts[name_col]] = float(parts[value_col])
        except ValueError:
            raise ValueError(f'line {ln}: {parts[value_col]!r} is not a number') from None
    return out


def cubic_offset(cal, which):
    """Return (T0, coefficients (4, 3) of dT^0..3) when the model is a cubic offset, else None.

    That is an ``offset_polynomial`` of order <= 3 with one reference for its three axes:
    what PX4 and ArduPilot hold exactly.
    """
    m = cal.accel if which == 'accel' else cal.gyro
    if (not isinstance(m, OffsetPolynomialModel) or m.order > 3
            or not np.all(m.t0 == m.t0[0])):
        return None
    c = np.zeros((4, 3))
    c[:m.order + 1] = m.coeffs
    return float(m.t0[0]), c


def exact_loss(which):
    """Return the loss dict of a model written exactly (nothing refitted)."""
    return {'rms': 0.0, 'max': 0.0, 'unit': loss_unit(which)[1], 'samples': 0,
            'what': 'exact'}


def loss_text(which, loss):
    """Return one line describing a loss dict."""
    if loss['what'] == 'exact':
        return f'{which}: written exactly (no refit)'
    verb = 'the static file loses' if loss['what'].startswith('static') else 'refit loses'
    if loss['max'] < 1e-6:
        return f'{which}: {verb} nothing measurable (< 1e-6 {loss["unit"]}; {loss["what"]})'
    return (f'{which}: {verb} {loss["rms"]:.3g} {loss["unit"]} RMS, {loss["max"]:.3g} '
            f'{loss["unit"]} max over {loss["samples"]} samples ({loss["what"]})')


# ----------------------------------------------------------------------- affine maps
def affine_map(model, temps, which):
    """Return (M, B, C, dropped) with corrected = M (raw - B) + C a at per-axis temps (3,).

    C is the gyro g-sensitivity (rad/s per m/s^2, zeros for accel); ``dropped`` describes
    terms the affine form cannot hold (2nd/3rd order output nonlinearity). Raises
    ExportRefused for a model that is not affine in the raw signal.
    """
    t = np.asarray(temps, float).reshape(1, 3)
    c = np.zeros((3, 3))
    dropped = ''
    if isinstance(model, FieldPolynomialModel):
        k, b = model.scale_bias(t)
        m = model._s_inv @ np.diag(1.0 / k[0])
        return m, b[0], c, dropped
    if isinstance(model, OffsetPolynomialModel):
        return np.eye(3), model.offset(t)[0], c, dropped
    if isinstance(model, _WholeUnitTriad):
        off, k = model.thermal(t)
        m = model.m1 @ np.diag(1.0 / k[0])
        b = off[0] - k[0] * np.linalg.solve(model.m1, model.m0)
        if model.coupling is not None:
            c = model.coupling.copy()
        if np.any(model.m2) or np.any(model.m3):
            full = STANDARD_GRAVITY if which == 'accel' else np.deg2rad(500.0)
            worst = np.max(np.abs(model.m2) * full ** 2 + np.abs(model.m3) * full ** 3)
            scale, unit = loss_unit(which)
            dropped = (f'the 2nd/3rd order output nonlinearity ({model.stems[2]}2, '
                       f'{model.stems[2]}3) is dropped: up to {worst * scale:.3g} {unit} at '
                       f'{"1 g" if which == "accel" else "500 deg/s"}')
        return m, b, c, dropped
    # any other family: numeric, if it is affine
    eye = np.eye(3)
    tt = np.repeat(t, 5, 0)
    pts = np.vstack([np.zeros(3), eye, 2 * eye[0]])[:5]
    try:
        out = model.correct(pts, tt, aux={'accel': np.zeros((5, 3))})
    except Exception as e:   # noqa: B902 - any family-specific failure means: not affine here
        raise ExportRefused(f'the {which} model ({model.kind}) cannot be evaluated as a '
                            f'matrix model ({e})') from None
    m = (out[1:4] - out[0]).T
    if not np.allclose(out[4], out[0] + 2 * m[:, 0], rtol=1e-9, atol=1e-12):
        raise ExportRefused(f'the {which} model ({model.kind}) is not affine in the raw '
                            'signal; it cannot be written as a matrix and a bias')
    b = -np.linalg.solve(m, out[0])
    return m, b, c, dropped


# ----------------------------------------------------------------------- samples
@dataclass
class Samples:
    """Raw and our corrected signals at known per-axis temperatures (for refits and losses)."""

    temps: np.ndarray           # (n, k) thermal inputs
    accel_raw: np.ndarray       # (n, 3) m/s^2
    gyro_raw: np.ndarray        # (n, 3) rad/s
    accel_ours: np.ndarray      # (n, 3) our compensated accel
    gyro_ours: np.ndarray       # (n, 3) our compensated gyro
    what: str


def samples(cal, windows=None, n_grid=41):
    """Return ``Samples`` from the calibration's own windows, else a grid.

    With ``windows`` (``Windows`` from ``calibrate --save-windows``) the raw signals are the
    window means and ours is ``cal.apply`` of them. Without, the valid range of each input
    is sampled at ``n_grid`` temperatures, and at each the six faces (1 g up) at rest are
    simulated through the models' ``forward`` (the inverse of the correction).
    """
    if windows is not None and len(windows):
        temps = np.asarray(windows.temp, float)
        comp = cal.apply(windows.accel, windows.gyro, temps)
        return Samples(temps, np.asarray(windows.accel, float), np.asarray(windows.gyro, float),
                       comp.accel, comp.gyro, f'the calibration\'s {len(windows)} windows')
    k = len(cal.inputs)
    if k:
        lo, hi = cal.valid_range[:, 0], cal.valid_range[:, 1]
        grid = lo + (hi - lo) * np.linspace(0.0, 1.0, n_grid)[:, None]
    else:
        grid = np.zeros((1, 0))
    temps = np.repeat(grid, len(SIX_FACES), 0)
    f = np.tile(SIX_FACES * cal.gravity, (len(grid), 1))
    w = np.zeros_like(f)
    acc, gyr = f, w
    try:
        if cal.accel is not None:
            ta, _ = cal.axis_temperatures(temps, 'accel')
            acc = cal.accel.forward(f, ta)
        if cal.gyro is not None:
            tg, _ = cal.axis_temperatures(temps, 'gyro')
            gyr = cal.gyro.forward(w, tg, aux={'accel': f})
    except NotImplementedError as e:
        raise ExportRefused(f'{e}: pass the calibration\'s windows (--windows FILE from '
                            '`calibrate --save-windows FILE`) to refit on them') from None
    comp = cal.apply(acc, gyr, temps)
    span = ('no temperature input' if not k else ', '.join(
        f'{a:.1f}..{b:.1f} {u}' for a, b, u in zip(lo, hi, cal.input_units)))
    return Samples(temps, acc, gyr, comp.accel, comp.gyro,
                   f'{len(grid)} temperatures over {span} x six faces at rest')


def single_input(cal, which, fmt):
    """Return the one degC input index the sensor's three axes use, or refuse."""
    idx = cal.accel_input if which == 'accel' else cal.gyro_input
    if not cal.inputs:
        raise ExportRefused(f'{fmt} needs a temperature input; this calibration has none')
    if len(set(idx)) != 1:
        raise ExportRefused(f'{fmt} uses one temperature per sensor; the {which} axes of this '
                            f'calibration follow inputs {list(idx)}; recalibrate with '
                            f'--{which}-input naming one topic')
    i = idx[0]
    if cal.inputs[i].unit != 'degC':
        raise ExportRefused(f'{fmt} compensates in degC but the {which} input '
                            f'{cal.inputs[i].topic} is in {cal.inputs[i].unit}')
    return i


def lag_note(cal, fmt):
    """Return a note when the calibration lags its inputs (the autopilots do not)."""
    if cal.temperature_filter is None:
        return []
    return [f'the calibration drives its models by a lagged temperature (thermal_input); '
            f'{fmt} uses the reading itself, so the lag is not exported']


def ageing_note(cal, fmt):
    """Return notes when the gyro bias is carried forward in time or moved by an offset."""
    ag = cal.gyro_ageing
    if not ag:
        return []
    notes = []
    if np.any(ag['rate']):
        rate = ', '.join(f'{v:+.3g}' for v in np.degrees(np.asarray(ag['rate'], float)) * 1e3)
        notes.append(f'gyro: the calibration carries its bias forward in time ({rate} '
                     f'mdeg/s per day from its epoch, at most {ag["max_days"]:.1f} days); '
                     f'{fmt} has no time term, so the exported bias is the one at the epoch: '
                     'recalibrate or export again as it ages')
    if ag.get('offset') is not None:
        off = ', '.join(f'{v:+.3g}' for v in np.degrees(np.asarray(ag['offset'], float)) * 1e3)
        notes.append(f'gyro: the exported bias includes the offset the recent holds gave '
                     f'({off} mdeg/s, a lifelong node\'s follower): it is the bias of that '
                     'time; export again as it moves')
    return notes


def history_note(cal, fmt):
    """Return notes when a model uses the thermal history, with the loss of dropping it.

    PX4 and ArduPilot hold a cubic of the reading; the exporters refit the model at thermal
    equilibrium (history terms zero). The calibration's ``fit.selection.export_loss``
    (``selection.time_folds``) says what that costs on the held-out blocks of the
    calibration log's own thermal history.
    """
    notes = []
    loss = ((cal.fit or {}).get('selection') or {}).get('export_loss') or {}
    for which in ('accel', 'gyro'):
        model = cal.accel if which == 'accel' else cal.gyro
        keys = getattr(model, 'history_keys', ())
        if not keys:
            continue
        text = (f'{which}: the model uses the thermal history ({", ".join(keys)}); {fmt} '
                'compensates with the reading only, so the cubic is refitted at thermal '
                'equilibrium and the history terms are dropped')
        lo = loss.get(which)
        if lo:
            a, b = lo['model'], lo['as_cubic_without_history']
            text += (f': held-out drift on held-out blocks of the calibration log '
                     f'{a:.3g} -> {b:.3g} {lo["unit"]} ({100 * (b / a - 1):+.0f} %)'
                     if a > 0 else '')
        notes.append(text)
    return notes


def offset_refit(cal, which, smp, columns, fmt):
    """Least-squares fit of an offset polynomial y = raw - L ours on the samples.

    ``columns(t)`` returns the (n, p) design for temperatures t (n,) of the sensor's
    input. L is the model's scale/misalignment at its reference (the autopilot's own static
    calibration holds it; identity for an offset model). Returns (coeffs (p, 3), L,
    residual (n, 3)).
    """
    model = cal.accel if which == 'accel' else cal.gyro
    i = single_input(cal, which, fmt)
    raw = smp.accel_raw if which == 'accel' else smp.gyro_raw
    ours = smp.accel_ours if which == 'accel' else smp.gyro_ours
    if isinstance(model, OffsetPolynomialModel):
        lin = np.eye(3)
    else:
        m, _, _, _ = affine_map(model, model.t0, which)
        lin = np.linalg.inv(m)
    y = raw - ours @ lin.T
    t = smp.temps[:, i]
    lo, hi = cal.own_range(which)[i]
    if cal.range_policy(which) != 'extrapolate':    # linear: the samples stay inside
        t = np.clip(t, lo, hi)
    design = columns(t)
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return coef, lin, y - design @ coef


def lq(m):
    """Return (L, Q) with m = L Q, L lower-triangular with a positive diagonal, Q orthogonal."""
    q, r = np.linalg.qr(np.asarray(m, float).T)     # m^T = Q R  ->  m = R^T Q^T
    sign = np.sign(np.diag(r))
    sign[sign == 0] = 1.0
    lower = (r * sign[:, None]).T
    lower[np.triu_indices(3, 1)] = 0.0
    return lower, (q * sign[None, :]).T


def is_identity(m, tol=1e-12):
    """Return True when a matrix is the identity to ``tol``."""
    return bool(np.allclose(m, np.eye(3), rtol=0, atol=tol))


def check_out(cal, which, fmt) -> Optional[str]:
    """Return a note when ``which`` is not clamped outside its range (the autopilots clamp)."""
    policy = cal.range_policy(which)
    if policy != 'clamp':
        how = 'extrapolates' if policy == 'extrapolate' else 'continues linearly'
        return (f'{fmt} clamps the temperature to TMIN..TMAX; this calibration {how} '
                f'outside its valid range ({which})')
    return None
