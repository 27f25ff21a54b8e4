"""Simulated fleet: units of one design, each recording a few short logs over months.

Unit ``uNN`` is device ``seed * 1000 + NN`` of the ``sim`` 'mems' family (same design,
different parameters); its log ``k`` is the ``demo`` scenario recorded ``k * spacing_days``
after the fleet epoch, with the IMU ``frame_id`` = unit id. Most units are stable; the
``drifting`` ones age: their accelerometer bias at T0 (db0) moves by ``drift`` m/s^2 per
30 days on every axis; one ``step`` unit's db0 jumps by ``step`` m/s^2 (and dk0 by
``step_scale``) from the middle log on (e.g. after a knock). Truth: every log's
``<log>.mcap.truth.yaml`` (from ``sim.write_scenario``) and ``DIR/fleet_truth.csv``.
"""

import csv
import dataclasses
import io
import os

import numpy as np

from .. import sim
from ..io.columns import TemperatureColumns
from ..io.output import write_atomic

FLEET_EPOCH_NS = 1_735_689_600 * 10 ** 9      # 2025-01-01T00:00:00Z
SCENARIO = 'demo'


@dataclasses.dataclass(frozen=True)
class FleetDesign:
    """What varies across the simulated fleet (SI units)."""

    units: int = 20
    logs_per_unit: int = 5
    seed: int = 0
    spacing_days: float = 30.0
    drifting: int = 3
    drift: float = 0.010            # m/s^2 per 30 days, every axis
    step: float = 0.040             # m/s^2, one axis
    step_scale: float = 2e-3        # 1, same axis


def unit_plan(design):
    """Return one dict per unit: id, device seed, kind (stable/drifting/step), step axis."""
    rng = np.random.default_rng([design.seed, 14])
    n = design.units
    special = rng.permutation(n)[:min(n, design.drifting + 1)] if n > 1 else []
    out = []
    for i in range(n):
        kind = 'stable'
        if len(special) and i == special[0]:
            kind = 'step'
        elif i in special[1:]:
            kind = 'drifting'
        out.append({'unit': f'u{i:02d}', 'device_seed': design.seed * 1000 + i, 'kind': kind,
                    'axis': int(rng.integers(0, 3)),
                    'step_log': design.logs_per_unit // 2 + design.logs_per_unit % 2})
    return out


def _shift(rec, delta_ns, frame_id, thermal):
    """Return ``rec`` moved in time by ``delta_ns``, renamed, with new thermal parameters."""
    dev = dataclasses.replace(rec.device, thermal=thermal)
    acc = rec.truth.accel
    truth = dataclasses.replace(
        rec.truth, frame_id=frame_id,
        accel=type(acc)(acc.t0, thermal, acc.k0, acc.b0, acc.s))
    temps = {t: TemperatureColumns(c.stamp_ns + delta_ns, c.temperature, frame_id)
             for t, c in rec.temperatures.items()}
    sched = [dataclasses.replace(h, stamp_start_ns=h.stamp_start_ns + delta_ns,
                                 stamp_end_ns=h.stamp_end_ns + delta_ns) for h in rec.schedule]
    return dataclasses.replace(rec, device=dev, truth=truth, temperatures=temps,
                               schedule=sched, start_ns=rec.start_ns + delta_ns,
                               frame_id=frame_id)


def log_thermal(plan, k, design):
    """Return the (3, 6) true thermal parameters of log ``k`` of a unit (sim column order)."""
    th = sim.draw_device('mems', plan['device_seed']).thermal.copy()
    db0, dk0 = sim.THERMAL_COLUMNS.index('db0'), sim.THERMAL_COLUMNS.index('dk0')
    if plan['kind'] == 'drifting':
        th[:, db0] += design.drift * k * design.spacing_days / 30.0
    elif plan['kind'] == 'step' and k >= plan['step_log']:
        th[plan['axis'], db0] += design.step
        th[plan['axis'], dk0] += design.step_scale
    return th


def write_log(out_dir, plan, k, design):
    """Write log ``k`` of one unit; returns its path (also a Dask task)."""
    unit = plan['unit']
    path = os.path.join(out_dir, unit, f'{unit}_log{k}.mcap')
    start = FLEET_EPOCH_NS + int(round(k * design.spacing_days * 86400)) * 10 ** 9
    thermal = log_thermal(plan, k, design)

    def transform(rec):
        return _shift(rec, start - rec.start_ns, unit, thermal)
    # the recording (noise, poses, warm-up) is drawn from the scenario name: one per log
    cfg = dataclasses.replace(sim.SCENARIOS[SCENARIO], name=f'fleet-{unit}-log{k}-s{design.seed}')
    sim.write_scenario(path, cfg, plan['device_seed'], transform=transform)
    return path


def write_truth(out_dir, plans, design):
    """Write DIR/fleet_truth.csv: one row per unit (kind, drift, step, step log, axis)."""
    path = os.path.join(out_dir, 'fleet_truth.csv')
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(['unit', 'device_seed', 'kind', 'drift_mps2_per_30d', 'step_mps2',
                'step_scale', 'step_axis', 'step_log'])
    for p in plans:
        w.writerow([p['unit'], p['device_seed'], p['kind'],
                    design.drift if p['kind'] == 'drifting' else 0.0,
                    design.step if p['kind'] == 'step' else 0.0,
                    design.step_scale if p['kind'] == 'step' else 0.0,
                    p['axis'] if p['kind'] == 'step' else '',
                    p['step_log'] if p['kind'] == 'step' else ''])
    return write_atomic(path, buf.getvalue())


def simulate_fleet(out_dir, design, client=None):
    """Write the whole fleet (on ``client``'s workers when given); returns the log paths."""
    plans = unit_plan(design)
    os.makedirs(out_dir, exist_ok=True)
    jobs = [(p, k) for p in plans for k in range(design.logs_per_unit)]
    if client is None:
        paths = [write_log(out_dir, p, k, design) for p, k in jobs]
    else:
        futs = [client.submit(write_log, out_dir, p, k, design, pure=False) for p, k in jobs]
        paths = client.gather(futs)
    write_truth(out_dir, plans, design)
    return paths


def read_truth(out_dir):
    """Return unit -> row dict of DIR/fleet_truth.csv."""
    with open(os.path.join(out_dir, 'fleet_truth.csv'), newline='') as f:
        return {r['unit']: r for r in csv.DictReader(f)}
