"""The spec of the calibration in use offered to the next estimate (``incumbent_spec``)."""

import json
import os

import numpy as np
import pytest

from _robot_month import lifelong_month
from thermal_imu_calib.estimation.hysteresis import (ARDUPILOT_SPEC, NO_THERMAL_SPEC, Spec,
                                                     spec_from_dict)
from thermal_imu_calib.lifelong import incumbent
from thermal_imu_calib.lifelong.config import LifelongConfig
from thermal_imu_calib.selection.time_folds import choose

CHAMBER = os.path.join(os.path.dirname(__file__), 'fixtures', 'real', 'tofupilot_chamber',
                       'imu_chamber_train.csv.gz')

LINEAR = Spec(1, (), (), 'time')
LAGGED = Spec(2, (216.3,), (('diff', (50.0, 500.0)),), 'temperature')


@pytest.mark.parametrize('spec', [LINEAR, LAGGED, ARDUPILOT_SPEC, NO_THERMAL_SPEC])
def test_a_spec_comes_back_equal_from_its_state(spec):
    item = json.loads(json.dumps(spec.to_dict()))
    assert spec_from_dict(item) == spec
    assert incumbent.from_state(item) == spec
    assert hash(spec_from_dict(item)) == hash(spec)


@pytest.mark.parametrize('item', [None, 3, 'cubic', {'order': 'x'}, {'base': []}])
def test_anything_else_in_the_state_offers_nothing(item):
    assert incumbent.from_state(item) is None
    assert incumbent.offered({'active_specs': {'accel': item}},
                             LifelongConfig(incumbent_spec='accel')) is None
    assert incumbent.from_state('rvm') == 'rvm'


def test_the_spec_in_use_is_kept_while_it_is_within_the_margin_of_the_best():
    raw = np.ones(4)
    figs = {NO_THERMAL_SPEC: [1.0] * 4, LINEAR: [0.90] * 4, LAGGED: [0.89] * 4,
            ARDUPILOT_SPEC: [0.95] * 4}
    # without it: the simplest within 3 % of the best (0.89): the linear slope
    assert choose(figs, raw)[0] == LINEAR
    assert choose(figs, raw, LAGGED)[0] == LAGGED
    # no thermal terms is 12 % worse than the best: not in the pool, not kept
    assert choose(figs, raw, NO_THERMAL_SPEC)[0] == LINEAR
    # a spec in use worse than the flight stacks' cubic is not kept either
    figs[LAGGED] = [0.96] * 4
    assert choose(figs, raw, LAGGED)[0] == LINEAR


def test_off_offers_nothing_and_accel_offers_the_accelerometer_only():
    state = {'active_specs': {'accel': LINEAR.to_dict(), 'gyro': 'rvm'}}
    assert incumbent.offered(state, LifelongConfig()) is None
    assert incumbent.offered(state, LifelongConfig(incumbent_spec='accel')) == \
        {'accel': LINEAR}
    assert incumbent.offered(state, LifelongConfig(incumbent_spec='both')) == \
        {'accel': LINEAR, 'gyro': 'rvm'}
    with pytest.raises(ValueError, match='incumbent_spec'):
        LifelongConfig(incumbent_spec='yes')


def test_the_loop_offers_the_active_spec_and_says_what_became_of_it(tmp_path):
    """On a robot's first day and a half: the active spec is known after each swap, and
    the next estimate on a history path says whether it kept it."""
    life = lifelong_month(tmp_path / 'life', LifelongConfig(incumbent_spec='accel'))
    swaps = [d for d in life.decisions() if d['action'] == 'swap']
    assert swaps, life.decisions()
    specs = life.state['active_specs']
    assert set(specs) == {'accel', 'gyro'}
    offered = incumbent.offered(life.state, life.config)
    if specs['accel'] is not None:
        assert isinstance(offered['accel'], Spec)
    # the newest model came from the history paths, which were offered the spec in use
    # (the swap before it activated one) and say in the file what became of it
    reason = life.active.fit['selection']['reason']
    assert "the calibration in use's" in reason, reason
    assert 'kept (within the margin of the best)' in reason or 'replaced' in reason
    # the state survives a restart: a new loop on the same directory offers the same
    from thermal_imu_calib.app.calibrate import CalibrateSettings
    from thermal_imu_calib.lifelong.manager import Lifelong
    again = Lifelong(str(tmp_path / 'life'), CalibrateSettings(latitude=45.0), 1,
                     ['/imu/temperature'], 'imu_link', config=life.config)
    assert incumbent.offered(again.state, again.config) == offered


def test_the_one_way_path_is_offered_no_history_terms(monkeypatch):
    """One leg cannot tell a history term (it flips with the rate's sign): a spec in use
    with one is not scored there, a plain polynomial in the reading is. The real chamber
    log's cooling leg (51.6 -> -17.6 degC, one way)."""
    import thermal_imu_calib.selection.one_way_select as ow
    from thermal_imu_calib.calibration import TemperatureInput
    from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
    from thermal_imu_calib.io.csv_logs import read_tofupilot_chamber
    from thermal_imu_calib.collection.feed import windows_from_columns
    imu, tc = read_tofupilot_chamber(CHAMBER)
    w = windows_from_columns([imu], [tc])
    t_turn = imu.stamp_ns[np.argmin(tc.temperature)] * 1e-9
    leg = w.select(0.5 * (w.t0 + w.t1) <= t_turn)
    seen = []
    real = ow.spec_figures

    def spy(w, idx, sig, specs, *a, **k):
        seen.append((sig, list(specs)))
        return real(w, idx, sig, specs, *a, **k)
    monkeypatch.setattr(ow, 'spec_figures', spy)
    quartic = Spec(4, (), (), 'time')
    for offered, scored in ((LAGGED, False), (quartic, True)):
        seen.clear()
        opts = CalibrateOptions(inputs=[TemperatureInput('/imu/temperature')],
                                incumbent_specs={'accel': offered})
        reason = calibrate_windows(leg, opts).calibration.fit['model_choice']['reason']
        accel = [specs for sig, specs in seen if sig == 'accel']
        assert accel, 'the one-way path did not run'
        assert (offered in accel[0]) is scored
        assert ("the calibration in use's order 4 T" in reason) is scored
