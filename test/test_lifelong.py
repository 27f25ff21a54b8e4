"""Lifelong core (no ROS): hold store bounds and restarts, motion hints, swap gate, loop.

Real numbers throughout: windows come from the stationary detector run on the simulated
robot month (``sim.robot_month``), calibrations from ``app.calibrate.calibrate_collected``.
"""

import ast
import dataclasses
import json
import os
import re

import numpy as np
import pytest

from thermal_imu_calib.app.calibrate import CalibrateSettings
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.fleet import registry
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.lifelong import alarm, compose, gate, knock_step
from thermal_imu_calib.lifelong.feed import Feeder
from thermal_imu_calib.lifelong.hints import HintGate, HintSource, twist_still
from thermal_imu_calib.lifelong.manager import Lifelong, LifelongConfig, main_pose
from thermal_imu_calib.lifelong.pose import main_pose_mask
from thermal_imu_calib.lifelong.store import HoldStore, StoreConfig
from thermal_imu_calib.sim.robot_month import DAY, robot_month

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOPIC = '/imu/temperature'


def test_core_imports_no_ros():
    bad = []
    base = os.path.join(ROOT, 'thermal_imu_calib', 'lifelong')
    for name in os.listdir(base):
        if name.endswith('.py'):
            tree = ast.parse(open(os.path.join(base, name)).read())
            for node in ast.walk(tree):
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                    [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
                bad += [f'{name}: {m}' for m in mods if m.split('.')[0] in (
                    'rclpy', 'geometry_msgs', 'nav_msgs', 'std_msgs', 'sensor_msgs')]
    assert not bad, bad


def test_robot_month_is_what_it_says():
    m = robot_month(0, days=4)
    s = m.summary()
    dur = np.array([st.t1 - st.t0 for st in m.stops])
    assert 10.0 <= dur.min() and dur.max() <= 600.0
    assert 30 * 4 * 0.8 <= s['stops'] <= 60 * 4
    assert 0.0 <= s['temperature_degC'][0] and s['temperature_degC'][1] <= 40.0
    assert s['slopes'] > 0 and s['blocked'] > 0 and s['pushes'] > 0
    # deterministic per seed; another seed is another month
    assert robot_month(0, days=4).summary() == s
    assert robot_month(1, days=4).summary() != s
    seg = next(x for x in m.segments() if x.stop.push is not None)
    assert not seg.still[(seg.imu.t >= seg.stop.push[0] + m.start_ns * 1e-9)
                         & (seg.imu.t < seg.stop.push[1] + m.start_ns * 1e-9)].any()
    # ageing and the knock move the true biases
    assert m.knock_t == np.inf                   # 4 days: before the knock (day 12-22)
    k = robot_month(0, days=4, knock_day=(2.0, 3.0))
    (a0, g0), (a1, g1) = k.bias_change([k.knock_t - 1]), k.bias_change([k.knock_t + 1])
    assert np.linalg.norm(g1 - g0) >= 2e-3 and np.linalg.norm(a1 - a0) >= 0.03
    stop = k.stops[len(k.stops) // 2]
    seg = k.segment(stop)
    raw = k.true_calibration(stop.t0).apply(seg.imu.accel[seg.still], seg.imu.gyro[seg.still],
                                            seg.temp_true[seg.still][:, None])
    # the true calibration at that time compensates the stop to the noise
    assert np.linalg.norm(np.mean(raw.gyro - seg.angular_rate[seg.still], 0)) < 1e-4


def test_store_bounds_compaction_and_restart(tmp_path, month_windows):
    _, win = month_windows
    cfg = StoreConfig(max_recent_holds=10, max_recent_windows=400)
    st = HoldStore(str(tmp_path / 's'), 1, cfg)
    ids = win.hold_ids
    for h in ids:
        st.add(win.select(win.hold == h))
        assert len(st.recent.hold_ids) <= 10 and len(st.recent) <= 400
    assert st.total_holds == len(ids)
    assert len(st.bins) > 0 and st.clusters
    w = st.windows(now=float(win.t1.max()))
    # one pseudo-hold per cluster first, then the raw holds; ids ascending (as a log's)
    assert len(w) == len(st.bins) + len(st.recent)
    assert len(w.hold_ids) == len(st.clusters) + len(st.recent.hold_ids)
    assert np.all(np.diff(w.hold_ids) > 0) and w.hold_ids[0] == 0
    # compacted statistics keep the samples' weight (no fading within 1.5 days: > 90 %)
    assert w.n.sum() > 0.9 * win.n.sum()
    lo, hi = st.temperature_span()
    assert lo == pytest.approx(win.temp[:, 0].min(), abs=0.5)
    assert hi == pytest.approx(win.temp[:, 0].max(), abs=0.5)
    size = st.disk_bytes()
    # restart: the same holds, counters and bins from the directory
    again = HoldStore(str(tmp_path / 's'), 1, cfg)
    assert again.total_holds == st.total_holds and again.next_hold == st.next_hold
    assert len(again.recent) == len(st.recent) and len(again.bins) == len(st.bins)
    np.testing.assert_allclose(again.windows(float(win.t1.max())).accel, w.accel)
    # a torn last line (killed mid-append) is dropped, the rest kept
    with open(tmp_path / 's' / 'recent.jsonl', 'a') as f:
        f.write('{"hold": 99999, "t0": 1.0, "t1"')
    assert len(HoldStore(str(tmp_path / 's'), 1, cfg).recent) == len(st.recent)
    assert size < 400 * 700 + 200_000          # the stated bound: ~0.5 kB per raw window
    # a cut drops everything before it
    t_cut = float(np.median(st.recent.t0))
    st.cut(t_cut)
    assert len(st.bins) == 0 and (st.recent.t0 >= t_cut).all()


def test_store_refuses_other_inputs(tmp_path, month_windows):
    _, win = month_windows
    HoldStore(str(tmp_path), 1).add(win.select(win.hold == win.hold_ids[0]))
    with pytest.raises(ValueError, match='thermal inputs'):
        HoldStore(str(tmp_path), 2)


def test_hint_gate_intervals_and_filter(month_windows):
    _, win = month_windows
    g = HintGate([HintSource('cmd_vel', True, 1.0), HintSource('still', False, 1.0)])
    assert g.intervals('cmd_vel') == [(-np.inf, np.inf)]       # silent command: still
    assert g.intervals('still') == []                            # silent Bool: unknown
    g.add('still', 100.0, True)
    for t in np.arange(100.0, 200.0, 0.5):                       # a Bool at 2 Hz
        g.add('still', t, True)
    assert len(g.events['still']) == 1                           # one segment, not 200
    g.add('cmd_vel', 150.0, False)                               # driving 150..151
    assert g.intervals('still') == [(100.0, 200.5)]
    ok = g.still_over([110.0, 149.0, 150.5, 152.0, 199.0],
                      [120.0, 150.2, 150.8, 160.0, 201.0])
    assert ok.tolist() == [True, False, False, True, False]
    assert twist_still([0, 0, 0], [0, 0, 5e-4]) and not twist_still([0.2, 0, 0], [0, 0, 0])
    # windows: without sources all pass; with a hint saying drive nothing passes
    assert len(HintGate().filter(win)) == len(win)
    drive = HintGate([HintSource('still', False, 1e9)])
    drive.add('still', float(win.t0.min()) - 1, False)
    assert len(drive.filter(win)) == 0 and drive.counts['windows_refused'] == len(win)


def test_swap_gate_on_real_calibrations(month_windows):
    m, win = month_windows
    truth = m.true_calibration(0.5 * DAY)
    holdout = main_pose(win.select(np.isin(win.hold, win.hold_ids[-10:])), 2.0)
    s_true = gate.score(truth, holdout, truth.gravity)
    s_raw = gate.score(None, holdout, truth.gravity)
    swap, fig = gate.decide(s_raw, s_true)
    assert swap and fig['gyro']['verdict'] == 'better'
    assert s_true['gyro_rms'] < 0.1 * s_raw['gyro_rms']
    swap, fig = gate.decide(s_true, s_true)          # the same model: never a swap
    assert not swap and fig['gyro']['verdict'] == 'same'
    swap, fig = gate.decide(s_true, s_raw)           # worse: kept
    assert not swap and fig['gyro']['verdict'] == 'worse'
    assert 'mdeg/s' in gate.describe(fig)
    # no held-out hold in the mounting pose: the accelerometer is not judged (seed 2 of the
    # month bench ended on this)
    empty = holdout.select(np.zeros(len(holdout), bool))
    s_t, s_r = (gate.score(c, holdout, truth.gravity, empty) for c in (truth, None))
    swap, fig = gate.decide(s_r, s_t)
    assert swap and fig['accel']['verdict'] == 'same' and s_t['accel_holds'] == 0


def test_vector_accel_score_sees_the_horizontal_axes(month_windows):
    """The 'vector' accelerometer score sees a horizontal error; 'magnitude' cannot.

    A horizontal error of 50 mm/s^2 per hold changes |a| by ~0.1 mm/s^2 in a level pose.
    """
    m, win = month_windows
    truth = m.true_calibration(0.5 * DAY)
    holdout = main_pose(win.select(np.isin(win.hold, win.hold_ids[-10:])), 2.0)
    sign = np.where(np.searchsorted(holdout.hold_ids, holdout.hold) % 2 == 0, 1.0, -1.0)
    accel = holdout.accel.copy()
    accel[:, 0] += 0.05 * sign                  # a wrong x offset, alternating per hold
    shifted = dataclasses.replace(holdout, accel=accel)
    for how, verdict in (('magnitude', 'same'), ('vector', 'better')):
        s_bad = gate.score(truth, shifted, truth.gravity, accel_score=how)
        s_good = gate.score(truth, holdout, truth.gravity, accel_score=how)
        _, fig = gate.decide(s_bad, s_good)
        assert fig['accel']['verdict'] == verdict, (how, fig['accel'])
        # the change alarm's reference is the magnitude figure either way
        assert s_good['accel_magnitude_rms'] == pytest.approx(
            gate.score(truth, holdout, truth.gravity)['accel_rms'])
    with pytest.raises(ValueError, match='accel_score'):
        gate.score(truth, holdout, truth.gravity, accel_score='norm')
    with pytest.raises(ValueError, match='accel_score'):
        LifelongConfig(accel_score='norm')


def test_lifelong_loop_swaps_logs_and_restarts(tmp_path):
    m = robot_month(3, days=1.2)
    d = str(tmp_path / 'life')
    logs = []
    cfg = LifelongConfig(new_holds=25)

    def make():
        return Lifelong(d, CalibrateSettings(), 1, [TOPIC], 'imu_link',
                        registry_dir=str(tmp_path / 'reg'), config=cfg,
                        log=lambda level, text: logs.append(text))
    life = make()
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    half = m.config.days * DAY / 2
    for seg in m.segments(0, half):
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    # restart: the state comes back from the directory
    total = life.store.total_holds
    active = life.active
    life = make()
    assert life.store.total_holds == total
    assert (life.active is None) == (active is None)
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    for seg in m.segments(half):
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    decisions = life.decisions()
    swaps = [x for x in decisions if x['action'] == 'swap']
    assert swaps, decisions
    for x in decisions:                           # every decision with its figures
        assert x['reason'] and x['text']
        if x['action'] in ('swap', 'keep'):
            f = x['figures']['gyro']
            assert {'active_rms', 'new_rms', 'margin', 'verdict'} <= set(f)
            assert (x['action'] == 'swap') == (
                'better' in (f['verdict'], x['figures']['accel']['verdict'])
                and x['figures']['net_margins'] > 1.0)
    # the registry holds every activated calibration: history works for one robot
    rows = registry.read_index(str(tmp_path / 'reg'))
    assert len(rows) == len(swaps) and {r['sensor'] for r in rows} == {'imu_link'}
    assert registry.load_valid(str(tmp_path / 'reg'), 'imu_link').id == life.active.id
    from thermal_imu_calib import cli
    assert cli.main(['history', str(tmp_path / 'reg')]) == 0
    # the active calibration compensates the gyro of later stops far better than raw
    seg = [s for s in m.segments(0.9 * m.config.days * DAY) if s.still.sum() > 100][0]
    st = seg.still
    temps = seg.temp_true[st][:, None]
    res = life.active.apply(seg.imu.accel[st], seg.imu.gyro[st], temps)
    err = np.linalg.norm(np.mean(res.gyro - seg.angular_rate[st], 0))
    raw = np.linalg.norm(np.mean(seg.imu.gyro[st] - seg.angular_rate[st], 0))
    assert err < 0.3 * raw, (err, raw)
    st_ = life.status(temperature=20.0, now=float(life.store.recent.t1.max()))
    assert st_['active'] == life.active.id and st_['holds_total'] == life.store.total_holds
    assert 'recent_gyro_rms_rad_s' in st_ and 'in_range' in st_
    assert json.loads(open(os.path.join(d, 'state.json')).read())['swaps'] == len(swaps)


def test_blocked_and_pushed_stops_are_not_collected(tmp_path):
    """Stops while the command says drive are refused; a push splits the hold."""
    m = robot_month(0, days=2)
    blocked = [s for s in m.stops if s.blocked and s.t1 - s.t0 > 60]
    assert blocked
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link')
    gate_ = HintGate([HintSource('cmd_vel', True, 1.0)])
    feeder = Feeder(life, gate_, estimate=False)
    for seg in m.segments():
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    feeder.finish()
    rec = life.store.recent
    base = m.start_ns * 1e-9
    for s in blocked:
        inside = (rec.t0 >= base + s.t0 - 1) & (rec.t1 <= base + s.t1 + 1)
        assert not inside.any(), f'blocked stop {s.index} collected'
    assert gate_.counts['windows_refused'] > 0
    # without hints the blocked stops are collected (the detector alone decides)
    life2 = Lifelong(str(tmp_path / 'nohints'), CalibrateSettings(), 1, [TOPIC], 'imu_link')
    f2 = Feeder(life2, None, estimate=False)
    for seg in m.segments():
        f2.push(seg.imu, [seg.temperature])
    f2.finish()
    assert life2.store.total_holds > life.store.total_holds


def test_simulate_robot_month_writes_a_log_with_hints(tmp_path):
    from thermal_imu_calib.io.bag import open_log
    from thermal_imu_calib.sim.robot_month import write_robot_month
    r = write_robot_month(tmp_path / 'rm.mcap', 4, days=0.3)
    with open_log(str(tmp_path / 'rm.mcap')) as rd:
        text = rd.info().format()
    assert '/cmd_vel' in text and 'geometry_msgs/msg/Twist' in text
    assert r['summary']['messages']['/imu/data_raw'] == r['summary']['imu_samples']
    assert os.path.exists(r['side'])


def test_simulate_lists_robot_month(capsys):
    from thermal_imu_calib import cli
    assert cli.main(['simulate', '-', '--list']) == 0
    assert 'robot-month' in capsys.readouterr().out


def test_knock_raises_an_alarm_then_a_new_calibration_recovers(tmp_path):
    m = robot_month(1, days=2.0, knock_day=(1.0, 1.1))
    reg_dir = str(tmp_path / 'registry')
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    registry_dir=reg_dir)
    feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
    for seg in m.segments():
        feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    base = m.start_ns * 1e-9
    dec = life.decisions()
    alarms = [d['time'] - base for d in dec if d['action'] == 'alarm']
    assert alarms and min(alarms) >= m.knock_t, (alarms, m.knock_t)    # no false alarm
    assert min(alarms) - m.knock_t < 0.5 * DAY
    # a swap follows the alarm (with alarm_cut 'shift' the re-estimate the alarm starts
    # keeps the moved older holds and may swap at the alarm's own stamp)
    first = next(i for i, d in enumerate(dec) if d['action'] == 'alarm')
    assert any(d['action'] == 'swap' for d in dec[first + 1:]), dec[first:]
    # recovered: the active calibration removes the knocked gyro bias on the last stops
    errs = []
    for seg in m.segments(1.8 * DAY):
        st = seg.still
        if st.sum() < 100:
            continue
        res = life.active.apply(seg.imu.accel[st], seg.imu.gyro[st], seg.temp_true[st][:, None])
        errs.append(np.linalg.norm(np.mean(res.gyro - seg.angular_rate[st], 0)))
    assert np.sqrt(np.mean(np.square(errs))) < 0.2 * np.linalg.norm(m.knock_gyro)
    # the registry's drift alarms (thermal-imu-calib history) see the knock too: the gyro
    # bias changed across it, and no change before it is flagged
    from thermal_imu_calib.fleet import registry
    rows = registry.read_index(reg_dir)
    found, info = registry.assess(rows)
    knock = registry.iso(int((m.start_ns * 1e-9 + m.knock_t) * 1e9))
    print(info['rule'], found)
    assert info['gyro_scale'] is not None, info['rule']
    steps = [a for a in found['imu_link'] if a.startswith('gyro db0') and 'changed' in a]
    assert steps, found
    by_time = {r['time']: Calibration.load(os.path.join(reg_dir, r['file'])) for r in rows}

    def gyro_fitted_before_knock(t):
        # a one-sensor (accelerometer) swap after the knock keeps the gyro of a calibration
        # activated before it (``fit.composed.gyro_from``)
        if t < knock:
            return True
        src = by_time[t].fit.get('composed', {}).get('gyro_from')
        return any(c.id == src and u < knock for u, c in by_time.items())
    for a in steps:
        before, after = a.split(' changed ')[1].split(':')[0].split(' -> ')
        assert gyro_fitted_before_knock(before) and knock <= after, (a, knock)


def test_reset_archives_the_store_and_keeps_the_active(tmp_path, month_windows):
    """~/reset's core: the holds move to archive/<UTC time>/ byte for byte, bounded."""
    from thermal_imu_calib.lifelong.manager import ArchiveFull, MAX_ARCHIVES
    _, win = month_windows
    ids = win.hold_ids
    d = tmp_path / 'life'
    logs = []

    def make():
        return Lifelong(str(d), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                        log=lambda level, text: logs.append(text))
    life = make()
    assert life.reset()['text'].startswith('collection restarted: nothing collected yet')
    assert not (d / 'archive').exists()                  # nothing to move: no archive
    life.add(win.select(np.isin(win.hold, ids[:30])))
    assert life.estimate('test')['action'] == 'swap'     # first estimate vs the raw output
    active = life.active.id
    total = life.store.total_holds
    before = {p.name: p.read_bytes() for p in (d / 'holds').iterdir()}
    assert before['recent.jsonl']
    dec = life.reset(when=1_800_000_000.0)
    dest = d / 'archive' / '20270115T080000Z'
    assert dec['archive'] == str(dest) and dec['action'] == 'reset'
    assert {p.name: p.read_bytes() for p in (dest / 'holds').iterdir()} == before
    assert f'moved the {total} holds' in dec['text'] and str(dest) in dec['text']
    assert f'active calibration {active} stays active' in dec['text']
    assert logs[-1] == 'lifelong reset: ' + dec['text']
    assert life.store.total_holds == 0 and not len(life.store.recent)
    assert life.active.id == active and (d / 'active.yaml').exists()
    assert life.decisions()[-1]['action'] == 'reset' and life.due() == ''
    # a restart finds the fresh collection and the same active calibration
    life = make()
    assert life.store.total_holds == 0 and life.active.id == active
    life.add(win.select(np.isin(win.hold, ids[30:32])))
    assert life.store.total_holds == 2
    # bounded: MAX_ARCHIVES archives; one more reset is refused and changes nothing
    for i in range(MAX_ARCHIVES - 1):
        life.reset(when=1_800_000_000.0 + i)
        life.add(win.select(win.hold == ids[33 + i]))
    names = sorted(p.name for p in (d / 'archive').iterdir())
    assert len(names) == MAX_ARCHIVES and names[0] == '20270115T080000Z'
    with pytest.raises(ArchiveFull, match='move or delete the ones no longer needed'):
        life.reset()
    assert life.store.total_holds == 1 and len(list((d / 'archive').iterdir())) == MAX_ARCHIVES


def test_archive_collection_of_a_directory_not_loaded(tmp_path, month_windows):
    """The node resets before its first hold: the earlier run's store and candidate move."""
    from thermal_imu_calib.lifelong.manager import archive_collection
    _, win = month_windows
    d = tmp_path / 'life'
    life = Lifelong(str(d), CalibrateSettings(), 1, [TOPIC], 'imu_link')
    life.add(win.select(np.isin(win.hold, win.hold_ids[:3])))
    (d / 'candidate.yaml').write_text('a candidate of the earlier run\n')
    recent = (d / 'holds' / 'recent.jsonl').read_bytes()
    dest = archive_collection(str(d), when=0.0)
    assert dest == str(d / 'archive' / '19700101T000000Z')
    assert (d / 'archive' / '19700101T000000Z' / 'holds' / 'recent.jsonl').read_bytes() == recent
    assert (d / 'archive' / '19700101T000000Z' / 'candidate.yaml').exists()
    assert not (d / 'holds').exists() and not (d / 'candidate.yaml').exists()
    assert Lifelong(str(d), CalibrateSettings(), 1, [TOPIC], 'imu_link').store.total_holds == 0
    assert archive_collection(str(d)) == ''          # an empty store: nothing to move


def _truth_active_on_20_holds(tmp_path, month_windows, later, latitude=None, **config):
    """Return (a loop whose store holds the month's first 20 holds and whose active is the
    true model, its ``gate.score`` on them, ``hold(i, gyro offset rad/s)``: the i-th of the
    next ``later`` holds with the offset added to its gyro). ``latitude`` (deg): the
    loop's and the score's, None: not known."""
    m, win = month_windows
    truth = m.true_calibration(0.5 * DAY)
    ids = win.hold_ids
    first, after = win.select(np.isin(win.hold, ids[:20])), ids[20:20 + later]
    life = Lifelong(str(tmp_path), CalibrateSettings(latitude=latitude), 1, [TOPIC],
                    'imu_link', config=LifelongConfig(**config))
    life.store.add(first)
    s = gate.score(truth, first, truth.gravity, latitude=latitude)
    life.active = truth
    life.state.update(active_gyro_rms=s['gyro_rms'], active_accel_rms=s['accel_rms'],
                      active_accel_median=float(np.median(s['errors']['accel'])),
                      holds_at_estimate=life.store.total_holds)

    def hold(i, gyro_offset):
        w = win.select(win.hold == after[i])
        return dataclasses.replace(w, gyro=w.gyro + gyro_offset)
    return life, s, hold


def test_holds_the_active_misses_make_a_re_estimate_due(tmp_path, month_windows):
    """Two new holds the active calibration misses, at any temperature, make an estimate due.

    The change alarm needs ``alarm_holds`` bad holds in a row inside the valid range; a
    calibration that fails only at the warm end of the day (seed 1 of the month bench) met
    that never. A re-estimate only makes a candidate for the swap gate, so two missed holds
    (each past the alarm's limit) are enough; one is not, and an estimate clears them.
    """
    life, s, hold = _truth_active_on_20_holds(tmp_path, month_windows, 3, new_holds=1000)
    truth = life.active
    assert life.due() == ''
    big = _knock_step(month_windows)        # 10x the alarm's factor times the truth's error
    life.add(hold(0, 0.0))                               # fitted well: not missed
    assert life.due() == '' and not life.state.get('missed')
    life.add(hold(1, big))                               # one miss: not yet
    assert life.due() == '' and len(life.state['missed']) == 1
    life.add(hold(2, big))
    why = life.due()
    assert why.startswith('the active calibration missed 2 new holds'), why
    assert not life.state['alarm_pending']               # no alarm: not 5 in a row
    # the miss is the change alarm's per-hold limit
    e = gate.hold_errors(truth, hold(2, big), truth.gravity)
    assert gate.misses(e, life.state['active_accel_median'], s['gyro_rms'], s['accel_rms'],
                       5.0, 5.0).all()
    life.estimate()
    assert life.state['missed'] == [] and 'missed' not in life.due()


@pytest.mark.parametrize('alarm_first', [True, False])
def test_the_alarm_answers_a_knock_before_the_misfit_trigger(
        tmp_path, month_windows, alarm_first):
    """Seed 52 of the month bench: 0.03 day after the knock two missed holds made a misfit
    re-estimate due; its swap re-measured the alarm's reference on the knocked holds and the
    alarm (5 in a row) never fired. With ``alarm_first`` no re-estimate is due while the
    newest holds all miss the limit and fewer than ``alarm_holds`` came in since the first:
    the fifth raises the alarm. A fitted hold ends the run, and the misfit trigger is due.
    """
    n = LifelongConfig().alarm_holds
    life, _, hold = _truth_active_on_20_holds(tmp_path, month_windows, 2 * n, new_holds=1000,
                                              alarm_first=alarm_first)
    big = _knock_step(month_windows)
    whys = []
    for i in range(n):
        life.add(hold(i, big))
        whys.append(life.due())
    assert life.state['alarms'] == 1 and whys[-1] == 'change alarm', whys
    if alarm_first:
        assert whys[:-1] == [''] * (n - 1), whys          # the alarm answers first
    else:
        assert whys[1].startswith('the active calibration missed 2 new holds'), whys
    # a run the alarm is deciding, broken by a hold the active fits: the misfit trigger
    life.state['alarm_pending'] = False
    life.track = []
    life.add(hold(n, big))
    life.add(hold(n + 1, big))
    assert (life.due() == '') == alarm_first
    assert alarm.pending_since(life.track, life.state, life.config) is not None
    life.add(hold(n + 2, 0.0))
    assert alarm.pending_since(life.track, life.state, life.config) is None
    assert life.due().startswith('the active calibration missed'), life.due()


def _gyro_knock_above_25_degc(tmp_path, month_windows, active, **config):
    """Return (the loop's alarm decisions, the loop) after a gyro knock on holds at 29-33
    degC, with ``active`` (its alarm reference measured on the first 20 holds, without the
    knock) and the ``LifelongConfig`` fields ``config``."""
    _, win = month_windows
    ids = win.hold_ids
    clean = win.select(np.isin(win.hold, ids[:20]))
    s = gate.score(active, clean, active.gravity)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(new_holds=1000, misfit_holds=1000, **config))
    life.store.add(clean)
    life.active = active
    life.state.update(active_gyro_rms=s['gyro_rms'], active_accel_rms=s['accel_rms'],
                      active_accel_median=float(np.median(s['errors']['accel'])),
                      holds_at_estimate=life.store.total_holds)
    step = np.array([0.0, 0.0, 10 * LifelongConfig().alarm_factor * s['gyro_rms']])
    for h in ids[20:20 + LifelongConfig().alarm_holds]:
        w = win.select(win.hold == h)
        assert 25.0 < w.temp.min()
        life.add(dataclasses.replace(w, gyro=w.gyro + step))
    return [d for d in life.decisions() if d['action'] == 'alarm'], life


@pytest.mark.parametrize('window', ['common', 'sensor'])
def test_the_change_alarm_watches_each_sensor_in_its_own_range(tmp_path, month_windows,
                                                               window):
    """After one-sensor swaps the sensors' valid ranges differ; a gyro knock at temperatures
    only the gyro's model covers is seen with ``alarm_window='sensor'``, not with 'common'.

    Seed 2 of the month bench: the common range narrowed and the knock alarm came 20.6 h
    late (3.4 h with whole swaps).
    """
    truth = month_windows[0].true_calibration(0.5 * DAY)
    # the accelerometer's model covers -20..25 degC only; these holds are at 29-33 degC
    active = dataclasses.replace(truth, sensor_range={'accel': np.array([[-20.0, 25.0]])})
    alarms, life = _gyro_knock_above_25_degc(tmp_path, month_windows, active,
                                             alarm_window=window)
    if window == 'sensor':
        assert len(alarms) == 1 and life.state['alarm_pending'], alarms
        assert alarms[0]['reason'].startswith('the active calibration no longer fits: gyro')
        assert 'accel' not in alarms[0]['figures']      # its holds are outside its range
        assert life.state['alarms'] == 1
    else:                           # outside the common range: not watched
        assert alarms == [] and not life.state['alarm_pending']


@pytest.mark.parametrize('sensors', ['every', 'thermal'])
def test_a_model_without_temperature_terms_does_not_narrow_the_alarm_window(
        tmp_path, month_windows, sensors):
    """An accelerometer model of degree 0 kept from a few cold holds (its own range
    -20..25 degC) narrows the common range with ``range_sensors='every'``, so a gyro knock
    at 29-33 degC is not watched; with 'thermal' the window is the valid range and the
    alarm fires (seeds 59 and 61 of the month bench lost their knock alarm so)."""
    truth = month_windows[0].true_calibration(0.5 * DAY)
    a = truth.accel
    thermal = a.thermal.copy()
    thermal[:, [1, 2, 4, 5]] = 0.0                  # no scale or bias terms in dT
    flat = type(a)(a.t0, thermal, a.k0, a.b0, a.s)
    assert flat.temperature_degree() == 0 and not compose.depends_on_temperature(flat)
    assert compose.depends_on_temperature(truth.gyro)
    active = dataclasses.replace(truth, accel=flat,
                                 sensor_range={'accel': np.array([[-20.0, 25.0]])})
    lo, hi = active.valid_range[0]
    want = [[lo, hi]] if sensors == 'thermal' else [[max(lo, -20.0), min(hi, 25.0)]]
    np.testing.assert_allclose(compose.common_range(active, sensors), want)
    alarms, life = _gyro_knock_above_25_degc(tmp_path, month_windows, active,
                                             range_sensors=sensors)
    if sensors == 'thermal':
        assert len(alarms) == 1 and life.state['alarm_pending'], alarms
        assert alarms[0]['reason'].startswith('the active calibration no longer fits: gyro')
    else:                           # outside the accelerometer's own range: not watched
        assert alarms == [] and not life.state['alarm_pending']
    with pytest.raises(ValueError, match="range_sensors 'sensor' is not one of every"):
        LifelongConfig(range_sensors='sensor')


def _knock_step(month_windows):
    """Return the gyro step (rad/s) of a knock: 10x the alarm factor times the true model's
    gyro error on the first 20 holds."""
    m, win = month_windows
    truth = m.true_calibration(0.5 * DAY)
    clean = win.select(np.isin(win.hold, win.hold_ids[:20]))
    s = gate.score(truth, clean, truth.gravity)
    return np.array([0.0, 0.0, 10 * LifelongConfig().alarm_factor * s['gyro_rms']])


def _clean_and_knocked(month_windows):
    """Return the first 20 holds and the next 14 with a knock's gyro step."""
    _, win = month_windows
    ids = win.hold_ids
    clean = win.select(np.isin(win.hold, ids[:20]))
    knocked = win.select(np.isin(win.hold, ids[20:34]))
    return clean, dataclasses.replace(knocked, gyro=knocked.gyro + _knock_step(month_windows))


@pytest.mark.parametrize('after_alarm', [True, False])
def test_one_sensor_swap_after_a_change_alarm(tmp_path, month_windows, after_alarm):
    """After a knock's alarm the store holds only the holds after the cut; an estimate on
    them fixes the gyro, while its accelerometer has a few holds of a narrow temperature
    range. With ``one_sensor_after_alarm`` the gyro alone is swapped in when the gate calls
    the accelerometer no better; without it the whole estimate is judged (the default)."""
    clean, knocked = _clean_and_knocked(month_windows)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(new_holds=1000, ageing=False,
                                          one_sensor_after_alarm=after_alarm,
                                          alarm_reference='explained'))
    active = life._calibrate(main_pose(clean, 2.0)).calibration   # before the knock
    life.store.add(knocked)                                         # the store after the cut
    life.active = active
    sa = gate.score(active, clean, active.gravity)
    life.state.update(active_gyro_rms=sa['gyro_rms'], active_accel_rms=sa['accel_rms'],
                      active_accel_median=float(np.median(sa['errors']['accel'])),
                      alarm_pending=True, holds_at_estimate=life.store.total_holds)
    d = life.estimate('change alarm')
    assert d['action'] == 'swap', d['text']
    verdicts = d['figures']['gyro']['verdict'], d['figures']['accel']['verdict']
    if after_alarm:
        assert d['one_sensor']['sensor'] == 'gyro' and d['one_sensor']['used'], d['text']
        assert life.active.accel is active.accel        # the accelerometer model is kept
        assert life.active.gyro is not active.gyro
    else:
        assert 'one_sensor' not in d, d['text']         # the whole estimate was judged
        assert life.active.accel is not active.accel
    assert verdicts[0] == 'better'
    assert not life.state['alarm_pending']
    assert 'alarm reference without' not in d['text']     # the old reference is not used


def _estimate_across_a_knock(tmp_path, month_windows, **config):
    """Return (life, active, its score on the clean holds, the decision) of an estimate on
    20 clean and 14 knocked holds (8 of them held out), the active fitted on the clean ones."""
    clean, knocked = _clean_and_knocked(month_windows)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(**config))
    life.store.add(clean)
    life.store.add(knocked)
    life.state['holds_at_estimate'] = life.store.total_holds
    active = life._calibrate(main_pose(clean, 2.0)).calibration   # before the knock
    life.active = active
    s = gate.score(active, clean, active.gravity)
    life.state.update(active_gyro_rms=s['gyro_rms'], active_accel_rms=s['accel_rms'],
                      active_accel_median=float(np.median(s['errors']['accel'])))
    return life, active, s, life.estimate('test')


@pytest.mark.parametrize('must_explain', [True, False])
def test_no_swap_to_a_calibration_that_misses_the_newest_holds_too(tmp_path, month_windows,
                                                                   must_explain):
    """Held-out holds both calibrations miss say the sensor changed: keep, let the alarm see.

    Seed 2 of the month bench: after the knock, estimates the gate called "better" (107 ->
    106 mdeg/s on holds the active had fitted to 2) were swapped in; each swap re-measured
    the change alarm's reference on the knocked holds, and the alarm came 21 h late. Here
    the newest 14 holds carry a gyro step (a knock): 6 are in the new fit, which follows
    them part of the way, so the new calibration is better on the 8 held-out ones than the
    active (fitted on the holds before the knock), and still misses them.
    """
    life, active, s, d = _estimate_across_a_knock(
        tmp_path, month_windows, new_holds=1000, ageing=False, swap_must_explain=must_explain)
    assert d['figures']['gyro']['verdict'] == 'better', d['text']
    if must_explain:
        assert d['action'] == 'keep', d['text']
        assert 'also misses 8 of the 8 held-out holds' in d['text'], d['text']
        assert life.active is active and life.state['active_gyro_rms'] == s['gyro_rms']
    else:                                                # the rule off: the old behaviour
        assert d['action'] == 'swap', d['text']
        assert life.state['active_gyro_rms'] > 5 * s['gyro_rms']    # the alarm is blind


@pytest.mark.parametrize('bad, words', [
    ({'alarm_window': 'sensors'}, ("alarm_window 'sensors'", 'common, sensor')),
    ({'holdout_holds': 1}, ('holdout_holds is 1', 'at least 2')),
    ({'alarm_holds': 2.5}, ('alarm_holds is 2.5', 'whole number')),
    ({'new_holds': True}, ('new_holds is True', 'whole number')),
    ({'alarm_factor': 0.0}, ('alarm_factor is 0.0', 'above 0')),
    ({'range_extension_degc': float('nan')}, ('range_extension_degc is nan', 'finite')),
])
def test_a_setting_the_loop_cannot_run_with_is_refused_by_name(bad, words):
    """A mistyped ``LifelongConfig`` is refused at once, naming the field and what to give
    (a misspelt ``alarm_window`` used to fall through to 'common' silently)."""
    with pytest.raises(ValueError) as caught:
        LifelongConfig(**bad)
    for w in words:
        assert w in str(caught.value)
    assert LifelongConfig(alarm_window='sensor').alarm_window == 'sensor'


@pytest.mark.parametrize('reference', ['explained', 'all'])
def test_a_swap_across_a_knock_keeps_the_alarm_seeing_it(tmp_path, month_windows, reference):
    """Seeds 19 and 2 of the month bench: a swap across a knock (the gate calls the new
    calibration better on the knocked held-out holds, which it still misses) re-measured the
    alarm's reference on those holds, and the alarm went blind. With
    ``alarm_reference='explained'`` the swap happens, the reference is measured on the
    holds the new calibration explains, and the next knocked holds raise the alarm."""
    life, active, s, d = _estimate_across_a_knock(
        tmp_path, month_windows, new_holds=1000, misfit_holds=1000, ageing=False,
        alarm_reference=reference)
    assert d['action'] == 'swap' and d['figures']['gyro']['verdict'] == 'better', d['text']
    _, win = month_windows
    later = win.select(np.isin(win.hold,
                               win.hold_ids[34:34 + LifelongConfig().alarm_holds + 3]))
    life.add(dataclasses.replace(later, gyro=later.gyro + _knock_step(month_windows)))
    if reference == 'explained':
        assert 'alarm reference without the holds it misses' in d['text'], d['text']
        left_out = int(re.search(r'gyro (\d+) of \d+\)', d['text']).group(1))
        assert left_out >= 8, d['text']                 # at least the 8 held-out knocked
        assert life.state['active_gyro_rms'] < 5 * s['gyro_rms']
        assert life.state['alarms'] == 1, life.decisions()[-1]['text']
    else:                                                # the default: blind
        assert life.state['active_gyro_rms'] > 5 * s['gyro_rms']
        assert life.state['alarms'] == 0


def test_a_one_sensor_cut_keeps_the_other_sensors_history(tmp_path, month_windows):
    """``cut(t, keep='accel')``: the holds before ``t`` leave this epoch (every fit of the
    gyro) but stay, compacted, in the accelerometer's fits, across a restart; a later cut
    that keeps the gyro drops them; at most ``MAX_KEPT`` histories are kept."""
    from thermal_imu_calib.lifelong.store import MAX_KEPT
    _, win = month_windows
    ids = win.hold_ids
    st = HoldStore(str(tmp_path / 's'), 1)
    st.add(win.select(np.isin(win.hold, ids[:20])))
    now = float(win.t1.max())
    t_cut = float(win.t0[win.hold == ids[14]].min())
    st.cut(t_cut, keep='accel')
    assert st.has_kept('accel') and not st.has_kept('gyro')
    epoch = st.windows(now)
    assert len(epoch.hold_ids) == 6 and (epoch.t0 >= t_cut).all()     # raw holds 14-19
    for again in (st, HoldStore(str(tmp_path / 's'), 1)):            # and after a restart
        acc, times = again.fit_windows(now, sensor='accel')
        assert len(acc) > len(epoch) and len(times) == len(acc)
        assert times.min() < t_cut                          # the older holds, compacted
        # every sample of the 20 holds (no fading within 1.5 days: > 90 %)
        assert acc.n.sum() > 0.9 * win.n[np.isin(win.hold, ids[:20])].sum()
        assert len(again.fit_windows(now, sensor='gyro')[0]) == len(epoch)
    assert st.summary()['kept_bins'] > 0
    # a cut of the accelerometer's history (the gyro keeps): the accel's kept one goes
    st.add(win.select(np.isin(win.hold, ids[20:28])))
    st.cut(float(win.t0[win.hold == ids[24]].min()), keep='gyro')
    assert st.has_kept('gyro') and not st.has_kept('accel')
    for k in range(MAX_KEPT + 2):                       # bounded
        st.add(win.select(np.isin(win.hold, ids[28 + 2 * k:30 + 2 * k])))
        st.cut(float(win.t0[win.hold == ids[29 + 2 * k]].min()), keep='gyro')
    assert len(st.kept) == MAX_KEPT
    st.cut(float(win.t1.max()))                         # both sensors: nothing kept
    assert st.kept == [] and not st.has_kept('gyro')


def _active_before_the_knock(life, clean):
    """Make the calibration of ``clean``'s mounting pose active in ``life``, with the change
    alarm's reference measured on ``clean``; return (it, ``gate.score`` on ``clean``)."""
    active = life._calibrate(main_pose(clean, 2.0)).calibration
    life.active = active
    s = gate.score(active, clean, active.gravity)
    life.state.update(active_gyro_rms=s['gyro_rms'], active_accel_rms=s['accel_rms'],
                      active_accel_median=float(np.median(s['errors']['accel'])),
                      holds_at_estimate=life.store.total_holds)
    return active, s


@pytest.mark.parametrize('cut', ['sensor', 'all'])
def test_a_gyro_alarm_cuts_the_gyro_history_only(tmp_path, month_windows, cut):
    """A knock that moves the gyro only: with ``alarm_cut='sensor'`` the alarm drops the
    older holds for the gyro alone, and the estimate after it fits the accelerometer on
    them too (its model covers their temperatures), the gyro on the holds after the cut.
    With 'all' (the default until 2026-12-04) both sensors start again from the holds
    after the cut."""
    clean, knocked = _clean_and_knocked(month_windows)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(new_holds=1000, misfit_holds=1000, ageing=False,
                                          alarm_cut=cut))
    life.store.add(clean)
    active, s = _active_before_the_knock(life, clean)
    for h in knocked.hold_ids:
        life.add(knocked.select(knocked.hold == h))
    alarms = [d for d in life.decisions() if d['action'] == 'alarm']
    assert len(alarms) == 1 and list(alarms[0]['figures']) == ['gyro'], alarms
    assert life.store.has_kept('accel') == (cut == 'sensor')
    assert ('(the accel keeps them)' in alarms[0]['reason']) == (cut == 'sensor')
    # the epoch starts at the first knocked hold: no hold from before the knock is left in
    # it (a relative stamp tolerance once kept ~4.8 h of them)
    assert (life.store.recent.t0 >= knocked.t0.min()).all()
    assert life.status()['alarm'] == 're-estimating from the holds after it'
    d = life.estimate('change alarm')
    assert d['action'] == 'swap' and d['figures']['gyro']['verdict'] == 'better', d['text']
    lo = life.active.own_range('accel')[0, 0]
    after_cut = life.store.windows().temp[:, 0].min()
    if cut == 'sensor':
        assert d['kept_history']['used'] and 'history kept' in d['text'], d['text']
        composed = life.active.fit['composed']
        assert composed['accel_from'] != composed['gyro_from']
        # the accelerometer's model spans the older holds' temperatures
        assert lo <= clean.temp[:, 0].min() + 0.5 < after_cut, (lo, after_cut)
        assert life.active.own_range('gyro')[0, 0] >= after_cut - 0.5
    else:
        assert 'kept_history' not in d
        assert lo >= after_cut - 0.5


def test_a_shift_alarm_keeps_the_older_holds_moved_by_the_knocks_step(
        tmp_path, month_windows):
    """``alarm_cut='shift'``: a knock that steps both sensors' offsets; the alarm measures
    the step on the holds after it against the active calibration, moves the older holds
    (raw and compacted, persisted) by it instead of dropping them, and the estimate after
    it spans the older holds' temperatures for both sensors."""
    clean, knocked = _clean_and_knocked(month_windows)
    g_step = _knock_step(month_windows)
    a_step = np.array([0.04, -0.03, 0.05])                 # m/s^2 (sim: 0.03-0.08)
    knocked = dataclasses.replace(knocked, accel=knocked.accel + a_step)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    config=LifelongConfig(new_holds=1000, misfit_holds=1000, ageing=False,
                                          alarm_cut='shift'))
    life.store.add(clean)
    life.store.compact(clean.hold_ids[:8])                  # some of them compacted
    active, s = _active_before_the_knock(life, clean)
    before = life.store.fit_windows()[0]
    # the first two knocked holds come in unscored (as holds outside the alarm's range
    # would): the alarm flags the next ones, and the change is found where it began
    ids = knocked.hold_ids
    life.store.add(knocked.select(np.isin(knocked.hold, ids[:2])))
    for h in ids[2:]:
        life.add(knocked.select(knocked.hold == h))
    alarms = [d for d in life.decisions() if d['action'] == 'alarm']
    assert len(alarms) == 1 and 'shifted by the step' in alarms[0]['reason'], alarms
    step = alarms[0]['step']
    assert step['t'] == knocked.t0.min() and step['earlier_holds'] == 2, step
    assert 'it began 2 holds before the first of them' in alarms[0]['reason'], alarms
    assert step['holds_after'] >= LifelongConfig().alarm_holds + 2
    assert step['holds_before'] == 10 and step['dropped_holds'] == 0
    np.testing.assert_allclose(step['gyro_rad_s'], g_step, atol=0.1 * np.abs(g_step).max())
    np.testing.assert_allclose(step['accel_m_s2'], a_step, atol=0.01)
    # nothing dropped: the older holds are there, moved by the measured step, after a
    # restart too (raw and compacted)
    for store in (life.store, HoldStore(str(tmp_path / 'holds'), 1)):
        old = store.fit_windows()[0]
        old = old.select(old.t1 <= clean.t1.max())
        assert len(old) == len(before)
        np.testing.assert_allclose(old.gyro - before.gyro, np.broadcast_to(
            step['gyro_rad_s'], old.gyro.shape), atol=1e-12)
        np.testing.assert_allclose(old.accel - before.accel, np.broadcast_to(
            step['accel_m_s2'], old.accel.shape), atol=1e-12)
        early = store.recent.select(store.recent.t0 < knocked.t0[knocked.hold == ids[2]].min())
        early = early.select(early.t0 >= knocked.t0.min())      # after the change: as they are
        np.testing.assert_array_equal(early.gyro, knocked.gyro[np.isin(knocked.hold, ids[:2])])
    assert life.due() == 'change alarm'
    assert life.status()['alarm'].startswith('re-estimating from every hold, the older')
    d = life.estimate('change alarm')
    assert d['action'] == 'swap' and d['figures']['gyro']['verdict'] == 'better', d['text']
    assert 'alarm' not in life.status()
    for which in ('accel', 'gyro'):         # both models span the pre-knock temperatures
        assert life.active.own_range(which)[0, 0] <= \
            main_pose(clean, 2.0).temp[:, 0].min() + 0.5
    # the new calibration explains the knocked holds to within the alarm's limit
    e = gate.hold_errors(life.active, knocked, life.active.gravity)
    assert np.median(e['gyro']) < life.config.alarm_factor * s['gyro_rms'], e['gyro']
    # holds in several poses: no step is measured (the mean vectors differ by the pose)
    turned = dataclasses.replace(knocked, accel=knocked.accel[:, [2, 0, 1]],
                                 gyro=knocked.gyro[:, [2, 0, 1]])
    both = Windows.concat([clean, turned])
    ranges = alarm.alarm_ranges(active, 1, 'common')
    assert knock_step.step(active, both, turned.t0.min(), active.gravity, None, 2.0,
                           ranges) is None


def test_hold_starts_are_each_holds_first_window_start(month_windows):
    """``Windows.hold_starts`` / ``hold_spans``: ids in order of appearance (any order of
    hold ids), each hold's earliest window start and latest window end, as the loops over
    holds the lifelong, selection and noise code had."""
    _, win = month_windows
    mixed = win.select(np.random.default_rng(2).permutation(len(win)))
    ids, starts = mixed.hold_starts()
    np.testing.assert_array_equal(ids, mixed.hold_ids)
    np.testing.assert_array_equal(starts, [mixed.t0[mixed.hold == h].min() for h in ids])
    ids2, starts2, ends = mixed.hold_spans()
    np.testing.assert_array_equal(ids2, ids)
    np.testing.assert_array_equal(starts2, starts)
    np.testing.assert_array_equal(ends, [mixed.t1[mixed.hold == h].max() for h in ids])


def test_a_change_starts_where_one_step_explains_both_sensors_best():
    """``knock_step.change_start``: the split of one mean step, found at or before the
    first flagged hold, whatever the scale of each sensor (each its own variance)."""
    rng = np.random.default_rng(5)
    gyro = rng.normal(0, 1e-4, (30, 3))
    accel = rng.normal(0, 3e-2, (30, 3))          # tilt scatter: 300x the gyro's
    gyro[12:] += [2e-3, 0, 1e-3]
    accel[12:] += [0.05, 0.0, -0.04]
    assert knock_step.change_start({'gyro': gyro, 'accel': accel}, 17) == 12
    assert knock_step.change_start({'gyro': gyro, 'accel': accel}, 9) == 9     # at most
    assert knock_step.change_start({'gyro': gyro}, 2) == 2                      # no room


def test_a_swap_refits_on_every_hold_and_the_next_gate_waits_for_unseen_holds(
        tmp_path, month_windows):
    """``refit_on_swap``: the judged estimate passes, the one fitted on every hold goes in use.

    The swap gate judges an estimate fitted without the newest holds; what is put in use is
    the same procedure run on all of them (the newest temperatures covered), and the next
    estimate waits until ``min_holds + holdout_holds`` holds began after that fit, so the
    gate never scores the active calibration on holds it was fitted on.
    """
    m, win = month_windows
    ids = win.hold_ids
    cfg = LifelongConfig(refit_on_swap=True, new_holds=1000)
    life = Lifelong(str(tmp_path), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                    registry_dir=str(tmp_path / 'reg'), config=cfg)
    life.store.add(win.select(np.isin(win.hold, ids[:20])))
    d = life.estimate('test')
    assert d['action'] == 'swap', d['text']
    r = d['refit']
    assert r['used'] and r['judged_id'] != life.active.id == d['id'], r
    # in use: the calibrate code on every hold of the mounting pose, the held-out ones too
    everything = life.store.fit_windows(d['time'])[0]
    fit = everything.select(main_pose_mask(everything, cfg.pose_deg))
    n = len(fit.hold_ids)
    assert 14 < n <= 20 and r['holds'] == n and f'fitted again on all {n} holds' in d['text']
    if 'ageing' not in d or not d['ageing']['used']:
        assert life._calibrate(fit).calibration.id == life.active.id
    held = life.store.holds(life.store.newest_holds(cfg.holdout_holds))
    held = held.select(main_pose_mask(held, cfg.pose_deg))
    lo, hi = life.active.valid_range[0]
    assert lo <= held.temp[:, 0].min() and held.temp[:, 0].max() <= hi
    assert registry.load_valid(str(tmp_path / 'reg'), 'imu_link').id == life.active.id
    # the next estimate waits for 6 + 8 holds newer than the fit, whatever else is due
    life.state['alarm_pending'] = True
    for i, h in enumerate(ids[20:34]):
        assert life.due() == '', i
        life.store.add(win.select(win.hold == h))
    assert life.due() == 'change alarm'
    # off (the default): the judged estimate is what goes in use
    plain = Lifelong(str(tmp_path / 'plain'), CalibrateSettings(), 1, [TOPIC], 'imu_link',
                     config=LifelongConfig(new_holds=1000))
    plain.store.add(win.select(np.isin(win.hold, ids[:20])))
    p = plain.estimate('test')
    assert p['action'] == 'swap' and 'refit' not in p and p['id'] == r['judged_id']


def test_slopes_either_way_are_one_orientation_family(month_windows):
    """Stops on slopes tilted opposite ways stay one family: the fit keeps the mounting pose.

    Two slopes of 11 deg either way are 22 deg apart; counted hold to hold (greedy, above
    ``distinct_orientations``' 20 deg) they were two orientations: the pose filter let the
    slopes into the one-orientation fit and every estimate was refused for missing faces
    (the simulated month of seed 22, from day 17 on), and ``calibrate`` of such a robot
    log was refused the same way. Measured from the mounting pose they are one family; a
    hold on another face is not.
    """
    from thermal_imu_calib.collection.segments import distinct_orientations
    from thermal_imu_calib.lifelong.pose import one_family

    _, win = month_windows
    ids = win.hold_ids

    def tilted(h, deg):
        a = np.radians(deg)
        r = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        w = win.select(win.hold == h)
        return dataclasses.replace(w, accel=w.accel @ r.T)
    level = win.select(np.isin(win.hold, ids[2:12]))
    level = level.select(main_pose_mask(level, 2.0))
    n_level = len(level.hold_ids)
    slopes = Windows.concat([tilted(ids[0], 11.0), tilted(ids[1], -11.0), level])
    assert distinct_orientations(slopes) == 1 and one_family(slopes)
    kept = slopes.select(main_pose_mask(slopes, 2.0))
    assert set(kept.hold_ids) == set(level.hold_ids) and len(kept.hold_ids) == n_level
    # a hold on its side is another orientation: nothing is left out
    side = Windows.concat([slopes, tilted(ids[13], 90.0)])
    assert not one_family(side) and main_pose_mask(side, 2.0).all()
    assert distinct_orientations(side) > 1
    # the command line's calibrate: a one-orientation calibration, not a refusal
    from thermal_imu_calib.app.calibrate import calibrate_collected
    from thermal_imu_calib.collection.collected import Collected
    cal = calibrate_collected(CalibrateSettings(), [Collected(
        slopes, 'imu_link', 0, 0.0, [TOPIC], [])]).calibration
    assert cal.fit['distinct_orientations'] == 1 and cal.gyro is not None


def test_calibrate_of_a_robot_log_with_slopes_either_way_is_not_refused(tmp_path, capsys):
    """The command line on 3 days of a simulated robot whose slopes go both ways (seed 7).

    Its holds counted two orientations hold to hold (slopes up to 24 deg apart), and
    ``calibrate`` refused the log for missing faces; it is one orientation family (every
    hold within 20 deg of the mounting pose) and gets the one-orientation calibration.
    """
    from thermal_imu_calib import cli
    from thermal_imu_calib.sim.robot_month import write_robot_month
    write_robot_month(tmp_path / 'rm.mcap', 7, days=3)
    out = tmp_path / 'c.yaml'
    rc = cli.main(['calibrate', str(tmp_path / 'rm.mcap'), '--imu-topic', '/imu/data_raw',
                   '--gravity', '9.80665', '-o', str(out)])
    text = capsys.readouterr()
    assert rc == 0, text.err
    assert 'accelerometer: one orientation only (+z)' in text.out
    cal = Calibration.load(out)
    assert cal.fit['distinct_orientations'] == 1 and cal.gyro is not None
    # level visits of one pose disagree (tilt, drift), and with one orientation there is no
    # standard fit to judge leaving them out: said so, not "inf ug ... paired z nan"
    judged = cal.fit['hold_consistency']['heldout']
    assert judged['heldout_holds'] == 0 and not judged['applied']
    assert 'no hold can be held out' in text.out
    assert 'nan' not in text.out and 'inf ug' not in text.out
    # the one-orientation fit uses the mounting pose's holds, as lifelong mode does: the
    # stops on slopes (3-12 deg) are named and not fitted
    from thermal_imu_calib.collection.segments import MOUNTING_POSE_DEG
    found = int(re.search(r'(\d+) stationary holds', text.out + text.err).group(1))
    assert cal.fit['holds'] < found
    assert (f'{found - cal.fit["holds"]} of {found} holds are more than '
            f'{MOUNTING_POSE_DEG:g} deg from the mounting pose') in text.out
