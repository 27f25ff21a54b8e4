"""The gyro beyond its range: continued only when held-out holds outside earlier ranges say so.

Synthetic windows with a known truth (rad/s, m/s^2, s, degC): a level robot, the earth rate
at 45 deg at a random heading, a gyro bias linear in temperature over the fitted 10-20 degC
and, beyond 20 degC, either still linear or flat (where clamping is right).
"""

from dataclasses import replace

import numpy as np

from _level_holds import earth_rate, windows_of
from _robot_month import lifelong_month
from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.lifelong import compose, continuation

G0 = 9.80665
LAT = 45.0
SLOPE = np.array([2e-5, -1.5e-5, 1e-5])           # rad/s per degC


def bias(temp, flat_above=None):
    """True gyro bias (n, 3) at (n,) degC; ``flat_above``: constant beyond that degC."""
    t = temp if flat_above is None else np.minimum(temp, flat_above)
    return 1e-3 + np.outer(t - 15.0, SLOPE)


def holds(temps, seed, flat_above=None, first_id=0, t_start=0.0):
    """Return windows (3 per hold) of level stops at the holds' temperatures (degC)."""
    rng = np.random.default_rng(seed)
    rows = []
    for h, temp in enumerate(temps):
        heading = rng.uniform(0, 2 * np.pi)
        w = earth_rate(heading, LAT)
        for j in range(3):
            t = t_start + 600.0 * h + 60.0 * j
            tj = temp + rng.normal(0, 0.05)
            g = bias(np.array([tj]), flat_above)[0] + w + rng.normal(0, 2e-6, 3)
            rows.append((first_id + h, t, t + 60.0, tj, g,
                         np.array([0.0, 0.0, G0]) + rng.normal(0, 2e-3, 3)))
    return windows_of(rows)


def fitted(seed=0):
    """Return a calibration fitted on 40 holds at 10-20 degC (offset model, latitude)."""
    win = holds(np.linspace(10.0, 20.0, 40), seed)
    opts = CalibrateOptions(model='offset', latitude=LAT,
                            inputs=[TemperatureInput('t', '/imu/temperature')])
    cal = calibrate_windows(win, opts).calibration
    assert cal.out_of_range == 'clamp'
    return cal


def test_a_trend_that_goes_on_beyond_the_range_is_continued():
    cal = fitted()
    beyond = holds(np.linspace(22.0, 27.0, 12), 1, first_id=100, t_start=1e5)
    rows = continuation.rows(cal, beyond, G0, LAT)
    assert len(rows) == 12
    r = np.array(rows)
    # clamped, the error grows with the excess; continued, it stays at a fraction of that
    assert np.all(r[:, 2] < r[:, 1]) and np.all(r[-6:, 2] < 0.3 * r[-6:, 1]), r
    assert np.all(np.diff(r[:, 0]) > 0)          # the holds' times, oldest first
    go, text = continuation.verdict(rows, 2.0)
    assert go and text.startswith('gyro continued linearly') and 'on 12 holds' in text
    new, note = continuation.choose(cal, rows, 2.0)
    assert new.out_of_range == 'linear_gyro' and note == text
    assert new.range_policy('accel') == 'clamp'   # the accelerometer is clamped as before
    # holds inside the range give no evidence
    assert continuation.rows(cal, holds([12.0, 18.0], 2), G0, LAT) == []


def test_a_trend_that_stops_at_the_edge_stays_clamped():
    cal = fitted()
    beyond = holds(np.linspace(22.0, 27.0, 12), 1, flat_above=20.0, first_id=100)
    rows = continuation.rows(cal, beyond, G0, LAT)
    r = np.array(rows)
    assert np.all(r[:, 2] > r[:, 1])              # continuing is the worse of the two here
    go, text = continuation.verdict(rows, 2.0)
    assert not go and text.startswith('gyro clamped')
    new, _ = continuation.choose(replace(cal, out_of_range='linear_gyro'), rows, 2.0)
    assert new.out_of_range == 'clamp'


def test_no_evidence_clamps_and_other_policies_are_left_alone():
    cal = fitted()
    go, text = continuation.verdict([], 2.0)
    assert not go and '0 holds' in text and '2 needed' in text
    assert continuation.choose(cal, [], 2.0)[0].out_of_range == 'clamp'
    ext = replace(cal, out_of_range='extrapolate')
    assert continuation.choose(ext, [[0.0, 1.0, 0.0, 1e-6]] * 5, 2.0) == (ext, '')
    assert continuation.rows(ext, holds([25.0], 1), G0, LAT) == []


def test_like_for_like_judges_on_the_rows_of_calibrations_of_a_like_span():
    """A first calibration's few rows, far worse continued, do not decide for a wide one.

    The pattern of seeds 175 and 178 (docs/lifelong.md): a calibration over a few degC
    continued far worse beyond its edge, later ones over 10 degC (here 10-20) far better.
    """
    cal = fitted()
    assert 10.0 <= continuation.span(cal) < 13.0          # 10-20 degC and its margin
    beyond = holds(np.linspace(22.0, 27.0, 12), 1, first_id=100, t_start=1e5)
    later = continuation.rows(cal, beyond, G0, LAT)
    assert all(r[4] == continuation.span(cal) for r in later)
    first = [[float(t), 1.0e-3, 7.0e-3, 1e-5, 3.0] for t in range(6)]
    evidence = first + later
    go, text = continuation.verdict(evidence, 2.0)
    assert not go and 'on 18 holds' in text                      # the RMS of every row
    go, text = continuation.verdict(evidence, 2.0, width=continuation.span(cal))
    assert go and 'on 12 holds' in text and 'spanning at least' in text
    assert continuation.choose(cal, evidence, 2.0, like_for_like=True)[0].out_of_range \
        == 'linear_gyro'
    # a narrow new estimate is judged on every row (each spans at least half of its span)
    assert len(continuation.like(evidence, 4.0)) == 18
    # rows without a span (older state files) stay
    assert continuation.like([[0.0, 1.0, 1.0, 0.1]], 30.0) == [[0.0, 1.0, 1.0, 0.1]]


def test_the_evidence_is_bounded_and_cut_at_a_change():
    state = {}
    continuation.add(state, [[float(t), 1.0, 0.5, 0.1] for t in range(3000)])
    assert len(state['continuation']) == continuation.MAX_ROWS
    assert state['continuation'][-1][0] == 2999.0
    continuation.cut(state, 2500.0)
    assert state['continuation'][-1][0] == 2499.0


def test_a_clamped_accelerometer_composes_with_a_continued_gyro():
    cal = fitted()
    cont = replace(cal, out_of_range='linear_gyro')
    assert compose.why_not(cal, cont) == ''
    assert compose.compose(cal, cont).out_of_range == 'linear_gyro'
    assert compose.compose(cont, cal).out_of_range == 'clamp'
    lin = replace(cal, out_of_range='linear')
    assert compose.composed_policy(lin, cal) is None
    assert 'out-of-range policy' in compose.why_not(lin, cal)


def test_the_loop_logs_the_continuation_with_each_estimate(tmp_path):
    """With the option on, every judged estimate's logged text says what the rule chose."""
    from thermal_imu_calib.lifelong.config import LifelongConfig
    life = lifelong_month(tmp_path / 'life', LifelongConfig(gyro_continuation='span'))
    judged = [d for d in life.decisions() if d['action'] in ('swap', 'keep')]
    assert judged, life.decisions()
    for d in judged:
        assert d['continuation'].startswith('gyro ') and d['continuation'] in d['text']
    # the first estimate had no evidence; later ones were judged on held-out rows
    assert '0 holds' in judged[0]['continuation']
    rows = life.state.get('continuation') or []
    assert all(len(r) == 5 and r[1] >= 0 and r[2] >= 0 and r[4] > 0 for r in rows)
    assert rows == sorted(rows)
    assert life.active is not None and life.active.out_of_range in continuation.CHOICES
