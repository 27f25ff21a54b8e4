"""Lab mode (seed 002 section 3.1, as written): chamber, turntable and centrifuge.

Known reference inputs come with the log as a *schedule*: one row per segment with its
stage, time span, averaging group and the true specific force f (m/s^2) and angular rate
w (rad/s, earth rate included if it matters) in the sensor (fixture) frame. The 63
coefficients of ``models.whole_unit`` are solved by linear least squares in the paper's
three steps:

1. chamber (eqs. 2, 4): the unit rests in one pose while the temperature steps; per axis
   ``U = ct0 + ct1 dT + ct2 dT^2`` (accel) and ``U_w = cw0 + cw1 dX + cw2 dX^2`` (gyro, X
   the gyro thermal input, e.g. its resonance frequency) -> 18 coefficients;
2. turntable (eqs. 5, 6): ``V_w = U_w - cw(X)``; the outputs of the segments of one group
   with the same true rate are averaged (opposite poses: gravity, hence C a, cancels),
   then per axis ``w_i = Omega0_i + Omega1_i . V + Omega2_i V_i^2 + Omega3_i V_i^3``
   -> 18 coefficients;
3. centrifuge (eqs. 7-10): ``V_a = U - ct(T)``; per axis ``a_i = A0_i + A1_i . V + A2_i
   V_i^2 + A3_i V_i^3`` -> 18 coefficients; then the residual of the turntable gyro model
   on the centrifuge segments, ``R = w - (Omega0 + Omega1 V_w + ...)``, gives ``C`` from
   ``C a = R`` -> 9 coefficients.

Convention (from the paper's procedure): ct0 and cw0 are what the chamber fit gives, so
they include the raw output in the chamber pose, and A0/Omega0 are the outputs at V = 0,
i.e. the chamber-pose inputs (``a_chamber``, ``w_chamber - C a_chamber``). The
polynomials are in dT = T - T0 with T0 the mean chamber input (T0 = 0 is the paper's form
literally; the shift only re-expands the polynomial). A stage whose design is rank
deficient is refused with what to collect; every coefficient of the result is estimated.

Schedule files:

* CSV with a header ``stage,t_start,t_end,group,f_x,f_y,f_z,w_x,w_y,w_z[,label]``;
* YAML ``{time_origin: first_sample | stamp, segments: [{stage, t_start, t_end, group,
  specific_force: [x, y, z], rate: [x, y, z], label}]}``.

Times are seconds from the first IMU sample (``time_origin: first_sample``, the CSV
default) or absolute header stamps in seconds (``stamp``).
"""

import csv
import os
from dataclasses import dataclass, field
from typing import List

import numpy as np
import yaml

from ..models.whole_unit import WholeUnitAccelModel, WholeUnitGyroModel

STAGES = ('chamber', 'turntable', 'centrifuge')


class LabError(ValueError):
    """A lab schedule or log that cannot give the coefficients; the message says why."""


@dataclass
class Segment:
    """One scheduled segment with its known inputs (sensor frame, SI)."""

    stage: str
    t_start: float
    t_end: float
    group: int = 0
    f: np.ndarray = field(default_factory=lambda: np.zeros(3))     # m/s^2
    w: np.ndarray = field(default_factory=lambda: np.zeros(3))     # rad/s
    label: str = ''


@dataclass
class Schedule:
    """Segments plus how their times are given."""

    segments: List[Segment]
    time_origin: str = 'first_sample'

    def table(self):
        """Return (stage (m,), t0 (m,), t1 (m,), group (m,), f (m, 3), w (m, 3))."""
        s = self.segments
        return (np.array([x.stage for x in s]), np.array([x.t_start for x in s]),
                np.array([x.t_end for x in s]), np.array([x.group for x in s]),
                np.array([x.f for x in s]).reshape(-1, 3),
                np.array([x.w for x in s]).reshape(-1, 3))


def _check_segments(segs, source):
    for i, s in enumerate(segs):
        if s.stage not in STAGES:
            raise LabError(f'{source}: segment {i} has stage {s.stage!r}; use one of {STAGES}')
        if not s.t_end > s.t_start:
            raise LabError(f'{source}: segment {i} ends before it starts '
                           f'({s.t_start} .. {s.t_end} s)')
        if np.linalg.norm(s.f) > 2000 or np.linalg.norm(s.w) > 200:
            raise LabError(f'{source}: segment {i} inputs |f| = {np.linalg.norm(s.f):.4g}, '
                           f'|w| = {np.linalg.norm(s.w):.4g} are not in m/s^2 and rad/s')


def read_schedule(path):
    """Read a CSV or YAML schedule (see the module docstring); raises LabError."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise LabError(f'schedule {path!r} does not exist')
    if path.endswith(('.yaml', '.yml')):
        with open(path) as f:
            d = yaml.safe_load(f) or {}
        try:
            segs = [Segment(str(s['stage']), float(s['t_start']), float(s['t_end']),
                            int(s.get('group', 0)),
                            np.asarray(s.get('specific_force', [0, 0, 0]), float).reshape(3),
                            np.asarray(s.get('rate', [0, 0, 0]), float).reshape(3),
                            str(s.get('label', '')))
                    for s in d.get('segments') or []]
        except (KeyError, TypeError, ValueError) as e:
            raise LabError(f'{path}: bad segment ({e.__class__.__name__}: {e})') from None
        origin = str(d.get('time_origin', 'first_sample'))
    else:
        with open(path, newline='') as f:
            rows = list(csv.DictReader(f))
        need = ('stage', 't_start', 't_end', 'f_x', 'f_y', 'f_z', 'w_x', 'w_y', 'w_z')
        if rows and any(k not in rows[0] for k in need):
            raise LabError(f'{path}: CSV header needs {",".join(need)} (group, label '
                           'optional)')
        try:
            segs = [Segment(r['stage'].strip(), float(r['t_start']), float(r['t_end']),
                            int(r.get('group') or 0),
                            np.array([float(r['f_x']), float(r['f_y']), float(r['f_z'])]),
                            np.array([float(r['w_x']), float(r['w_y']), float(r['w_z'])]),
                            (r.get('label') or '').strip()) for r in rows]
        except ValueError as e:
            raise LabError(f'{path}: {e}') from None
        origin = 'first_sample'
    if origin not in ('first_sample', 'stamp'):
        raise LabError(f'{path}: time_origin {origin!r} is not first_sample or stamp')
    if not segs:
        raise LabError(f'{path}: no segments')
    _check_segments(segs, path)
    return Schedule(segs, origin)


def write_schedule(schedule, path):
    """Write a schedule as CSV (relative times) or YAML (by extension)."""
    path = os.fspath(path)
    if path.endswith(('.yaml', '.yml')):
        d = {'time_origin': schedule.time_origin,
             'segments': [{'stage': s.stage, 't_start': float(s.t_start),
                           't_end': float(s.t_end), 'group': int(s.group),
                           'specific_force': np.asarray(s.f, float).tolist(),
                           'rate': np.asarray(s.w, float).tolist(), 'label': s.label}
                          for s in schedule.segments]}
        with open(path, 'w') as f:
            yaml.safe_dump(d, f, sort_keys=False, default_flow_style=None)
        return path
    with open(path, 'w', newline='') as f:
        wr = csv.writer(f)
        wr.writerow(['stage', 't_start', 't_end', 'group', 'f_x', 'f_y', 'f_z', 'w_x', 'w_y',
                     'w_z', 'label'])
        for s in schedule.segments:
            wr.writerow([s.stage, repr(float(s.t_start)), repr(float(s.t_end)), s.group,
                         *[repr(float(v)) for v in s.f], *[repr(float(v)) for v in s.w],
                         s.label])
    return path


class SegmentAccumulator:
    """Streaming per-segment sums of raw accel, raw gyro and thermal inputs.

    Memory: a few floats per segment, whatever the log length.
    """

    def __init__(self, schedule, n_inputs, trim_s=0.0):
        self.schedule = schedule
        self.k = int(n_inputs)
        self.trim_s = float(trim_s)
        _, t0, t1, _, _, _ = schedule.table()
        self._t0 = t0 + self.trim_s
        self._t1 = t1 - self.trim_s
        m = len(t0)
        self.n = np.zeros(m)
        self.sa = np.zeros((m, 3))
        self.sg = np.zeros((m, 3))
        self.st = np.zeros((m, self.k))
        self._origin = None

    def push(self, t, accel, gyro, temps=None):
        """Add samples (t in s: header stamps; accel m/s^2, gyro rad/s, temps (n, k))."""
        t = np.asarray(t, float)
        if not len(t):
            return
        if self._origin is None:
            self._origin = t[0] if self.schedule.time_origin == 'first_sample' else 0.0
        tr = t - self._origin
        temps = np.zeros((len(t), self.k)) if temps is None else \
            np.asarray(temps, float).reshape(len(t), self.k)
        for j in range(len(self._t0)):
            a, b = np.searchsorted(tr, [self._t0[j], self._t1[j]], side='left')
            if b > a:
                self.n[j] += b - a
                self.sa[j] += accel[a:b].sum(0)
                self.sg[j] += gyro[a:b].sum(0)
                if self.k:
                    self.st[j] += temps[a:b].sum(0)

    def means(self):
        """Return SegmentMeans of the segments that got samples."""
        ok = self.n > 0
        n = self.n[:, None]
        with np.errstate(invalid='ignore', divide='ignore'):
            return SegmentMeans([s for s, o in zip(self.schedule.segments, ok) if o],
                                self.n[ok], (self.sa / n)[ok], (self.sg / n)[ok],
                                (self.st / n)[ok] if self.k else np.zeros((int(ok.sum()), 0)),
                                int(np.sum(~ok)))


@dataclass
class SegmentMeans:
    """Per-segment means of the raw outputs and thermal inputs."""

    segments: List[Segment]
    n: np.ndarray
    accel: np.ndarray        # (m, 3) raw m/s^2
    gyro: np.ndarray         # (m, 3) raw rad/s
    temps: np.ndarray        # (m, k)
    empty: int = 0           # scheduled segments without samples


@dataclass
class LabResult:
    """The 63-coefficient calibration and how each stage fitted."""

    accel: WholeUnitAccelModel
    gyro: WholeUnitGyroModel
    report: dict
    notes: list


def _lstsq(a, y, stage, what):
    """Solve a linear least-squares stage; returns (x, std, residual rms, condition)."""
    if a.shape[0] < a.shape[1]:
        raise LabError(f'{stage}: {a.shape[0]} equations for the {a.shape[1]} {what}; '
                       'collect more points')
    cs = np.sqrt(np.sum(a * a, axis=0))
    cs[cs == 0] = 1.0
    an = a / cs
    sv = np.linalg.svd(an, compute_uv=False)
    cond = float(sv[0] / max(sv[-1], 1e-300))
    if sv[-1] < 1e-9 * sv[0]:
        raise LabError(f'{stage}: the {what} are not separable with these points (condition '
                       f'{cond:.3g})')
    x, *_ = np.linalg.lstsq(an, y, rcond=None)
    r = y - an @ x
    dof = max(a.shape[0] - a.shape[1], 1)
    s2 = float(r @ r) / dof
    cov = np.linalg.inv(an.T @ an) * s2
    return x / cs, np.sqrt(np.maximum(np.diag(cov), 0)) / cs, float(np.sqrt(np.mean(r * r))), \
        cond


def _poly_design(x, order):
    return np.stack([x ** j for j in range(order + 1)], axis=1)


def _cubic_rows(v, i):
    """Design row block of eq. (5)/(7) for output axis i: 1, V_x, V_y, V_z, V_i^2, V_i^3."""
    return np.column_stack([np.ones(len(v)), v, v[:, i] ** 2, v[:, i] ** 3])


def solve_lab(means, accel_input=(0, 1, 2), gyro_input=(0, 1, 2), order=2,
              gyro_input_unit='degC', t0=None, x0=None):
    """Solve the 63 coefficients from segment means (see the module docstring).

    accel_input / gyro_input: which thermal input column drives each axis. ``t0``/``x0``:
    polynomial reference of the accel/gyro inputs (default: the mean chamber input).
    Returns a LabResult; raises LabError naming the stage that cannot be solved.
    """
    stage = np.array([s.stage for s in means.segments])
    group = np.array([s.group for s in means.segments])
    f_true = np.array([s.f for s in means.segments]).reshape(-1, 3)
    w_true = np.array([s.w for s in means.segments]).reshape(-1, 3)
    for st in STAGES:
        if not np.any(stage == st):
            raise LabError(f'the schedule has no {st} segments with samples; seed 002 lab mode '
                           'needs chamber temperature steps, turntable rates and centrifuge '
                           'accelerations')
    if means.temps.shape[1] == 0:
        raise LabError('lab mode needs thermal inputs (temperature topics) in the log')
    ta = means.temps[:, list(accel_input)]
    xg = means.temps[:, list(gyro_input)]
    ch = stage == 'chamber'
    t0 = np.round(ta[ch].mean(0), 3) if t0 is None else np.broadcast_to(t0, (3,)).astype(float)
    x0 = np.round(xg[ch].mean(0), 3) if x0 is None else np.broadcast_to(x0, (3,)).astype(float)
    report = {'segments': {st: int(np.sum(stage == st)) for st in STAGES},
              'empty_segments': means.empty}
    # 1. chamber: offset polynomials per axis (eqs. 2 and 4)
    ct = np.zeros((order + 1, 3))
    cw = np.zeros((order + 1, 3))
    std = {}
    sd_ct = np.zeros((order + 1, 3))
    sd_cw = np.zeros((order + 1, 3))
    rms = {'chamber_accel': [], 'chamber_gyro': []}
    for i in range(3):
        x, s, r, _ = _lstsq(_poly_design(ta[ch, i] - t0[i], order), means.accel[ch, i],
                            'chamber', f'accel {"xyz"[i]} temperature coefficients')
        ct[:, i], sd_ct[:, i] = x, s
        rms['chamber_accel'].append(r)
        x, s, r, _ = _lstsq(_poly_design(xg[ch, i] - x0[i], order), means.gyro[ch, i],
                            'chamber', f'gyro {"xyz"[i]} thermal-input coefficients')
        cw[:, i], sd_cw[:, i] = x, s
        rms['chamber_gyro'].append(r)

    def offset(c, x, ref):
        out = np.zeros_like(x)
        for row in c[::-1]:
            out = out * (x - ref) + row
        return out

    va = means.accel - offset(ct, ta, t0)
    vw = means.gyro - offset(cw, xg, x0)
    # 2. turntable: average same-rate points of a group (eqs. 5, 6)
    tt = np.flatnonzero(stage == 'turntable')
    keys = {}
    for j in tt:
        keys.setdefault((int(group[j]), *np.round(w_true[j], 6)), []).append(j)
    av_v = np.array([vw[idx].mean(0) for idx in keys.values()])
    av_w = np.array([w_true[idx].mean(0) for idx in keys.values()])
    av_f = np.array([f_true[idx].mean(0) for idx in keys.values()])
    report['turntable_points'] = len(keys)
    report['turntable_residual_gravity'] = {'max': float(np.max(np.linalg.norm(av_f, axis=1))),
                                            'unit': 'm/s^2'}
    om = np.zeros((3, 6))
    sd_om = np.zeros((3, 6))
    rms['turntable'], cond = [], {}
    for i in range(3):
        x, s, r, c = _lstsq(_cubic_rows(av_v, i), av_w[:, i], 'turntable',
                            f'gyro {"xyz"[i]} coefficients (Omega0, Omega1, Omega2, Omega3)')
        om[i], sd_om[i] = x, s
        rms['turntable'].append(r)
        cond[f'turntable_{"xyz"[i]}'] = c
    # 3. centrifuge: accel coefficients (eq. 7), then C from the gyro residual (eqs. 8-10)
    cf = np.flatnonzero(stage == 'centrifuge')
    am = np.zeros((3, 6))
    sd_am = np.zeros((3, 6))
    rms['centrifuge_accel'] = []
    for i in range(3):
        x, s, r, c = _lstsq(_cubic_rows(va[cf], i), f_true[cf, i], 'centrifuge',
                            f'accel {"xyz"[i]} coefficients (A0, A1, A2, A3)')
        am[i], sd_am[i] = x, s
        rms['centrifuge_accel'].append(r)
        cond[f'centrifuge_{"xyz"[i]}'] = c
    v = vw[cf]
    model_w = om[:, 0] + v @ om[:, 1:4].T + om[:, 4] * v ** 2 + om[:, 5] * v ** 3
    resid = w_true[cf] - model_w
    cc = np.zeros((3, 3))
    sd_c = np.zeros((3, 3))
    rms['centrifuge_gyro'] = []
    for i in range(3):
        x, s, r, c = _lstsq(f_true[cf], resid[:, i], 'centrifuge',
                            f'g-sensitivity row {"xyz"[i]} (C)')
        cc[i], sd_c[i] = x, s
        rms['centrifuge_gyro'].append(r)
    report['residual_rms'] = {k: {'value': v, 'unit': 'rad/s' if 'gyro' in k or k ==
                                  'turntable' else 'm/s^2'} for k, v in rms.items()}
    report['condition'] = cond
    # the chamber polynomials' uncertainty at the turntable/centrifuge inputs shifts V by
    # a constant, i.e. the bias terms (first-order propagation, correlations ignored)

    def at(sd, x, ref):
        d = np.mean(x, axis=0) - ref
        return np.sqrt(sum((sd[j] * d ** j) ** 2 for j in range(order + 1)))
    sd_om[:, 0] = np.hypot(sd_om[:, 0], np.abs(om[:, 1:4]) @ at(sd_cw, xg[tt], x0))
    sd_am[:, 0] = np.hypot(sd_am[:, 0], np.abs(am[:, 1:4]) @ at(sd_ct, ta[cf], t0))
    std = {'ct' + str(j): sd_ct[j] for j in range(order + 1)}
    std.update({'A0': sd_am[:, 0], 'A1': sd_am[:, 1:4], 'A2': sd_am[:, 4], 'A3': sd_am[:, 5]})
    accel = WholeUnitAccelModel(t0, ct, None, am[:, 0], am[:, 1:4], am[:, 4], am[:, 5],
                                std=std, convention='lab: fixture frame; ct0 from the chamber '
                                'pose (seed 002 3.1)')
    gstd = {'cw' + str(j): sd_cw[j] for j in range(order + 1)}
    gstd.update({'Omega0': sd_om[:, 0], 'Omega1': sd_om[:, 1:4], 'Omega2': sd_om[:, 4],
                 'Omega3': sd_om[:, 5], 'C': sd_c})
    gyro = WholeUnitGyroModel(x0, cw, None, om[:, 0], om[:, 1:4], om[:, 4], om[:, 5], cc,
                              std=gstd, input_unit=gyro_input_unit,
                              convention='lab: fixture frame; cw0 from the chamber pose '
                                         '(seed 002 3.1)')
    n_est = accel.count()[0] + gyro.count()[0]
    notes = [f'seed 002 lab mode: {n_est} coefficients by linear least squares (chamber '
             f'{report["segments"]["chamber"]}, turntable {report["turntable_points"]} '
             f'averaged points, centrifuge {report["segments"]["centrifuge"]} segments)']
    if report['turntable_residual_gravity']['max'] > 0.5:
        notes.append('turntable groups do not cancel gravity (|mean f| up to '
                     f'{report["turntable_residual_gravity"]["max"]:.2f} m/s^2): Omega is '
                     'biased by C times that; pair opposite poses in each group')
    return LabResult(accel, gyro, report, notes)


def accumulate_log(path, schedule, imu_topic=None, temperature_topics=None, trim_s=0.5,
                   chunk_size=20000, max_gap_s=5.0):
    """Stream a log through a SegmentAccumulator; return (SegmentMeans, temperature topics)."""
    from ..io.align import StreamAligner
    from ..io.bag import open_log
    from ..io.topics import resolve_topics
    with open_log(path) as reader:
        imu_topic, temps = resolve_topics(reader, imu_topic, temperature_topics)
        acc = SegmentAccumulator(schedule, len(temps), trim_s)
        aligner = StreamAligner(temps, max_gap_s)
        for raw in reader.stream(imu_topic, temps, chunk_size):
            for ch in aligner.push(raw):
                acc.push(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps)
        for ch in aligner.finish():
            acc.push(ch.imu.t, ch.imu.accel, ch.imu.gyro, ch.temps)
    return acc.means(), temps


# ---------------------------------------------------------------------- simulation
def paper_schedule(gravity=9.80665, chamber_pose=(0.0, 0.0, 1.0), earth_rate=None,
                   temps=tuple(range(0, 75, 5)), rates_deg=tuple(range(0, 520, 25)),
                   centrifuge_g=tuple(range(0, 35, 5)), radius=4.0, segment_s=10.0,
                   gap_s=2.0):
    """Return a schedule of seed 002's lab procedure plus the chamber temperature per segment.

    Chamber: the unit rests in ``chamber_pose`` (up axis) at each temperature. Turntable:
    three groups of two opposite poses (axis i up / down), each turning so that the
    sensor-frame rate is +r e_i, at +-rates_deg. Centrifuge: radial axis +-e_i with the up
    axis e_(i+2 mod 3), at each level in g. Returns (Schedule, (m,) temperature setpoints,
    degC; room temperature 25 outside the chamber).
    """
    w_e = np.zeros(3) if earth_rate is None else np.asarray(earth_rate, float)
    segs, temp = [], []
    t = 0.0
    up_ch = np.asarray(chamber_pose, float)
    for tc in temps:
        segs.append(Segment('chamber', t, t + segment_s, 0, gravity * up_ch, w_e.copy(),
                            f'chamber {tc} degC'))
        temp.append(float(tc))
        t += segment_s + gap_s
    eye = np.eye(3)
    for i in range(3):
        for sign in (1.0, -1.0):
            for r in sorted({s * d for d in rates_deg for s in (1, -1)}):
                rate = np.radians(r) * eye[i]
                segs.append(Segment('turntable', t, t + segment_s, i, sign * gravity * eye[i],
                                    rate, f'table axis {"xyz"[i]} {"up" if sign > 0 else "down"}'
                                    f' {r} deg/s'))
                temp.append(25.0)
                t += segment_s + gap_s
    for i in range(3):
        up = eye[(i + 2) % 3]
        for sign in (1.0, -1.0):
            for lev in centrifuge_g:
                om = np.sqrt(lev * gravity / radius)
                f = -sign * lev * gravity * eye[i] + gravity * up
                segs.append(Segment('centrifuge', t, t + segment_s, 3 + i, f, om * up,
                                    f'centrifuge radial {"+" if sign > 0 else "-"}'
                                    f'{"xyz"[i]} {lev} g'))
                temp.append(25.0)
                t += segment_s + gap_s
    return Schedule(segs, 'first_sample'), np.array(temp)


def simulate_lab_log(schedule, setpoints, accel, gyro, rate=100.0, accel_noise=0.0,
                     gyro_noise=0.0, proxy=None, seed=0):
    """Return (t (n,), raw accel (n, 3), raw gyro (n, 3), inputs (n, k)) for a schedule.

    ``accel``/``gyro`` are the true whole-unit models (their ``forward``); the thermal
    inputs are the setpoint temperature for the accel axes and ``proxy(T)`` (default: T)
    for the gyro axes, as columns [Tx, Ty, Tz, Xx, Xy, Xz]. Between segments nothing is
    recorded.
    """
    rng = np.random.default_rng(seed)
    proxy = proxy or (lambda temp: temp)
    ts, accs, gyrs, ins = [], [], [], []
    for s, sp in zip(schedule.segments, setpoints):
        n = int(round((s.t_end - s.t_start) * rate))
        t = s.t_start + np.arange(n) / rate
        temp = np.full((n, 3), sp)
        x = np.full((n, 3), proxy(sp))
        f = np.broadcast_to(s.f, (n, 3))
        w = np.broadcast_to(s.w, (n, 3))
        accs.append(accel.forward(f, temp) + accel_noise * rng.standard_normal((n, 3)))
        gyrs.append(gyro.forward(w, x, aux={'accel': f}) + gyro_noise *
                    rng.standard_normal((n, 3)))
        ts.append(t)
        ins.append(np.hstack([temp, x]))
    return np.concatenate(ts), np.concatenate(accs), np.concatenate(gyrs), np.concatenate(ins)
