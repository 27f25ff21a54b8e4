"""Pose changes between holds through the offline pipeline and the CLI (whole_unit gyro).

The seed 002 gyro (``--model whole_unit``, or chosen for an accelerometer-only model) fits
the gyro scale and misalignment (Omega1) from the rotations between static holds. Checked
here: the pipeline collects them (MotionCollector) without changing the windows, keeps each
on its own holds when logs are merged, ``--save-windows`` writes them, and the CLI estimate
is real: much closer to the true Omega1 than the prior."""

import io

from _motion_data import recording, SHORT_COLDSTART
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main
from thermal_imu_calib.collection.motion import load_transitions, save_transitions, Transition
from thermal_imu_calib.collection.segments import Windows
from thermal_imu_calib.io.columns import ImuColumns
from thermal_imu_calib.app.collect import collect_windows
from thermal_imu_calib.collection.collected import merge_transitions, merge_windows
from thermal_imu_calib.rotations import integrate_rotation


def assert_on_their_holds(windows, transitions):
    """Each pose change spans from the end of its hold_from to the start of its hold_to."""
    for tr in transitions:
        end = windows.t1[windows.hold == tr.hold_from].max()
        start = windows.t0[windows.hold == tr.hold_to].min()
        assert abs(tr.t[0] - end) < 0.011 and abs(tr.t[-1] - start) < 0.011, \
            (tr.hold_from, tr.hold_to, tr.t[0], end, tr.t[-1], start)


def pose_change_angle_errors(rec, cal):
    """Return RMS rotation errors (deg) over the pose changes: ours, true parameters, raw.

    Each is the angle between the rotation integrated from the true body rate and the one
    integrated from: ``cal`` on the written (distorted) log, the simulator's true calibration
    on its undistorted raw data, and the raw log.
    """
    imu = ImuColumns.concat(list(rec.imu_chunks()))
    raw_sim = ImuColumns.concat(list(rec.rec.imu_chunks()))
    tcs = list(rec.rec.truth_chunks())
    w_true = np.concatenate([tc.angular_rate for tc in tcs])
    temps = np.concatenate([tc.temps for tc in tcs])
    t = (imu.stamp_ns - imu.stamp_ns[0]) * 1e-9
    ours = cal.apply(imu.accel, imu.gyro, temps[:, :len(cal.temperature_topics)]).gyro
    true = rec.truth.apply(raw_sim.accel, raw_sim.gyro,
                           temps[:, :len(rec.truth.temperature_topics)]).gyro
    moving = np.flatnonzero(np.linalg.norm(w_true, axis=1) > 1e-3)
    segs = np.split(moving, np.flatnonzero(np.diff(moving) > 1) + 1)
    assert len(segs) == len(rec.schedule) - 1

    def rms(rates):
        ang = [np.linalg.norm((Rotation.from_rotvec(integrate_rotation(t[s], w_true[s])).inv() *
                               Rotation.from_rotvec(integrate_rotation(t[s], rates[s])))
                              .as_rotvec()) for s in segs]
        return float(np.degrees(np.sqrt(np.mean(np.square(ang)))))
    return rms(ours), rms(true), rms(imu.gyro)


@pytest.fixture(scope='module')
def coldstart(tmp_path_factory):
    """Return (recording, bag path) of a short MEMS cold start with a distorted gyro."""
    rec = recording('mems-coldstart', 0, **SHORT_COLDSTART)
    return rec, rec.write(str(tmp_path_factory.mktemp('coldstart') / 'cold.mcap'))


def test_merged_logs_keep_each_pose_change_on_its_own_holds(tmp_path):
    recs = [recording('demo', seed, repetitions=1) for seed in (3, 4)]
    paths = [r.write(str(tmp_path / f'log{i}.mcap')) for i, r in enumerate(recs)]
    cols = [collect_windows(p, motion=True, progress=False) for p in paths]
    plain = collect_windows(paths[1], progress=False)
    assert plain.transitions == [] and plain.motion is None
    assert np.array_equal(plain.windows.t0, cols[1].windows.t0)
    assert np.array_equal(plain.windows.accel, cols[1].windows.accel)
    for c, r in zip(cols, recs):
        assert len(c.transitions) == len(c.windows.hold_ids) - 1 == len(r.schedule) - 1
        assert 0 < c.motion['peak_bytes'] < 3e6 and not any(c.motion['dropped'].values())
        assert_on_their_holds(c.windows, c.transitions)
    w, trs = merge_windows(cols), merge_transitions(cols)
    assert len(w.hold_ids) == sum(len(c.windows.hold_ids) for c in cols)
    assert len(trs) == sum(len(c.transitions) for c in cols)
    assert_on_their_holds(w, trs)
    assert trs[len(cols[0].transitions)].hold_from == len(cols[0].windows.hold_ids)
    assert cols[1].transitions[0].hold_from == 0          # the inputs are not modified


def test_cli_whole_unit_fits_gyro_scale_and_misalignment_from_pose_changes(coldstart, tmp_path,
                                                                           capsys):
    rec, bag = coldstart
    out, saved = str(tmp_path / 'cal.yaml'), str(tmp_path / 'windows.jsonl')
    assert main(['calibrate', bag, '--model', 'whole_unit', '--latitude', '45', '-o', out,
                 '--save-windows', saved]) == 0
    cap = capsys.readouterr()
    n = len(rec.schedule) - 1
    assert f'stationary holds, {n} pose changes' in cap.err, cap.err
    assert f'{n} of {n} pose changes used for gyro scale and misalignment' in cap.out, cap.out
    cal = Calibration.load(out)
    assert cal.gyro.kind == 'whole_unit_gyro'
    assert np.all(cal.gyro.meta()['estimated']['Omega1'])
    assert 'Omega1' not in cal.gyro.meta().get('fixed', {})
    assert cal.fit['pose_changes'] == {'collected': n, 'used': n}
    truth = rec.true_omega1()
    om1 = cal.gyro.params()['Omega1']
    err = np.abs(om1.value - truth).max()
    prior_err = np.abs(np.eye(3) - truth).max()
    # Omega1 within its own stated 1-sigma of the truth (seed 0: max |z| 2.6), and far from
    # the prior (the identity)
    z = np.abs(om1.value - truth) / om1.std
    assert z.max() < 4.0 and err < prior_err / 5, \
        f'Omega1: max |z| {z.max():.3g}, max error {err:.3g} vs prior {prior_err:.3g}'
    # the compensated gyro integrates over each pose change to the true rotation about as well
    # as the true calibration applied to the undistorted raw data does (noise floor)
    ours, true, raw = pose_change_angle_errors(rec, cal)
    assert ours < 2.0 * true, (f'pose-change rotation error RMS [deg]: ours {ours:.3g}, '
                               f'true parameters {true:.3g}, raw {raw:.3g}')
    # --save-windows keeps the pose changes next to the windows, on the same hold ids
    windows = Windows.from_jsonl(open(saved).read())
    trs = load_transitions(saved + '.transitions.npz')
    assert len(trs) == n and len(windows.hold_ids) == n + 1
    assert_on_their_holds(windows, trs)


def test_cli_field_model_gyro_uses_the_pose_changes_too(coldstart, tmp_path, capsys):
    rec, bag = coldstart
    out = str(tmp_path / 'f.yaml')
    assert main(['calibrate', bag, '--model', 'field', '--latitude', '45', '-o', out]) == 0
    cap = capsys.readouterr()
    n = len(rec.schedule) - 1
    assert f'stationary holds, {n} pose changes' in cap.err, cap.err
    cal = Calibration.load(out)
    assert cal.accel.kind == 'field_polynomial'
    # six faces of a g-sensitive MEMS gyro: gyro_select picks the seed 002 gyro, which uses
    # every pose change (the other branch, 'used': 0, would hide a broken pose-change path)
    assert cal.gyro.kind == 'whole_unit_gyro', cal.fit.get('gyro_selection')
    assert cal.fit['pose_changes'] == {'collected': n, 'used': n}
    assert f'{n} of {n} pose changes used' in cap.out, cap.out
    assert np.all(cal.gyro.meta()['estimated']['Omega1'])


def test_transitions_file_round_trip_and_bad_files():
    rng = np.random.default_rng(0)
    trs = [Transition(h, h + 1, np.arange(n) * 0.005, rng.normal(size=(n, 3)),
                      rng.normal(size=(n, 3)), np.array([22.0 + h]), closed=(h == 4))
           for h, n in ((0, 700), (4, 3))]
    buf = io.BytesIO()
    save_transitions(buf, trs)
    back = load_transitions(io.BytesIO(buf.getvalue()))
    for a, b in zip(trs, back):
        assert (a.hold_from, a.hold_to, a.closed) == (b.hold_from, b.hold_to, b.closed)
        for name in ('t', 'gyro', 'accel', 'temps'):
            assert np.array_equal(getattr(a, name), getattr(b, name))
    empty = io.BytesIO()
    save_transitions(empty, [])
    assert load_transitions(io.BytesIO(empty.getvalue())) == []
    for bad in (buf.getvalue()[:len(buf.getvalue()) // 2], b'not an npz'):
        with pytest.raises(ValueError, match='not a readable transitions file.*delete it'):
            load_transitions(io.BytesIO(bad))
    other = io.BytesIO()
    np.savez(other, t=np.zeros(3))
    with pytest.raises(ValueError, match="not a transitions file.*missing.*'accel'"):
        load_transitions(io.BytesIO(other.getvalue()))
