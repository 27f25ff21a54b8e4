"""``placement_folds``: held-out folds that never keep a test hold's other windows in training.

A robot's stops are separate placements: each hold's level on the horizontal axes holds
g sin(floor tilt). A fold that tests on part of a hold while training on the rest of it
lets a model that can tell holds apart (a lagged input barely moves inside one) learn that
level and "predict" it (docs/lifelong.md, "The first estimate reads floor tilt as
temperature").
"""

import numpy as np

from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.selection.one_way_select import band_folds
from thermal_imu_calib.selection.time_folds import time_folds, whole_holds


def _windows(holds, temps):
    m = len(holds)
    t0 = np.arange(m) * 30.0
    z = np.zeros((m, 3))
    temps = np.asarray(temps, float)[:, None]
    return Windows(hold=np.asarray(holds), t0=t0, t1=t0 + 30.0, n=np.full(m, 100), accel=z,
                   gyro=z, accel_var=z, gyro_var=z, temp=temps, temp_rate=np.zeros_like(temps))


def test_no_test_hold_keeps_windows_in_training():
    # 8 holds of 15 windows, 20 windows a temperature band: holds straddle band edges
    holds = np.repeat(np.arange(8), 15)
    temps = np.linspace(0.0, 12.0, 120)
    w = _windows(holds, temps)
    leaky, _ = band_folds(w)
    assert any(np.isin(w.hold[tr], w.hold[te]).any() for tr, te, _ in leaky)
    folds, kind = band_folds(w, placements=True)
    assert folds and 'separate placements' in kind
    for tr, te, _ in folds:
        assert not np.isin(w.hold[tr], w.hold[te]).any() and not (tr & te).any()
    for tr, te, _ in time_folds(w, placements=True)[0]:
        assert not np.isin(w.hold[tr], w.hold[te]).any()


def test_one_continuous_hold_keeps_no_fold():
    """One mounting, one hold (a chamber log): nothing is left to train on, so the option
    is for separate placements only; without it the window bands stay."""
    w = _windows(np.zeros(120, int), np.linspace(0.0, 12.0, 120))
    assert len(band_folds(w)[0]) == 4
    assert whole_holds(w, band_folds(w)[0]) == []
