"""Both nodes over DDS: calibrate live from a simulated cold start, then compensate another.

The simulated ``demo`` device (two rounds of six faces during a MEMS warm-up) is replayed
evenly paced and faster than real time into the calibrator and the compensator;
``~/calibrate`` estimates and publishes the model, the compensator picks it up from the
latched topic, and a second, independent cold start of the same device is replayed: every
message must come out, with a static gravity error at least 20x smaller than the raw one.
"""

import dataclasses

from conftest import replay, wait_for
import numpy as np

from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import Trigger

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.nodes import common
from thermal_imu_calib.nodes.calibrator import CalibratorNode
from thermal_imu_calib.nodes.compensator import CompensatorNode


SEED = 3
RATE = 1000.0   # IMU messages per second: 10x the recording's 100 Hz


def recordings():
    """Return (calibration run, validation run): two cold starts of one simulated device."""
    cal_run = sim.simulate('demo', SEED)
    val_cfg = dataclasses.replace(sim.SCENARIOS['demo'], name='demo-validation',
                                  repetitions=1, t_amb=23.0)
    return cal_run, sim.simulate(val_cfg, SEED)


def hold_gravity_error(rec, stamps, accel, shift_ns=0, guard_s=1.5):
    """Return per-hold | |mean f| - g | in m/s^2 over the recording's stationary holds."""
    out = []
    for h in rec.schedule:
        m = ((stamps >= h.stamp_start_ns + shift_ns + guard_s * 1e9)
             & (stamps <= h.stamp_end_ns + shift_ns - guard_s * 1e9))
        assert m.sum() > 100, f'hold {h.index} has only {m.sum()} samples'
        out.append(abs(np.linalg.norm(accel[m].mean(0)) - rec.gravity))
    return np.array(out)


def test_live_calibration_then_compensation_of_a_new_cold_start(ros, tmp_path):
    cal_run, val_run = recordings()
    cal_file = tmp_path / 'calibration.yaml'
    calibrator = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal_file)),
        Parameter('collection_file', value=str(tmp_path / 'collection.jsonl')),
        Parameter('gravity', value=float(cal_run.gravity))]))
    compensator = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal_file))]))
    assert compensator.active is None
    driver = ros.node('player')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    (topic, temps), = cal_run.temperatures.items()
    temp_pub = driver.create_publisher(Temperature, topic, 100)
    out = []
    sub = driver.create_subscription(Imu, 'imu/data_compensated',
                                     lambda m: out.extend([m] + common.drain(sub, 999, driver)),
                                     10000)
    ros.wait_matched(imu_pub, 2)
    ros.wait_matched(temp_pub, 2)
    wait_for(lambda: compensator.pub.get_subscription_count() >= 1, 10, 'output subscriber')

    # 1. calibration run
    imu = cal_run.imu()
    n = replay(imu_pub, imu, [(temp_pub, temps.stamp_ns, temps.temperature)], RATE)
    # generous waits: a loaded 2-core machine may take a while to drain the queues, but
    # every message must still arrive
    wait_for(lambda: compensator.counts['received'] >= n, 60,
             lambda: f'compensator input {n} (got {compensator.counts["received"]})')
    wait_for(lambda: calibrator.counts['samples'] >= n - 200, 60,
             lambda: f'calibrator to collect ~{n} samples: {calibrator.counts}, '
                     f'received {calibrator._rate.total}')
    wait_for(lambda: len(out) >= n, 60, lambda: f'{n} passed-through messages (got {len(out)})')
    assert compensator.counts['passthrough'] == n   # no model yet: passthrough, nothing lost
    progress = calibrator.progress()
    assert progress['missing_faces'] == [] and progress['ready'], progress

    resp = ros.call(driver, Trigger, '/thermal_imu_calibrator/calibrate', timeout=60)
    assert resp.success, resp.message
    cal = Calibration.load(cal_file)
    assert cal.id in resp.message and 'field_polynomial' in resp.message
    assert cal.temperature_topics == ['imu/temperature'] and cal.frame_id == 'imu_link'
    wait_for(lambda: compensator.active is not None and compensator.active.id == cal.id, 10,
             'the compensator to apply the published calibration')

    # 2. validation run of the same device: count every message, compare static errors
    out.clear()
    compensator.counts['received'] = 0
    # the same clock: the validation run starts 10 s after the calibration run ended
    shift = int(imu.stamp_ns[-1]) + 10 * 10 ** 9 - int(val_run.start_ns)
    vimu = val_run.imu()
    vimu.stamp_ns = vimu.stamp_ns + shift
    (vtopic, vtemps), = val_run.temperatures.items()
    n = replay(imu_pub, vimu, [(temp_pub, vtemps.stamp_ns + shift, vtemps.temperature)], RATE)
    wait_for(lambda: len(out) >= n, 60, lambda: f'all {n} compensated messages (got {len(out)})')
    assert len(out) == n
    stamps, accel, _ = common.imu_to_arrays(out)
    order = np.argsort(stamps)
    stamps, accel = stamps[order], accel[order]
    np.testing.assert_array_equal(stamps, vimu.stamp_ns)
    assert compensator.counts['compensated'] == n, compensator.counts
    assert np.isfinite(accel).all()
    raw_err = hold_gravity_error(val_run, vimu.stamp_ns, vimu.accel, shift)
    comp_err = hold_gravity_error(val_run, stamps, accel, shift)
    ratio = np.sqrt(np.mean(raw_err ** 2)) / np.sqrt(np.mean(comp_err ** 2))
    print(f'static gravity error RMS over {len(raw_err)} holds: raw '
          f'{np.sqrt(np.mean(raw_err ** 2)) * 1e6 / 9.8:.0f} ug, compensated '
          f'{np.sqrt(np.mean(comp_err ** 2)) * 1e6 / 9.8:.1f} ug, ratio {ratio:.0f}')
    assert ratio >= 20, (raw_err, comp_err)
    assert comp_err.max() < raw_err.min()
