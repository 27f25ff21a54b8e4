"""The real chamber log through both nodes: the CLI's calibration, the stream's compensation.

The training part of the tofupilot chamber log (one orientation, 51.6 -> -17.6 -> 74 degC,
~2 Hz) is replayed over DDS into the calibrator, which must estimate what the CLI's
``calibrate_windows`` estimates offline (a history-dependent model chosen on held-out
blocks); the compensator then applies it to a second replay from its streaming state,
sample for sample what ``Calibration.stream()`` gives offline.
"""

import os

from conftest import calibrate_compensate_rig, replay_flow, wait_count, wait_for
import numpy as np

from std_srvs.srv import Trigger

from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows, CalibrateOptions
from thermal_imu_calib.io.csv_logs import read_tofupilot_chamber
from thermal_imu_calib.nodes import common
from thermal_imu_calib.collection.feed import windows_from_columns

CHAMBER = os.path.join(os.path.dirname(__file__), 'fixtures', 'real', 'tofupilot_chamber',
                       'imu_chamber_train.csv.gz')
RATE = 1000.0
WAIT = 120.0
#: replay chunks of 8 samples (4 s at ~2 Hz): a chunk's temperatures are published before its
#: IMU messages, and a lead of more than 10 s reads as a clock jump (temperatures cleared)
WINDOW = 16
G = 9.80665


def test_chamber_log_calibrator_equals_cli_and_compensator_streams(ros, tmp_path):
    imu, tc = read_tofupilot_chamber(CHAMBER)
    start = 1_700_000_000 * 10 ** 9
    imu.stamp_ns = imu.stamp_ns + start
    tc.stamp_ns = tc.stamp_ns + start
    offline = calibrate_windows(windows_from_columns([imu], [tc]), CalibrateOptions(
        inputs=[TemperatureInput('imu/temperature')], gravity=G)).calibration

    cal_file = tmp_path / 'calibration.yaml'
    calibrator, compensator, driver, imu_pub, temp_pub, out = calibrate_compensate_rig(
        ros, tmp_path, G)

    n = replay_flow(imu_pub, imu, [(temp_pub, tc.stamp_ns, tc.temperature)], RATE,
                    lambda: calibrator._rate.total, window=WINDOW, what='the calibrator input')
    wait_count(lambda: calibrator._rate.total, n, 'calibrator input')
    resp = ros.call(driver, Trigger, '/thermal_imu_calibrator/calibrate', timeout=WAIT)
    assert resp.success, resp.message
    live = Calibration.load(cal_file)
    # the same calibration as the CLI path: model, history terms, coefficients
    assert live.fit['model_choice']['model'] == offline.fit['model_choice']['model'] == \
        'hysteresis'
    for which in ('accel', 'gyro'):
        a, b = getattr(live, which), getattr(offline, which)
        assert a.kind == b.kind == 'hysteresis_offset' and a.history_keys == b.history_keys
        np.testing.assert_allclose(a.coeffs, b.coeffs, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(a.term_coeffs, b.term_coeffs, rtol=1e-9, atol=1e-15)
    wait_for(lambda: compensator.active is not None and compensator.active.id == live.id, WAIT,
             'the compensator to apply the published calibration')

    # a second replay a day later: the compensator's stream state against the offline one
    out.clear()
    compensator.counts['received'] = 0
    shift = 86400 * 10 ** 9
    second = imu.slice(slice(0, len(imu.stamp_ns)))
    second.stamp_ns = imu.stamp_ns + shift
    # every reading is in before the samples it belongs to (``readings``): the reference
    # below uses the reading at each sample's own stamp
    n = replay_flow(imu_pub, second, [(temp_pub, tc.stamp_ns + shift, tc.temperature)], RATE,
                    lambda: compensator.counts['received'], window=WINDOW,
                    what='the compensator input', readings=lambda: compensator.temps.received[0])
    got = wait_count(lambda: compensator.counts['received'], n, 'compensator input')
    wait_for(lambda: len(out) >= got, WAIT, lambda: f'{got} compensated (got {len(out)})')
    assert got >= 0.99 * n, compensator.counts
    stamps, accel, gyro = common.imu_to_arrays(out)
    order = np.argsort(stamps)
    stamps, accel, gyro = stamps[order], accel[order], gyro[order]
    rows = np.searchsorted(second.stamp_ns, stamps)
    assert np.array_equal(second.stamp_ns[rows], stamps)
    comp = np.any(accel != second.accel[rows], axis=1)
    assert comp.sum() == compensator.counts['compensated'] >= 0.99 * n, compensator.counts
    r = rows[comp]
    ref = live.stream().apply(second.stamp_ns[r] * 1e-9, second.accel[r], second.gyro[r],
                              tc.temperature[r, None])
    # the compensator's streaming state gives what the offline stream gives on its samples
    np.testing.assert_allclose(accel[comp], ref.accel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gyro[comp], ref.gyro, rtol=0, atol=1e-9)
