"""A swap held back until holds collected after its estimate judge it (``prequential_holds``)."""

import copy
import dataclasses
import os

import numpy as np
import pytest

from _robot_month import lifelong_month
from thermal_imu_calib.app.calibrate import CalibrateSettings
from thermal_imu_calib.lifelong import prequential
from thermal_imu_calib.lifelong.config import LifelongConfig
from thermal_imu_calib.lifelong.manager import Lifelong

DAY = 86400.0
TOPIC = '/imu/temperature'


def _biased(cal, gyro_rad_s):
    """Return ``cal`` with a constant gyro bias (rad/s, x axis) added to its model."""
    g = copy.copy(cal.gyro)
    g.offset = np.array(g.offset, float)
    g.offset[0, 0] += gyro_rad_s
    return dataclasses.replace(cal, gyro=g)


def _loop(directory, month_windows, active, pending, n=4):
    """Return (a loop on the month's first 20 holds with ``active``, a swap to ``pending``
    held back at the 20th hold's end, the windows of the next ``n`` + 1 holds by hold)."""
    _, win = month_windows
    ids = win.hold_ids
    life = Lifelong(str(directory), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(prequential_holds=n, new_holds=1000))
    first = win.select(np.isin(win.hold, ids[:20]))
    life.store.add(first)
    life.active = active
    life.state.update(holds_at_estimate=life.store.total_holds, active_gyro_rms=1.0,
                      active_accel_rms=1.0, active_accel_median=0.0)
    now = float(first.t1.max())
    life.pending = pending
    life._save_cal(pending, prequential.PENDING)
    life.state['pending'] = prequential.record(pending, now, None, None)
    life._save_state()
    later = [win.select(win.hold == h) for h in ids[20:21 + n]]
    return life, later


@pytest.mark.parametrize('bad', ['active', 'pending'])
def test_the_later_holds_take_the_better_calibration_and_keep_the_worse(tmp_path,
                                                                        month_windows, bad):
    """Nothing happens before the N-th later hold; then the swap takes effect when those
    holds favour it and the held-back calibration becomes the candidate when they don't."""
    m, _ = month_windows
    truth = m.true_calibration(0.5 * DAY)
    worse = _biased(truth, 2e-3)        # 2 mrad/s: ~100x the month's gyro hold noise
    active, pending = (worse, truth) if bad == 'active' else (truth, worse)
    life, later = _loop(tmp_path, month_windows, active, pending, n=4)
    for w in later[:3]:
        life.add(w)
        assert life.due() == ''
    # nothing else is due while it waits: the holds the active misses would make an
    # estimate due (``trigger.due``), which must not replace it before it is judged
    life.state['missed'] = [(0.0, 20.0), (1.0, 21.0)]
    assert life.due() == ''
    life.state['missed'] = []
    # a restart in between: the held-back swap comes back from the directory
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=life.config)
    assert life.pending is not None and life.pending.id == pending.id
    life.active = active
    life.add(later[3])
    assert life.due() == prequential.REASON
    decision = life.estimate(life.due())
    assert decision['reason'] == prequential.REASON and decision['heldout_holds'] == 4
    assert life.pending is None and life.state['pending'] is None
    assert not os.path.exists(tmp_path / prequential.PENDING)
    if bad == 'active':
        assert decision['action'] == 'swap', decision['text']
        assert life.active.id == truth.id and life.state['swaps'] == 1
        assert 'the 4 holds collected after its estimate favour it' in decision['text']
    else:
        assert decision['action'] == 'keep', decision['text']
        assert life.active.id == truth.id and life.candidate.id == worse.id
        assert "do not favour it" in decision['text']
        assert os.path.exists(tmp_path / 'candidate.yaml')
    assert life.status()['pending'] == ''


def test_a_change_alarm_or_a_reset_turns_the_held_back_swap_into_the_candidate(
        tmp_path, month_windows):
    m, _ = month_windows
    truth = m.true_calibration(0.5 * DAY)
    life, later = _loop(tmp_path / 'a', month_windows, _biased(truth, 2e-3), truth)
    assert life.status()['pending'] == truth.id
    life.reset()
    assert life.pending is None and life.candidate.id == truth.id
    assert not os.path.exists(tmp_path / 'a' / prequential.PENDING)
    assert life.due() != prequential.REASON
    # the alarm path: the same drop (``_drop_pending``), called where the alarm is logged
    life, later = _loop(tmp_path / 'b', month_windows, _biased(truth, 2e-3), truth)
    life._drop_pending()
    assert life.pending is None and life.state['pending'] is None
    assert life.candidate.id == truth.id


def test_off_and_without_an_active_calibration_nothing_waits():
    state = {'alarm_pending': False}
    on = LifelongConfig(prequential_holds=8)
    assert not prequential.holds_back(LifelongConfig(), state, object())
    assert prequential.holds_back(on, state, object())
    assert not prequential.holds_back(on, state, None)          # the first calibration
    assert not prequential.holds_back(on, {'alarm_pending': True}, object())  # a knock
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match='prequential_holds'):
            LifelongConfig(prequential_holds=bad)


def test_the_loop_holds_swaps_back_and_judges_them_on_later_holds(tmp_path):
    """On a robot's first day and a half: the first calibration is taken at once; every
    later swap the gate passes waits, and is judged on holds collected after it."""
    life = lifelong_month(tmp_path / 'life', LifelongConfig(prequential_holds=4))
    d = life.decisions()
    acts = [x['action'] for x in d]
    assert 'swap' in acts and 'pending' in acts, acts
    first = acts.index('swap')
    assert d[first]['reason'] != prequential.REASON         # no active yet: at once
    judged = [x for x in d if x['reason'] == prequential.REASON]
    assert judged, acts
    for x in judged:
        assert x['action'] in ('swap', 'keep') and x['heldout_holds'] >= 4
        assert x['time'] > x['held_back']['time']
        # the decision before it held that calibration back
        held = [y for y in d if y['action'] == 'pending' and y['id'] == x['id']]
        assert held and held[-1]['time'] == x['held_back']['time']
    # each held-back swap is judged before any other estimate
    for a, b in zip(d, d[1:]):
        if a['action'] == 'pending':
            assert b['reason'] == prequential.REASON or b['action'] == 'alarm', (a, b)
    # every swap after the first was judged on later holds
    later_swaps = [x for x in d[first + 1:] if x['action'] == 'swap']
    assert all(x['reason'] == prequential.REASON or 'alarm' in x['reason']
               for x in later_swaps), [(x['reason'], x['text'][:80]) for x in later_swaps]
    # the held-back one (if any) is on disk exactly while the state names it
    assert os.path.exists(tmp_path / 'life' / prequential.PENDING) == \
        bool(life.state['pending'])
