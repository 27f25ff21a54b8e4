"""Thermal inputs whose header stamps are not on the IMU's clock (``io.headerless.StampChoice``).

A driver that leaves ``header.stamp`` 0, or stamps its readings by another clock than the
IMU's (device time against ROS time), used to be refused ("header stamp 0", "different
clocks?"). Such an input is now put on the IMU's clock like a header-less one: each reading
takes the stamp of the IMU message logged before it. So such a log must read, through both
readers and at any chunk size, exactly as the same log with those stamps written in; and a
log on one clock must read as it did, the readings before the first IMU message included.
"""

import numpy as np
import pytest

from _hostile import recording, TEMP_TOPIC, write_bag
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.columns import TemperatureColumns
from thermal_imu_calib.io.headerless import (clock_notes, LiveClocks, OTHER_CLOCK_S,
                                             StampChoice)

S = 10 ** 9


@pytest.fixture(scope='module')
def rec():
    return recording()


def test_the_choice_is_made_by_the_distance_to_the_imu_stamps():
    def choice(stamp, first, last):
        return StampChoice('/t').decide(stamp, first, last)
    assert choice(0, 100 * S, 101 * S)                                  # never set
    assert not choice(100 * S, 100 * S, 100 * S)
    assert not choice(95 * S, 100 * S, 200 * S)               # within OTHER_CLOCK_S
    assert not choice(150 * S, 100 * S, 200 * S)              # inside the IMU stamps
    assert choice(int(94.9 * S), 100 * S, 200 * S)
    assert choice(int(205.1 * S), 100 * S, 200 * S)
    assert OTHER_CLOCK_S == 5.0
    c = StampChoice('/t')
    c.decide(10 ** 12 + 100 * S, 100 * S, 100 * S)
    assert 'is stamped +1000 s from the IMU messages before it' in c.pop_note()
    assert c.pop_note() == ''                                  # said once


def test_readings_wait_for_the_first_imu_message_and_the_end_releases_them():
    c = StampChoice('/t')
    got = c.place([5 * S, 6 * S], [20.0, 21.0], [0, 0], np.zeros(0, np.int64), None)
    assert len(got) == 0 and c.holding and c.on_imu_clock is None
    got = c.place([7 * S], [22.0], [1], np.array([int(6.5 * S)]), None)   # one clock
    assert c.on_imu_clock is False and not c.holding
    assert got.stamp_ns.tolist() == [5 * S, 6 * S, 7 * S]
    c = StampChoice('/t')
    c.place([0, 0], [20.0, 21.0], [0, 0], np.zeros(0, np.int64), None)
    got = c.place([0, 0], [22.0, 23.0], [1, 2], np.array([100, 200]), None)
    assert c.on_imu_clock is True and c.left_out == 2
    assert got.stamp_ns.tolist() == [100, 200] and got.temperature.tolist() == [22.0, 23.0]
    c = StampChoice('/t')                                  # no IMU message after them
    c.place([5 * S], [20.0], [0], np.zeros(0, np.int64), None)
    got = c.place([], [], [], np.zeros(0, np.int64), None, final=True)
    assert got.stamp_ns.tolist() == [5 * S] and c.on_imu_clock is None


def _on_imu_clock(a):
    """The reference: each reading stamped with the IMU stamp logged before it (the log
    times are the original stamps, the IMU first at a tie); none before: dropped."""
    st = a['stamp_ns']
    before = np.searchsorted(st, a['temp_stamp_ns'], side='right')
    keep = before > 0
    a['temp_stamp_ns'] = st[before[keep] - 1]
    a['temperature'] = a['temperature'][keep]


EDITS = {'stamps_0': lambda a: a['temp_stamp_ns'].__setitem__(slice(None), 0),
         'another_clock': lambda a: a['temp_stamp_ns'].__setitem__(
             slice(None), a['temp_stamp_ns'] - 3600 * S)}


def _stream(path, chunk_size):
    with open_log(path) as r:
        chunks = list(r.stream('/imu/data_raw', [TEMP_TOPIC], chunk_size=chunk_size))
    notes = [n for c in chunks for n in c.notes]
    return (np.concatenate([c.temps[TEMP_TOPIC].stamp_ns for c in chunks]),
            np.concatenate([c.temps[TEMP_TOPIC].temperature for c in chunks]), notes)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('case', sorted(EDITS))
def test_a_log_on_another_clock_reads_as_the_log_stamped_by_the_imu(rec, tmp_path, storage,
                                                                    case):
    imu, temp = rec
    n_before = 3                  # readings logged before the first IMU message
    stamps = temp.stamp_ns.copy()
    stamps[:n_before] = imu.stamp_ns[0] - np.arange(n_before, 0, -1) * S // 10
    temp = TemperatureColumns(stamps, temp.temperature.copy())
    ref = write_bag(str(tmp_path / 'ref.mcap'), imu, temp, _on_imu_clock)
    want, want_t, notes = _stream(ref, 20000)
    assert len(want) == len(temp.stamp_ns) - n_before and not notes
    log = write_bag(str(tmp_path / f'{case}_{storage}'), imu, temp, EDITS[case], storage)
    for size in (20000, 7, 1):
        got, got_t, notes = _stream(log, size)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(got_t, want_t)
        assert len(notes) == 1 and "not stamped by the IMU's clock" in notes[0]
        assert ('header stamp 0' in notes[0]) == (case == 'stamps_0')
    with open_log(log) as r:         # info: the rate over log times, and why
        info = r.info()
        line = next(ln for ln in info.format().splitlines() if TEMP_TOPIC in ln)
        notes = clock_notes(info, '/imu/data_raw', [TEMP_TOPIC])
    assert ' 9.97 Hz' in line or '10.00 Hz' in line, line   # 10 Hz, 3 readings moved early
    assert ('header stamps all 0 (rate over log times' in line) == (case == 'stamps_0'), line
    assert len(notes) == 1 and ('every header stamp is 0' in notes[0] if case == 'stamps_0'
                                else 'header stamps run -3600 s from the IMU' in notes[0])


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_log_on_one_clock_reads_as_before(rec, tmp_path, storage):
    imu, temp = rec
    stamps = temp.stamp_ns.copy()    # the first reading 10 s before the first IMU message,
    stamps[0] = imu.stamp_ns[0] - 10 * S     # logged then: a driver started before the IMU's
    temp = TemperatureColumns(stamps, temp.temperature.copy())
    log = write_bag(str(tmp_path / f'one_{storage}'), imu, temp, None, storage)
    for size in (20000, 7, 1):
        got, got_t, notes = _stream(log, size)
        np.testing.assert_array_equal(got, stamps)   # the early one included
        np.testing.assert_array_equal(got_t, temp.temperature)
        assert not notes
    with open_log(log) as r:
        assert clock_notes(r.info(), '/imu/data_raw', [TEMP_TOPIC]) == []


def test_live_clocks_hold_until_an_imu_message_then_follow_the_choice():
    """The nodes' helper: (header stamp, source timestamp, value) readings, as they come."""
    def stamp_of(r):
        return r[0]
    c = LiveClocks(['/a', '/b', '/c'], [False, False, True])
    assert c.on and c.bare == [False, False, True]
    assert c.choose(0, [(0, 5, 20.0)], stamp_of) == ([], '')        # no IMU message yet
    assert c.choose(1, [(90 * S, 6, 21.0)], stamp_of) == ([], '')
    c.add_imu([10, 20], [100 * S, 101 * S])
    out, note = c.choose(0, [(0, 15, 22.0), (0, 25, 23.0)], stamp_of)   # stamp 0: IMU clock
    assert c.bare[0] and 'header stamp 0' in note and len(out) == 3
    got = c.stamp(0, [(s_, v) for _, s_, v in out])      # the one before any IMU: left out
    assert got.stamp_ns.tolist() == [100 * S] and got.temperature.tolist() == [22.0]
    assert c.clock.left_out == 1                          # the last waits for the next IMU
    c.add_imu([30], [102 * S])
    assert c.stamp(0, []).stamp_ns.tolist() == [101 * S]
    out, note = c.choose(1, [], stamp_of)                 # 10 s before the first: on its own
    assert c.bare[1] and 'is stamped -10 s' in note
    c = LiveClocks(['/a'], [False])
    c.add_imu([10], [100 * S])
    out, note = c.choose(0, [(99 * S, 11, 20.0)], stamp_of)
    assert out == [(99 * S, 11, 20.0)] and note == '' and not c.bare[0] and not c.on
    c.add_imu([12], [101 * S])                           # nothing kept once all are decided
    assert c.span == (100 * S, 100 * S) and c.clock._n == 1
    c = LiveClocks(['/a'], [False])          # a driver started 10 s before the IMU's
    c.choose(0, [(90 * S, 1, 20.0), (99 * S, 2, 20.1)], stamp_of)
    c.add_imu([3], [100 * S])
    out, note = c.choose(0, [], stamp_of)     # judged at the newest held reading
    assert len(out) == 2 and note == '' and not c.bare[0]


def test_live_clocks_retype_an_input_as_the_type_its_topic_is_published_as():
    """``nodes/thermal_types``: a node re-subscribes an input as another type; its clock
    starts again, and when nothing was tracking the IMU's publish order any more the IMU
    history starts again too (a reading before the next IMU message is left out)."""
    def stamp_of(r):
        return r[0]
    c = LiveClocks(['/a'], [False])
    c.retype(0, True)                         # undecided header-stamped -> header-less
    assert c.bare == [True] and c.on and c.choices[0].headerless
    c.add_imu([10], [100 * S])
    assert c.stamp(0, [(11, 20.0)]).stamp_ns.tolist() == []   # waits for the next IMU
    c.add_imu([12], [101 * S])
    assert c.stamp(0, []).stamp_ns.tolist() == [100 * S]
    c = LiveClocks(['/a'], [False])          # decided on header stamps: the IMU not tracked
    c.add_imu([10], [100 * S])
    c.choose(0, [(100 * S, 11, 20.0)], stamp_of)
    assert not c.on
    c.add_imu([12], [101 * S])               # not kept: the newest known is still 100 s
    c.clock.add_reading(0, 13, 21.0)          # (a reading of the old type, still waiting)
    left = c.clock.left_out
    c.retype(0, True)                         # the driver now publishes a header-less type
    assert c.on and c.bare == [True] and c.span is None and c.clock._n == 0
    assert c.clock.left_out == left and not c.clock._wait[0]   # the old reading dropped
    assert c.stamp(0, [(14, 22.0)]).stamp_ns.tolist() == []    # before the next IMU message
    c.add_imu([15], [102 * S])
    assert c.stamp(0, []).stamp_ns.tolist() == [] and c.clock.left_out == left + 1
    assert c.stamp(0, [(16, 23.0)]).stamp_ns.tolist() == []
    c.add_imu([17], [103 * S])
    assert c.stamp(0, []).stamp_ns.tolist() == [102 * S]
    c.retype(0, False)                        # and back: the choice waits again
    assert c.undecided(0) and not c.bare[0] and c.on


def test_fresh_live_clocks_choose_again():
    """A calibrator's ``~/reset``: the inputs and their types stay, every choice is redone."""
    def stamp_of(r):
        return r[0]
    c = LiveClocks(['/a', '/b'], [False, True])
    c.add_imu([10], [100 * S])
    c.choose(0, [(0, 11, 20.0)], stamp_of)          # stamp 0: the IMU's clock
    assert c.bare == [True, True]
    f = c.fresh()
    assert f.undecided(0) and f.bare == [False, True] and f.on and f.clock._n == 0
    assert [x.topic for x in f.choices] == ['/a', '/b'] and f.clock.left_out == 0
    f.add_imu([20], [200 * S])
    f.choose(0, [(200 * S, 21, 20.0)], stamp_of)    # now stamped by the IMU's clock
    assert f.bare == [False, True] and not f.undecided(0)
