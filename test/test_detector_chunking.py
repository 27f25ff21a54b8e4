"""The detector and the pose-change collector do not depend on how the stream is cut.

The calibrator node gets live DDS data in batches of any size, the CLI reads 20,000
messages at a time and the temperature aligner re-cuts them: all must give the same holds,
windows and pose changes. A real recording (imucal's Ferraris session, a fixture) and a
simulated one (``hand-held``, with a temperature input) are fed in chunks of 1, 7, 50,
777 and 20,000 samples and of random sizes, and everything compared bit for bit; so is the
node's ``~/calibrate`` path (a deep copy of the live collector, finished) against an
offline run over the same samples.
"""

import copy
import dataclasses
import os

import numpy as np
import pytest

from thermal_imu_calib import sim
from thermal_imu_calib.collection import stationary
from thermal_imu_calib.collection.motion import MotionCollector
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.io.align import StreamAligner
from thermal_imu_calib.io.columns import TemperatureColumns
from thermal_imu_calib.io.csv_logs import read_imucal_session

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FER = os.path.join(ROOT, 'test', 'fixtures', 'real', 'imucal_ferraris')
SIZES = [1, 7, 50, 777, 20000, 'random']


def ferraris():
    s = read_imucal_session(os.path.join(FER, 'example_ferraris_session.csv.gz'))
    return s.imu.t, s.imu.accel, s.imu.gyro, np.zeros((len(s.imu.t), 0))


def hand_held():
    """The simulated hand-held session through the temperature aligner, as columns."""
    rec = sim.simulate('hand-held', 0)
    temps = list(rec.temperatures.values())
    aligner = StreamAligner(len(temps))
    parts, pending = [], temps
    for ch in rec.imu_chunks():
        parts += aligner.push_columns(ch, pending)
        pending = [TemperatureColumns.empty() for _ in temps]
    parts += aligner.finish()
    assert temps and parts
    return tuple(np.concatenate(c) for c in zip(*[(a.imu.t, a.imu.accel, a.imu.gyro, a.temps)
                                                  for a in parts]))


@pytest.fixture(scope='module', params=['ferraris', 'hand-held'])
def stream(request):
    return ferraris() if request.param == 'ferraris' else hand_held()


def cuts(n, size, seed=0):
    """Return chunk boundaries over n samples: fixed ``size`` or random sizes 1..3000."""
    if size == 'random':
        rng = np.random.default_rng(seed)
        steps = rng.integers(1, 3000, n)
        steps[rng.random(n) < 0.3] = 1          # many tiny batches, as DDS delivers them
    else:
        steps = np.full(n // size + 1, size)
    ends = np.cumsum(steps)
    return np.r_[0, ends[ends < n], n]


def feed(col, cols, bounds):
    parts = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        parts.append(col.update(*(c[lo:hi] for c in cols)))
    return parts


def run(cols, size):
    col = MotionCollector(None, cols[3].shape[1])
    parts = feed(col, cols, cuts(len(cols[0]), size))
    parts.append(col.finish())
    return Windows.concat(parts), col


def assert_same_collection(a, b, where):
    (wa, ca), (wb, cb) = a, b
    for f in dataclasses.fields(Windows):
        x, y = getattr(wa, f.name), getattr(wb, f.name)
        assert x.dtype == y.dtype and np.array_equal(x, y), (where, f.name)
    assert ca.det.holds == cb.det.holds, where
    assert ca.det.settings() == cb.det.settings(), where
    assert ca.dropped == cb.dropped, where
    assert len(ca.transitions) == len(cb.transitions), where
    for ta, tb in zip(ca.transitions, cb.transitions):
        for f in dataclasses.fields(ta):
            x, y = getattr(ta, f.name), getattr(tb, f.name)
            assert np.array_equal(x, y), (where, f.name, ta.hold_from)


def test_same_holds_windows_and_pose_changes_whatever_the_chunks(stream):
    want = run(stream, 20000)
    w, col = want
    assert len(col.det.holds) >= 10 and len(col.transitions) >= 9   # real detections
    assert len(w.hold_ids) == len(col.det.holds)
    for size in SIZES:
        assert_same_collection(run(stream, size), want, size)


@pytest.mark.parametrize('seed', [1, 2])
def test_a_copy_finished_mid_stream_is_the_offline_run_of_those_samples(stream, seed):
    # the calibrator node's ~/calibrate: deep-copy the live collector, finish the copy;
    # the live one goes on and, at the end, is the offline run of the whole stream
    n = len(stream[0])
    bounds = cuts(n, 'random', seed)
    live = MotionCollector(None, stream[3].shape[1])
    parts = []
    rng = np.random.default_rng(seed)
    stops = set(rng.choice(len(bounds) - 1, 3, replace=False).tolist())
    for i, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])):
        parts.append(live.update(*(c[lo:hi] for c in stream)))
        if i in stops:
            snap = copy.deepcopy(live)
            got = Windows.concat(parts + [snap.finish()])
            prefix = tuple(c[:hi] for c in stream)
            assert_same_collection((got, snap), run(prefix, 20000), ('copy at', int(hi)))
    parts.append(live.finish())
    assert_same_collection((Windows.concat(parts), live), run(stream, 777), 'live')


def test_settings_come_from_the_first_samples_only():
    # a first chunk longer than DERIVE_SAMPLES must not change the derived rate
    t = np.arange(5000) * 0.01
    t[stationary.DERIVE_SAMPLES + 10:] = (t[stationary.DERIVE_SAMPLES + 10] +
                                          np.arange(5000 - stationary.DERIVE_SAMPLES - 10)
                                          * 0.004)
    rng = np.random.default_rng(3)
    a = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.01, (5000, 3))
    g = rng.normal(0, 1e-3, (5000, 3))
    rates = []
    for first in (stationary.DERIVE_SAMPLES, 5000):
        det = stationary.StationaryDetector()
        det.update(t[:first], a[:first], g[:first])
        det.update(t[first:], a[first:], g[first:])
        det.finish()
        rates.append(det.settings()['rate_hz'])
    assert rates[0] == rates[1] == pytest.approx(100.0)
