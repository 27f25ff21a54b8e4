"""Several orientations across a temperature span: the standard fit is a candidate too.

The thermal family ``auto`` chooses must predict runs of holds it did not see (in time)
better than the standard fit with its bias polynomial in temperature, or the standard fit
is returned (``selection/standard_floor.py``). Synthetic sessions whose truth is one or the
other model, and registry alarms that work for every family (``models/alarm_terms.py``).
"""

import dataclasses
import re

import numpy as np
import pytest

from _thermal_data import make_windows, options, sim_windows
from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.estimation.calibrate import calibrate_windows
from thermal_imu_calib.fleet import registry as reg
from thermal_imu_calib.models.alarm_terms import bias_scale_terms
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.whole_unit import WholeUnitAccelModel
from thermal_imu_calib.selection.standard_floor import MIN_FACE_VISITS, time_runs

G = 9.80665
FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def _truth(temp, bias_x=0.05, scale_slope=1e-4):
    """Return the session's true bias (m/s^2) and scale factor at ``temp`` (n,) degC."""
    dt = (np.asarray(temp, float) - 30.0)[:, None]
    bias = np.array([bias_x, -0.08, 0.12]) + 2e-3 * dt + 4e-5 * dt ** 2
    return bias, 1 + np.array([2e-3, -1e-3, 1.5e-3]) + scale_slope * dt


def _session(scale_slope, visits=5, seed=0, misalign=True, bias_x=0.05, faces=6, s=None,
             tilt=0.0):
    """Six faces visited ``visits`` times along a 20 -> 40 degC warm-up, 3 windows a hold.

    Truth: raw = b(T) + k(T) * f with a bias polynomial in T, a fixed 2e-3 scale error and
    a misalignment (``misalign``, or the lower-triangular ``s`` given; else none), and a
    scale factor changing by ``scale_slope`` per degC; x's bias at 30 degC ``bias_x``
    m/s^2; the first ``faces`` faces only, each hold tilted off its face by ``tilt`` rad
    (1-sigma per axis; 0: exactly on it).
    """
    rng = np.random.default_rng(seed)
    order = np.concatenate([rng.permutation(faces) for _ in range(visits)])
    n_holds = len(order)
    t = np.repeat(np.arange(n_holds) * 120.0, 3) + np.tile([0.0, 5.0, 10.0], n_holds)
    temp = 20.0 + 20.0 * (1 - np.exp(-t / t.max() * 3)) / (1 - np.exp(-3))
    hold = np.repeat(np.arange(n_holds), 3)
    up = FACES[order].astype(float)
    if tilt:
        up += rng.normal(0.0, tilt, up.shape)
        up /= np.linalg.norm(up, axis=1, keepdims=True)
    f = G * up[hold]
    if s is None:
        s = np.array([[1.0, 0, 0], [4e-4, 1.0, 0], [-3e-4, 5e-4, 1.0]]) if misalign else \
            np.eye(3)
    bias, k = _truth(temp, bias_x, scale_slope)
    accel = bias + k * (f @ s.T)
    return make_windows(t, temp, accel, np.zeros_like(accel), hold=hold, n=500,
                        sigma_a=2e-3, rng=rng)


def test_time_runs_keep_every_face_twice():
    w = _session(0.0)
    folds, n = time_runs(w)
    assert n == 5
    ids, means = w.hold_means()
    for f in range(n):
        kept = means[np.isin(ids, np.unique(w.hold[folds != f]))]
        axis = np.argmax(np.abs(kept), 1)
        faces = axis * 2 + (kept[np.arange(len(kept)), axis] < 0)
        assert np.bincount(faces, minlength=6).min() >= MIN_FACE_VISITS
    # each face twice in 12 holds: no run can leave without a face falling below twice
    assert time_runs(_session(0.0, visits=2))[1] == 0


def test_standard_fit_wins_when_it_is_the_truth():
    res = calibrate_windows(_session(0.0), options())
    choice = res.report['model_choice']
    assert choice['model'] == 'standard', choice['reason']
    assert 'against the standard fit (5 contiguous runs' in choice['reason']
    assert 'does not predict them better by more than the noise' in choice['reason']
    assert res.calibration.accel.kind == 'whole_unit_accel'
    assert res.calibration.accel.offset_order == 2       # bias polynomial in temperature


def test_thermal_family_kept_when_held_out_runs_say_so():
    res = calibrate_windows(_session(1e-4), options())
    choice = res.report['model_choice']
    assert choice['model'] != 'standard', choice['reason']
    assert 'predicts them better by more than the noise: kept' in choice['reason']
    z = float(choice['reason'].split('paired z ')[1].split(' ')[0])
    assert z > 1.64


def test_no_run_and_no_hold_fold_evidence_returns_the_standard_fit():
    # each face twice along the warm-up: no time run can be held out; with the standard
    # form as the truth the hold folds at fixed tilts do not favour the family. (Before
    # 2026-12-07 this ran with a scale factor changing 1e-4 per degC, and the standard fit
    # was returned because the two-step field fit of these sessions stopped at its 1000
    # sweeps unconverged: its tilts spoilt both held-out figures, 1556 against 1608 ug.
    # Converged (``estimation.fixed_point``, 250 sweeps) the folds see that truth:
    # field 107 against 1023 ug, z 3.49, kept; ``bench/two_step_speed.py``.)
    for seed in (0, 1):
        res = calibrate_windows(_session(0.0, visits=2, seed=seed), options())
        choice = res.report['model_choice']
        assert choice['model'] == 'standard', choice['reason']
        assert 'no run of holds in time can be held out' in choice['reason']
        assert '2 hold folds (at most one hold per face out)' in choice['reason']
        assert 'does not predict them better by more than the noise' in choice['reason']
        assert res.calibration.accel.kind == 'whole_unit_accel'
        # the user sees why, in a note (printed by calibrate)
        assert any(n.startswith('auto, a thermal family judged against the standard fit (')
                   and 'the standard fit (bias polynomial in temperature)' in n
                   for n in res.calibration.notes), res.calibration.notes


def test_six_faces_held_twice_converge_and_the_folds_then_see_the_thermal_truth(monkeypatch):
    """The two-step field fit of these sessions converges (it stopped unconverged at its
    1000 sweeps before 2026-12-07), and the hold folds then keep the family its truth is."""
    import thermal_imu_calib.estimation.field_estimator as fe
    from thermal_imu_calib.estimation import fixed_point
    w = _session(1e-4, visits=2)
    ta, t0 = np.repeat(w.temp, 3, 1), np.full(3, 30.0)
    mixed = fe.fit_field_model(w, ta, G, t0, refine=False)
    assert mixed.converged and mixed.iterations < 500
    res = calibrate_windows(w, options())
    choice = res.report['model_choice']
    assert choice['model'] == 'field', choice['reason']
    assert 'no run of holds in time can be held out' in choice['reason']
    assert 'field predicts them better by more than the noise: kept' in choice['reason']
    monkeypatch.setattr(fixed_point, 'ANDERSON_DEPTH', 0)   # the plain alternation, as before
    plain = fe.fit_field_model(w, ta, G, t0, refine=False, tol=1e-3)
    assert not plain.converged and plain.iterations == 1000


def test_hold_folds_at_fixed_tilts_keep_the_family_the_held_out_holds_support():
    # the simulated demo: each face held twice; against its truth the field model is ~10x
    # better than the standard fit, and the held-out holds say so
    w = sim_windows(sim.simulate('demo', 0))
    res = calibrate_windows(w, options())
    choice = res.report['model_choice']
    assert choice['model'] == 'field', choice['reason']
    assert 'no run of holds in time can be held out' in choice['reason']
    assert 'field predicts them better by more than the noise: kept' in choice['reason']
    std, fam = re.search(r'over 12 holds, standard ([\d.]+) ug, field ([\d.]+) ug',
                         choice['reason']).groups()
    assert float(fam) < 0.5 * float(std)


def test_no_held_out_holds_at_all_is_no_evidence_for_the_family():
    # a family the fixed-tilt frame cannot refit, and no time run: nothing is held out
    from thermal_imu_calib.selection import standard_floor as sf
    from thermal_imu_calib.selection.heldout import Selection
    w = _session(1e-4, visits=2)
    captured = {}
    real = sf.judge_family

    def spy(ctx, sel):
        captured['ctx'] = ctx
        return real(ctx, sel)
    import thermal_imu_calib.selection.static_select as ss
    orig = ss.judge_family
    ss.judge_family = spy
    try:
        calibrate_windows(w, options())
    finally:
        ss.judge_family = orig
    out = sf.judge_family(captured['ctx'], Selection('whole_unit', 'chosen'))
    assert out.model == 'standard'
    assert 'no held-out evidence that whole_unit is better' in out.reason
    assert 'hold every face at least twice, at different temperatures' in out.reason


def test_alarm_terms_of_the_field_model_are_its_parameters():
    rng = np.random.default_rng(1)
    th = rng.normal(0, 1e-3, (3, 6))
    std = np.abs(rng.normal(0, 1e-4, (3, 6))) + 1e-6
    m = FieldPolynomialModel([25.0, 26.0, 27.0], th, thermal_std=std)
    t = bias_scale_terms(m)
    np.testing.assert_allclose(t['T0'], [25.0, 26.0, 27.0])
    np.testing.assert_allclose(t['b'], th[:, 3:], atol=1e-12)
    np.testing.assert_allclose(t['k'][:, 0], 1 + th[:, 0], atol=1e-12)
    np.testing.assert_allclose(t['k'][:, 1:], th[:, 1:3], atol=1e-11)
    np.testing.assert_allclose(t['b_std'], std[:, 3:], rtol=1e-6)
    np.testing.assert_allclose(t['k_std'], std[:, :3], rtol=1e-5)


def _whole_unit(bias, std=1e-4):
    m1 = np.diag([1 / 1.002, 1 / 0.999, 1 / 1.001])
    return WholeUnitAccelModel([30.0] * 3, np.array([bias, [1e-3] * 3]), m1=m1,
                               std={'ct0': np.full(3, std), 'ct1': np.full(3, 1e-5),
                                    'A1': np.full((3, 3), 1e-5)})


def test_alarm_terms_of_the_standard_fit_and_a_chain_per_family():
    t = bias_scale_terms(_whole_unit([0.1, 0.2, 0.3]))
    np.testing.assert_allclose(t['b'][:, 0], [0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(t['b'][:, 1], 1e-3, atol=1e-12)
    np.testing.assert_allclose(t['k'][:, 0], [1.002, 0.999, 1.001], rtol=1e-9)
    assert np.all(t['b_std'][:, 0] >= 1e-4 * (1 - 1e-9)) and np.all(t['k_std'][:, 0] > 0)
    field = FieldPolynomialModel([30.0] * 3, np.zeros((3, 6)),
                                 thermal_std=np.full((3, 6), 1e-4))
    # standard, field, standard with x's bias moved by 2 mg (14 sigma of the difference):
    # the two standard fits are compared across the field calibration between them
    cals = [_whole_unit([0.1, 0.2, 0.3]), field, _whole_unit([0.1 + 2e-3, 0.2, 0.3])]
    rows = [reg.index_row('u', Calibration(accel=m), (1_700_000_000 + 86400 * i) * 10 ** 9,
                          (1_700_000_000 + 86400 * i - 3600) * 10 ** 9, f'u/{i}.yaml', ['a'])
            for i, m in enumerate(cals)]
    rows = [{k: str(v) for k, v in r.items()} for r in rows]
    tests = reg.unit_tests(rows)
    changes = [(lbl, z) for lbl, z in tests if 'changed' in lbl]
    bx = [z for lbl, z in changes if lbl.startswith('db0 x')]
    assert len(bx) == 1 and bx[0] == pytest.approx(2e-3 / np.sqrt(2 * 1e-4 ** 2), rel=0.05)
    alarms, info = reg.assess(rows)
    assert any('db0 x changed' in a for a in alarms['u'])
    assert any('that change is not tested' in n for n in info['notes']['u'])


def test_a_scale_factor_without_thermal_terms_over_a_span_is_not_tested():
    """The standard fit over warm holds: its stds leave out the scale factor's drift.

    On the stable units of held-out simulated fleets (bench/fleet_family_switch.py) its
    changes had z std 3.6-4.3; its accelerometer is left out of the tests when its holds
    span more than ``FLAT_SPAN_DEGC`` and kept at one temperature.
    """
    cals = [_whole_unit([0.1, 0.2, 0.3]), _whole_unit([0.1 + 2e-3, 0.2, 0.3])]

    def rows(span):
        out = []
        for i, m in enumerate(cals):
            r = reg.index_row('u', Calibration(accel=m), (1_700_000_000 + 86400 * i) * 10 ** 9,
                              (1_700_000_000 + 86400 * i - 3600) * 10 ** 9, f'u/{i}.yaml',
                              ['a'])
            r.update(temp_min=25.0, temp_max=25.0 + span)
            out.append({k: str(v) for k, v in r.items()})
        return out
    warm, flat = rows(10.0), rows(0.5)
    assert all(reg.untested_accel(r) for r in warm)
    assert not any(reg.untested_accel(r) for r in flat)
    assert not [lbl for lbl, _ in reg.unit_tests(warm) if lbl.startswith('db0')]
    assert [lbl for lbl, _ in reg.unit_tests(flat) if lbl.startswith('db0 x changed')]
    alarms, info = reg.assess(warm)
    assert not alarms['u']
    assert any('not tested: its scale factor has no temperature terms over 10.0 degC' in n
               for n in info['notes']['u'])


@pytest.mark.parametrize('name', ['rvm', 'field-lag', 'whole_unit', 'field'])
def test_every_thermal_family_can_be_judged(name):
    from thermal_imu_calib.estimation.calibrate import make_context
    from thermal_imu_calib.selection.heldout import Selection
    from thermal_imu_calib.selection.standard_floor import judge_family
    ctx = make_context(_session(1e-4), options())
    ctx.filter_ok = True
    sel = Selection(name, 'forced', tau_s=np.array([300.0]) if name == 'field-lag' else None)
    ctx.thermal_selection = sel
    out = judge_family(ctx, sel)
    # refitted on each run through its own estimator (lagged inputs for field-lag) and
    # scored: every family here predicts the held-out runs better than the standard fit
    assert out.model == name, out.reason
    row = out.table[f'{name} (vs standard, held out)']
    assert row['heldout_holds'] >= 3 and row['z'] > 1.64
    assert np.isfinite(row['residual_ug'])


def _accel_columns(cal):
    return {k: v for k, v in reg.alarm_columns(cal).items() if k.startswith('accel.')}


def _rows(cals):
    rows = [reg.index_row('u', c, (1_700_000_000 + 86400 * i) * 10 ** 9,
                          (1_700_000_000 + 86400 * i - 3600) * 10 ** 9, f'u/{i}.yaml', ['a'])
            for i, c in enumerate(cals)]
    return [{k: str(v) for k, v in r.items()} for r in rows]


def test_a_calibration_of_another_family_carries_the_field_yardstick(tmp_path):
    """The drift alarms read the field model's terms whatever model compensates.

    The standard fit's stds are 3-4x too small across a warm-up (docs/fleet.md), so its
    own terms cannot be compared with a field calibration's; its yardstick is the field
    model fitted to the same holds, with S estimated when no prior gives it: exactly the
    yardstick ``--model field`` gets, through a file.
    """
    w = _session(1e-4)
    std = calibrate_windows(w, dataclasses.replace(options(), model='standard')).calibration
    field = calibrate_windows(w, dataclasses.replace(options(), model='field')).calibration
    assert std.accel.kind == 'whole_unit_accel' and field.accel.kind == 'field_polynomial'
    y = std.fit['alarm_yardstick']
    assert y['family'] == 'field' and 'error' not in y and 'drift alarms' in y['note']
    assert y['kind'] == 'field_polynomial+S' and 'S is estimated' in y['note']
    want = field.fit['alarm_yardstick']
    for k in ('T0', 'b', 'b_std', 'k', 'k_std'):
        np.testing.assert_allclose(y[k], want[k], rtol=1e-9, atol=1e-15)
    # S's terms (truth 4e-4, -3e-4, 5e-4) within their stds
    z = (np.array(y['s_terms']['value']) - [4e-4, -3e-4, 5e-4]) / y['s_terms']['std']
    assert np.all(np.abs(z) < 4), z
    loaded = Calibration.load(std.save(str(tmp_path / 'std.yaml')))
    cols, ref = _accel_columns(loaded), _accel_columns(field)
    assert cols['accel.alarm_family'] == ref['accel.alarm_family'] == 'field_polynomial+S'
    assert cols.keys() == ref.keys()
    for k, v in ref.items():
        if k != 'accel.alarm_family':
            assert cols[k] == pytest.approx(v, rel=1e-9, abs=1e-15), k
    # the compensation is the standard fit's, untouched
    assert loaded.accel.kind == 'whole_unit_accel'


def test_a_step_across_a_family_switch_is_tested_on_the_yardstick():
    """A bias step on x between a field and a standard calibration raises the alarm.

    Before the yardstick the change across the switch was not tested (seed 19 u00 of the
    alarm bench, docs/fleet.md); without it (a registry written before) it still is not.
    """
    o = options()
    before = calibrate_windows(_session(1e-4, seed=1), dataclasses.replace(o, model='field'))
    after = calibrate_windows(_session(1e-4, seed=2, bias_x=0.05 + 5e-3),
                              dataclasses.replace(o, model='standard'))
    rows = _rows([before.calibration, after.calibration])
    alarms, info = reg.assess(rows)
    assert any('db0 x changed' in a for a in alarms['u']), info['unit_tests']
    assert [n for n in info['notes']['u'] if 'tested on the terms of the field model' in n]
    # `history` shows the terms it tested, the standard fit's row too
    from thermal_imu_calib.fleet.history import format_history
    text = format_history(rows, alarms, info)
    assert 'b0 at T0 x/y/z [mm/s^2]' in text and ' db0 x/y/z' not in text
    line = next(ln.split() for ln in text.splitlines() if ln.strip().startswith(rows[1]['time']))
    assert line[1] == 'whole_unit_accel' and not line[3].startswith('-/'), line
    # a row of a registry written before the alarm columns keeps its field parameters shown
    legacy = [{k: v for k, v in rows[0].items() if not k.startswith('accel.alarm_')}, rows[1]]
    assert ' db0 x/y/z' in format_history(legacy, alarms, info)
    bare = dataclasses.replace(after.calibration, fit={
        k: v for k, v in after.calibration.fit.items() if k != 'alarm_yardstick'})
    old = _rows([before.calibration, bare])
    old_alarms, old_info = reg.assess(old)
    assert not [lbl for lbl, _ in old_info['unit_tests']['u'] if lbl.startswith('db0')]
    assert any('that change is not tested' in n for n in old_info['notes']['u'])


def test_a_yardstick_that_cannot_be_fitted_says_why_and_keeps_the_models_terms():
    """Five faces: the field model refuses; the standard fit keeps its own terms."""
    from thermal_imu_calib.estimation import alarm_yardstick
    from thermal_imu_calib.estimation.calibrate import make_context
    w = _session(1e-4, faces=5, visits=6)
    # a derived minimum hold of 0.5 s is advised as such (it read "at least 0 s")
    y = alarm_yardstick.yardstick(make_context(w, dataclasses.replace(options(),
                                                                      min_hold_s=0.5)))
    assert y['family'] == 'field' and 'cannot be fitted' in y['error']
    assert 'missing -z' in y['error'] and 'still for at least 0.5 s' in y['error']
    assert alarm_yardstick.terms_of({'alarm_yardstick': y}) is None
    cal = Calibration(accel=_whole_unit([0.1, 0.2, 0.3]), fit={'alarm_yardstick': y})
    cols = _accel_columns(cal)
    assert cols['accel.alarm_family'] == 'whole_unit_accel'
    assert cols['accel.alarm_b0.x'] == pytest.approx(0.1)
    # one orientation, or the field model itself with a lab S: no yardstick is fitted
    field = FieldPolynomialModel([30.0] * 3, np.zeros((3, 6)))
    assert not alarm_yardstick.needed('offset', 1, cal.accel)
    assert not alarm_yardstick.needed('field', 6, field, lab_s=True)
    assert alarm_yardstick.needed('field', 6, field)
    assert alarm_yardstick.needed('standard', 6, cal.accel, lab_s=True)


def test_the_yardstick_estimates_a_datasheet_cross_axis_and_stays_honest():
    """With 1-2 % cross-axis terms, tilted holds and no prior, the yardstick estimates S and
    its terms are within their stds, which are far narrower than the S = identity fit's."""
    il = np.tril_indices(3, -1)
    s = np.eye(3)
    s[il] = [1.5e-2, -1.2e-2, 1.8e-2]      # unit diagonal, as the yardstick estimates it
    w = _session(1e-4, s=s, tilt=0.05)
    field = calibrate_windows(w, dataclasses.replace(options(), model='field')).calibration
    y = field.fit['alarm_yardstick']
    assert 'error' not in y, y
    z_s = (np.array(y['s_terms']['value']) - s[il]) / y['s_terms']['std']
    assert np.all(np.abs(z_s) < 4), z_s
    own = bias_scale_terms(field.accel)
    b_true, k_true = (np.diag(v) for v in _truth(own['T0']))     # per axis at its T0
    z_own = (own['k'][:, 0] - k_true) / own['k_std'][:, 0]
    z_yard = (np.array(y['k'])[:, 0] - k_true) / np.array(y['k_std'])[:, 0]
    zb_yard = (np.array(y['b'])[:, 0] - b_true) / np.array(y['b_std'])[:, 0]
    # S = identity does not fit the tilted holds: its stds are inflated by the misfit
    # (chi^2/dof ~ 5000 here, honest but ~60x wider); the yardstick's are not
    assert field.fit['chi2_per_dof'] > 100 and np.all(np.abs(z_own) < 4), z_own
    assert np.all(own['k_std'][:, 0] > 20 * np.array(y['k_std'])[:, 0])
    assert np.all(np.array(y['s_terms']['std']) < 1e-3)        # S is determined by the tilts
    assert np.max(np.abs(z_yard)) < 4 and np.max(np.abs(zb_yard)) < 4, (z_yard, zb_yard)
    # with the part's S from a lab prior the field model is honest itself: no yardstick
    from thermal_imu_calib.calibration import Calibration as Cal
    prior = Cal(accel=FieldPolynomialModel([30.0] * 3, np.zeros((3, 6)), s=s))
    lab = calibrate_windows(w, dataclasses.replace(options(), model='field', prior=prior))
    assert 'alarm_yardstick' not in lab.calibration.fit


def test_a_registry_written_before_the_s_yardstick_starts_a_new_chain_and_says_so():
    """An old field row (S = identity terms) is not compared with a new one (S estimated)."""
    o = dataclasses.replace(options(), model='field')
    old, new = (calibrate_windows(_session(1e-4, seed=s), o).calibration for s in (1, 2))
    legacy = dataclasses.replace(old, fit={k: v for k, v in old.fit.items()
                                           if k != 'alarm_yardstick'})
    rows = _rows([legacy, new])
    assert [r['accel.alarm_family'] for r in rows] == ['field_polynomial', 'field_polynomial+S']
    _, info = reg.assess(rows)
    assert not [lbl for lbl, _ in info['unit_tests']['u'] if lbl.startswith(('db0', 'dk0'))]
    assert [n for n in info['notes']['u'] if 'changed family field_polynomial -> '
            'field_polynomial+S' in n and 'not tested' in n]
    # two new rows are compared
    _, info2 = reg.assess(_rows([old, new]))
    assert [lbl for lbl, _ in info2['unit_tests']['u'] if lbl.startswith('db0')]
    assert not info2['notes']['u']


def test_a_pinned_field_calibration_does_not_import_scipy_stats():
    """scipy.stats costs 0.1-0.3 s of start-up (docs/speed.md: `calibrate --model field`
    against a rosbags loop); only a held-out comparison (``selection.paired``) needs it."""
    import os
    import subprocess
    import sys
    import textwrap
    code = textwrap.dedent('''
        import dataclasses, sys
        sys.path.insert(0, sys.argv[1])
        import numpy as np
        from _thermal_data import G, make_windows, options
        import thermal_imu_calib.cli.commands  # noqa: F401  (what the CLI loads)
        from thermal_imu_calib.estimation.calibrate import calibrate_windows
        rng = np.random.default_rng(0)
        order = np.concatenate([rng.permutation(6) for _ in range(3)])
        t = np.repeat(np.arange(len(order)) * 120.0, 3) + np.tile([0.0, 5.0, 10.0], len(order))
        temp = 20.0 + 20.0 * t / t.max()
        hold = np.repeat(np.arange(len(order)), 3)
        up = np.vstack([np.eye(3), -np.eye(3)])[order][hold]
        w = make_windows(t, temp, 0.05 + 1.002 * G * up, np.zeros_like(up), hold=hold,
                         n=500, sigma_a=2e-3, rng=rng)
        cal = calibrate_windows(w, dataclasses.replace(options(), model='field')).calibration
        print(cal.accel.kind, 'scipy.stats' in sys.modules)
    ''')
    out = subprocess.run([sys.executable, '-c', code, os.path.dirname(__file__)],
                         capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ['field_polynomial', 'False'], out.stdout + out.stderr


def test_the_yardsticks_terms_given_s_are_the_fit_at_that_s():
    """The yardstick's thermal vector given S (gains, stds) is the field fit redone at S.

    The drift alarms carry each calibration's terms to the S pooled over the unit's logs
    (``fleet/pooled_s.py``) with these gains; they must predict the fit at another S.
    """
    from thermal_imu_calib.estimation.context import make_context
    from thermal_imu_calib.estimation.field_estimator import fit_field_model, s_of_terms
    il = np.tril_indices(3, -1)
    s = np.eye(3)
    s[il] = [1.5e-2, -1.2e-2, 1.8e-2]
    w = _session(1e-4, s=s, tilt=0.05)
    ctx = make_context(w, dataclasses.replace(options(), model='field'))
    g = ctx.options.gravity
    free = fit_field_model(w, ctx.ta, g, ctx.t0, free_s=True)
    q, cond = free.model.s[il], free.s_condition
    at_q = fit_field_model(w, ctx.ta, g, ctx.t0, s=s_of_terms(q))
    np.testing.assert_allclose(at_q.model.thermal, free.model.thermal, atol=1e-7)
    np.testing.assert_allclose(at_q.model.thermal_std, cond.std, rtol=0.02)
    d = np.array([1e-3, -2e-3, 1.5e-3])
    moved = fit_field_model(w, ctx.ta, g, ctx.t0, s=s_of_terms(q + d)).model.thermal
    change = moved - free.model.thermal
    assert np.abs(change - cond.gain @ d).max() < 0.02 * np.abs(change).max()
    # what the data say about S: with the prior's information once, its fitted terms
    info = cond.info + np.eye(3) / 2e-2 ** 2
    np.testing.assert_allclose(np.linalg.solve(info, cond.eta), q, atol=0.05 * free.s_std.max())


def test_the_yardsticks_curvature_on_s_predicts_the_fit_far_from_its_s():
    """The scale factor at another S, to second order: six faces leave its gain near 0.

    On the +-x faces the tilt takes up s10 and s20 and |c| = 1 shortens x's own component
    by (s10^2 + s20^2) / 2, so k_x grows by that (k_y by s21^2 / 2 on the +-y faces); the
    gains at the fitted S miss it, the stored curvature (``alarm_yardstick.K_CURVATURE``,
    the Gauss-Newton gain's derivative) follows a refit at S two prior stds away.
    """
    from thermal_imu_calib.estimation.alarm_yardstick import _k_curvature
    from thermal_imu_calib.estimation.context import make_context
    from thermal_imu_calib.estimation.field_estimator import fit_field_model, s_of_terms
    from thermal_imu_calib.models.alarm_terms import coefficients
    il = np.tril_indices(3, -1)
    s = np.eye(3)
    s[il] = [1.5e-2, -1.2e-2, 1.8e-2]
    w = _session(1e-4, s=s)
    ctx = make_context(w, dataclasses.replace(options(), model='field'))
    g = ctx.options.gravity
    free = fit_field_model(w, ctx.ta, g, ctx.t0, free_s=True)
    q, cond, m = free.model.s[il], free.s_condition, free.model
    k = coefficients(m, m.t0)[1]
    curv = _k_curvature(m, cond.curvature.tolist(), k)
    np.testing.assert_allclose(curv[0], np.diag([1.0, 1.0, 0.0]), atol=0.03)
    np.testing.assert_allclose(curv[1], np.diag([0.0, 0.0, 1.0]), atol=0.03)
    d = np.array([4e-2, -3e-2, 4e-2])
    moved = fit_field_model(w, ctx.ta, g, ctx.t0, s=s_of_terms(q + d)).model
    change = coefficients(moved, m.t0)[1][:, 0] - k[:, 0]
    linear = cond.gain[:, 0] @ d
    quadratic = linear + 0.5 * np.einsum('amn,m,n->a', curv, d, d)
    assert np.abs(change[:2] - linear[:2]).min() > 5e-4          # the gains alone miss it
    assert np.abs(change - quadratic).max() < 0.05 * np.abs(change - linear).max()


def _pooled_rows(gains, values, std_s=1e-4, info=1e2, name='b', q=None, k_dss=None):
    """Rows of one unit whose ``name`` terms have the gains ``gains[i]`` (3, 3) on S.

    ``q[i]``: row i's own S terms (0), with its information vector info q[i];
    ``k_dss``: the scale factor's curvature on S (3, 3, 3), stored in every row.
    """
    from thermal_imu_calib.fleet import pooled_s
    rows = []
    for i, (gain, value) in enumerate(zip(gains, values)):
        field = FieldPolynomialModel([30.0] * 3, np.zeros((3, 6)),
                                     thermal_std=np.full((3, 6), 1e-3))
        r = reg.index_row('u', Calibration(accel=field), (1_700_000_000 + 86400 * i) * 10 ** 9,
                          (1_700_000_000 + 86400 * i - 3600) * 10 ** 9, f'u/{i}.yaml', ['a'])
        r['accel.alarm_family'] = 'field_polynomial+S'
        r[f'accel.alarm_{name}0.x'] = value
        own = np.zeros(3) if q is None else np.asarray(q[i], float)
        terms = {'s': own, 's_eta': info * own, 's_info': np.eye(3) * info,
                 'b_std_s': np.full((3, 3), std_s), 'k_std_s': np.full((3, 3), std_s),
                 'b_ds': np.zeros((3, 3, 3)), 'k_ds': np.zeros((3, 3, 3))}
        terms[f'{name}_ds'][:, 0] = gain
        if k_dss is not None:
            terms['k_dss'] = np.asarray(k_dss, float)
        r.update(pooled_s.columns(terms))
        rows.append({k: str(v) for k, v in r.items()})
    return rows


def test_the_alarms_compare_terms_at_the_units_pooled_s():
    """A change is tested at the pooled S: the S part cancels between equal gains.

    The fit's marginal std (1e-3 here) carries S's whole uncertainty; given S the terms are
    known to 1e-4, and S* (prior 2e-2, each log's information 1e2) is uncertain by
    (1 / 2e-2^2 + 3e2)^-1/2, so a gain difference adds (G1 - G0) Cov(S*) (G1 - G0)'.
    """
    same = np.full((3, 3), 0.1)
    rows = _pooled_rows([same] * 3, [0.0, 1e-3, 1e-3])
    z = dict(reg.unit_tests(rows))
    first = next(v for k, v in z.items() if k.startswith('db0 x changed'))
    assert first == pytest.approx(1e-3 / np.sqrt(2 * 1e-4 ** 2), rel=1e-6)
    other = [same, same + np.diag([0.5, 0, 0]), same]
    var_s = 1.0 / (1 / 2e-2 ** 2 + 3 * 1e2)
    z2 = dict(reg.unit_tests(_pooled_rows(other, [0.0, 1e-3, 1e-3])))
    first2 = next(v for k, v in z2.items() if k.startswith('db0 x changed'))
    assert first2 == pytest.approx(1e-3 / np.sqrt(2 * 1e-4 ** 2 + 0.5 ** 2 * var_s), rel=1e-6)
    # the trend: slope over equal steps of a day, variance with the shared S part
    trend = next(v for k, v in z2.items() if k.startswith('db0 x trend'))
    t = np.arange(3.0)
    a = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    g = np.array([0.1, 0.6, 0.1])
    slope = a @ np.array([0.0, 1e-3, 1e-3])
    assert trend == pytest.approx(slope / np.sqrt(a @ a * 1e-8 + (a @ g) ** 2 * var_s), rel=1e-6)
    # without the columns (a registry written before them): the marginal stds
    from thermal_imu_calib.fleet.pooled_s import without_given_s
    plain = without_given_s(rows)
    assert len(rows[0]) - len(plain[0]) == 3 + 3 + 9 + 2 * 9 * (1 + 3)
    z3 = dict(reg.unit_tests(plain))
    first3 = next(v for k, v in z3.items() if k.startswith('db0 x changed'))
    assert first3 == pytest.approx(1e-3 / np.sqrt(2 * 1e-3 ** 2), rel=1e-6)
    assert 'S pooled over' in reg.assess(rows)[1]['rule']
    assert 'S pooled over' not in reg.assess(plain)[1]['rule']


def test_the_scale_factor_is_compared_at_the_pooled_s_with_its_curvature(tmp_path):
    """With its curvature stored, dk0 goes to S* to second order; without, its own stds.

    Two logs whose own S differ in s10 (2e-2 and 0, each log's information 1e2): S* is their
    information-weighted mean with the prior's, each scale factor moves by
    0.5 H (S* - q)^2 and its gain at S* is H (S* - q), whose difference carries Cov(S*).
    """
    h = np.zeros((3, 3, 3))
    h[0] = np.diag([1.0, 1.0, 0.0])
    q = [[2e-2, 0, 0], [0, 0, 0]]
    zero = np.zeros((3, 3))
    rows = _pooled_rows([zero, zero], [1.0, 1.0005], name='k', q=q, k_dss=h)
    info = np.eye(3) / 2e-2 ** 2 + 2 * 1e2 * np.eye(3)
    cov = np.linalg.inv(info)
    s_star = cov @ (1e2 * np.array(q).sum(0))
    ds = [s_star - np.array(qi) for qi in q]
    v = [1.0 + 0.5 * ds[0] @ h[0] @ ds[0], 1.0005 + 0.5 * ds[1] @ h[0] @ ds[1]]
    dg = h[0] @ ds[1] - h[0] @ ds[0]
    want = (v[1] - v[0]) / np.sqrt(2 * 1e-4 ** 2 + dg @ cov @ dg)
    z = dict(reg.unit_tests(rows))
    got = next(val for key, val in z.items() if key.startswith('dk0 x changed'))
    assert got == pytest.approx(want, rel=1e-6)
    # the history says at which S the z's are
    from thermal_imu_calib.fleet.history import format_history
    found, info = reg.assess(rows)
    text = format_history(rows, found, info)
    said = (f'S pooled over 2 calibration(s): s10 {s_star[0] * 1e4:.1f}'
            f'+-{np.sqrt(cov[0, 0]) * 1e4:.1f}, s20 0.0')
    assert said in text, text
    from thermal_imu_calib.fleet.history import write_html
    page = tmp_path / 'history.html'
    write_html(str(page), rows, found, info)
    assert said in page.read_text()
    # rows written before the curvature: the scale factor with its own stds (1e-3)
    plain = _pooled_rows([zero, zero], [1.0, 1.0005], name='k', q=q)
    z2 = dict(reg.unit_tests(plain))
    got2 = next(val for key, val in z2.items() if key.startswith('dk0 x changed'))
    assert got2 == pytest.approx(5e-4 / np.sqrt(2 * 1e-3 ** 2), rel=1e-6)
