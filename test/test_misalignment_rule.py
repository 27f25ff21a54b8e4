"""The standard fit's misalignment rule is judged held out (selection/static_select.py).

imu_tk estimates all three accelerometer misalignments from whatever poses it gets. The
standard fit's posterior/prior rule fixes at 0 those the holds determine only weakly; it
stands only when held-out holds support it, or when the fit with them estimated cannot be
made. Sessions are built hold by hold (one window per hold) from a biased sensor with
1.5 mg per-sample noise, every pose tilted by a random 1 deg (a hand-placed cube) unless
said otherwise.
"""

import numpy as np

from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.estimation.calibrate import CalibrateOptions, calibrate_windows

G = 9.81
SD = 0.015                                              # m/s^2 per sample (1.5 mg)
BIAS = np.array([0.05, -0.04, 0.03])
FACES = [np.eye(3)[i] * s for i in range(3) for s in (1, -1)]
#: six faces, then each face again: the Ferraris/imucal procedure's holds, no tilted pose
SESSION = FACES + FACES[::2] + FACES[1::2]
#: a consumer MEMS part: 1-2 % cross-axis coupling (the MPU-6050 session's is of that size)
COUPLED = np.array([[1.02, 0.0, 0.0], [0.02, 0.97, 0.0], [-0.01, 0.015, 1.01]])


def session(ups, seed, L, tilt_deg=1.0):
    """Return Windows of one hold per pose in ``ups``; the sensor reads L^-1 f + BIAS."""
    rng = np.random.default_rng(seed)
    rows, n = [], rng.integers(250, 900, len(ups))
    for j, u in enumerate(ups):
        u = u + rng.normal(0.0, np.radians(tilt_deg), 3)
        u /= np.linalg.norm(u)
        raw = np.linalg.solve(L, G * u) + BIAS
        rows.append(raw + rng.normal(0.0, SD / np.sqrt(n[j]), 3))
    m = len(rows)
    return Windows(np.arange(m), 10.0 * np.arange(m), 10.0 * np.arange(m) + 5.0, n,
                   np.array(rows), np.zeros((m, 3)), np.full((m, 3), SD ** 2),
                   np.zeros((m, 3)), np.zeros((m, 0)), np.zeros((m, 0)))


def _calibrate(w):
    res = calibrate_windows(w, CalibrateOptions(gravity=G))
    return res.calibration, res.summary


def test_a_coupled_sensor_on_the_faces_keeps_its_misalignment_estimated():
    # the rule would fix a 1-2 % coupling at 0; the held-out holds say estimating it
    # predicts them better, so the standard fit stays imu_tk's (all three estimated)
    for seed in range(3):
        cal, summary = _calibrate(session(SESSION, seed, COUPLED))
        rule = cal.fit['misalignment_rule']
        assert rule['terms'] and not rule['applied'], rule
        assert rule['heldout_holds'] >= 3 and rule['estimated_ug'] < rule['fixed_ug'], rule
        assert 'estimated, as imu_tk does' in rule['text']
        assert any(rule['text'] == n for n in cal.notes)
        assert 'estimated as imu_tk does (the rule that fixes weak ones judged' in summary
        assert not any('fixed at 0' in n for n in cal.notes), cal.notes
        assert np.all(np.asarray(cal.accel.m1)[[1, 2, 2], [0, 0, 1]] != 0.0)


def test_exact_faces_cannot_determine_the_misalignment_so_it_stays_fixed():
    # gravity on the axes only: with the misalignments estimated the fit does not converge
    cal, summary = _calibrate(session(FACES + FACES, 0, np.diag([1.02, 0.97, 1.01]), 0.0))
    rule = cal.fit['misalignment_rule']
    assert rule['applied'] and rule['heldout_holds'] == 0, rule
    assert 'cannot be made' in rule['text'] and rule['text'].endswith('fixed at 0')
    A1 = np.asarray(cal.accel.m1)
    assert A1[1, 0] == A1[2, 0] == A1[2, 1] == 0.0
    assert 'fixed at 0 (the rule that fixes weak ones judged held out' in summary


def test_well_determined_misalignments_need_no_judgement():
    tilted = [np.array(v, float) / np.linalg.norm(v)
              for v in ([1, 1, 0], [-1, 0, 1], [0, -1, -1], [1, -1, 1])]
    cal, summary = _calibrate(session(FACES + tilted + FACES, 0, COUPLED))
    assert 'misalignment_rule' not in cal.fit
    idx = ([1, 2, 2], [0, 0, 1])
    np.testing.assert_allclose(np.asarray(cal.accel.m1)[idx], COUPLED[idx], atol=2e-3)
    assert 'weak ones judged' not in summary
