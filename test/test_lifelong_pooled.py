"""The gyro swap judged on the pooled held-out holds of successive estimates (``pooled``).

Synthetic level holds with a known truth (rad/s, m/s^2, s, degC): the earth rate at 45 deg
at a random heading and a gyro bias that has aged since the active calibration was fitted,
by twice a hold mean's standard error: on one estimate's 8 held-out holds the gain is below
the gate's noise floor; the pool of several estimates' holds tells.
"""

import numpy as np

from _level_holds import earth_rate, windows_of
from _robot_month import lifelong_month
from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.lifelong import gate, pooled
from thermal_imu_calib.lifelong.config import LifelongConfig

G0 = 9.80665
LAT = 45.0
SE = 1e-5                       # rad/s: the standard error of one hold's gyro mean
CONFIG = LifelongConfig(gyro_pooled_gate=True)


def holds(n, seed, bias, first_id=0, t_start=0.0):
    """Return windows (3 per hold) of ``n`` level holds at 15-20 degC, gyro bias ``bias``."""
    rng = np.random.default_rng(seed)
    rows = []
    for h in range(n):
        heading = rng.uniform(0, 2 * np.pi)
        w = earth_rate(heading, LAT)
        temp = rng.uniform(15.0, 20.0)
        for j in range(3):
            t = t_start + 600.0 * h + 60.0 * j
            g = bias + w + rng.normal(0, SE * np.sqrt(3), 3)   # the hold's mean: SE
            rows.append((first_id + h, t, t + 60.0, temp, g,
                         np.array([0.0, 0.0, G0]) + rng.normal(0, 2e-4, 3)))
    return windows_of(rows, gyro_var=SE ** 2 * 1800)


def fit(win):
    """Return an offset calibration fitted on ``win`` with the latitude known."""
    opts = CalibrateOptions(model='offset', latitude=LAT,
                            inputs=[TemperatureInput('t', '/imu/temperature')])
    return calibrate_windows(win, opts).calibration


def test_the_floor_shrinks_with_the_pooled_holds():
    rng = np.random.default_rng(0)
    se = np.full(64, 2e-5)
    act = np.abs(3e-5 + rng.normal(0, 2e-6, 64))
    new = act - 1e-5                                  # half the floor, every hold
    rows = [[float(t), a, b, s] for t, a, b, s in zip(range(64), act, new, se)]
    one = pooled.verdict(rows[:8], 8, 2.0)
    assert one['floor'] == 2e-5 and one['verdict'] == 'same'
    # the gate itself on those 8 holds says the same
    assert gate.compare(act[:8], new[:8], 2e-5, 2.0)['verdict'] == 'same'
    many = pooled.verdict(rows, 8, 2.0)
    assert np.isclose(many['floor'], 2e-5 * np.sqrt(8 / 64)) and many['holds'] == 64
    assert many['verdict'] == 'better' and many['gain'] > many['margin']
    assert 'pooled over 64 held-out holds' in pooled.describe(many)
    assert pooled.verdict(rows[:1], 8, 2.0)['verdict'] == 'same'
    assert pooled.verdict([], 8, 2.0)['verdict'] == 'same'


def test_each_hold_is_pooled_once_bounded_and_emptied():
    state = {}
    assert pooled.add(state, [[1.0, 2.0, 1.0, 0.1], [2.0, 2.0, 1.0, 0.1]]) == 2
    # the next estimate holds out one of the same holds and a new one
    assert pooled.add(state, [[2.0, 9.0, 9.0, 0.1], [3.0, 2.0, 1.0, 0.1]]) == 1
    assert [r[0] for r in state['gyro_pool']] == [1.0, 2.0, 3.0]
    assert state['gyro_pool'][1][1] == 2.0          # the first candidate's row stays
    pooled.add(state, [[float(t), 1.0, 0.5, 0.1] for t in range(10, 3010)])
    assert len(state['gyro_pool']) == pooled.MAX_ROWS
    pooled.clear(state)
    assert 'gyro_pool' not in state


def test_an_aged_gyro_is_swapped_on_the_pooled_evidence_alone():
    b0 = np.array([1e-3, -5e-4, 2e-4])
    active = fit(holds(200, 0, b0))
    aged = b0 + 2e-5 * np.array([0.6, -0.64, 0.48])  # 2 SE: each hold's error grows ~0.6 SE
    state, swapped, judged = {}, None, []
    for k in range(12):
        new = fit(holds(200, 100 + k, aged))
        held = holds(8, 200 + k, aged, first_id=1000 + 8 * k, t_start=1e5 + 1e4 * k)
        s_act = gate.score(active, held, G0, latitude=LAT)
        s_new = gate.score(new, held, G0, latitude=LAT)
        swap, fig = gate.decide(s_act, s_new, CONFIG.swap_sigmas)
        assert not swap                             # the gate alone never swaps here
        part, record = pooled.judge(state, active, new, fig, s_act, s_new, held, held,
                                    LAT, CONFIG)
        assert record['added'] == 8 and record['pooled_holds'] == 8 * (k + 1)
        judged.append(record)
        if part is not None:
            swapped = (k, part, record)
            break
    assert swapped is not None, [r['text'] for r in judged]
    k, (cal, score, fig_c), record = swapped
    assert k >= 1 and record['used'] and record['figures']['verdict'] == 'better'
    # the candidate's gyro, the active accelerometer
    assert cal.gyro is new.gyro and cal.accel is active.accel
    assert 'composed' in cal.fit and fig_c['gyro']['gain'] > 0
    assert score['gyro_rms'] < s_act['gyro_rms']


def test_nothing_is_pooled_without_an_active_calibration_or_after_an_alarm():
    win = holds(8, 1, np.zeros(3))
    cal = fit(holds(40, 0, np.zeros(3)))
    s = gate.score(cal, win, G0, latitude=LAT)
    fig = gate.decide(s, s)[1]
    assert pooled.judge({}, None, cal, fig, s, s, win, win, LAT, CONFIG) == (None, {})
    state = {'alarm_pending': True}
    assert pooled.judge(state, cal, cal, fig, s, s, win, win, LAT, CONFIG) == (None, {})
    assert 'gyro_pool' not in state
    # a candidate no better on its own holds is pooled, not judged
    part, record = pooled.judge({}, cal, cal, fig, s, s, win, win, LAT, CONFIG)
    assert part is None and record['added'] == 8 and 'not judged' in record['text']


def test_the_loop_pools_logs_and_starts_afresh_after_a_gyro_swap(tmp_path):
    # 2.2 days: a swap of both models (day 0.76), then three kept estimates judged on
    # the pool (days 1.5-2.0); 3 days gave the same checks in 4.5x the time
    life = lifelong_month(tmp_path / 'life', CONFIG, days=2.2)
    judged = [d for d in life.decisions() if d['action'] in ('swap', 'keep')]
    assert judged, life.decisions()
    records = [d for d in judged if 'pooled' in d]
    assert records, [d['text'] for d in judged]
    for d in records:
        assert d['pooled']['text'] in d['text']
    # the pool grows over successive estimates
    assert any(d['pooled']['pooled_holds'] > d['pooled']['added'] for d in records)
    # after a swap that replaced the gyro the pool holds only the newer estimates' holds
    fresh = False
    checked = 0
    for d in judged:
        if 'pooled' in d and fresh:
            assert d['pooled']['pooled_holds'] == d['pooled']['added'], d['text']
            checked += 1
        fresh = d['action'] == 'swap' and '(accel model only)' not in d['text']
    assert checked, [d['text'] for d in judged]
    pool = life.state.get('gyro_pool') or []
    times = [r[0] for r in pool]
    assert len(set(times)) == len(times)
    assert all(len(r) == 4 and r[1] >= 0 and r[2] >= 0 and r[3] > 0 for r in pool)
