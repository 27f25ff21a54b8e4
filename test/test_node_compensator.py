"""Compensator node over real DDS: compensation, reload, policies, rejection, diagnostics."""

import json
import threading

from conftest import imu_msg, other_participant, temperature_msg, wait_count, wait_for
import numpy as np
import pytest

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.io.imu_units import ACCEL_WINDOW
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.nodes import common
from thermal_imu_calib.nodes.compensator import CompensatorNode
from thermal_imu_calib.nodes.compensator_batch import SILENT_WARN_AFTER

S = 1_000_000_000
WAIT = 60.0   # bound of a wait on a condition (reached only when something is broken)
T0_NS = 1_700_000_000 * S
ACCEL = (0.3, -0.2, 9.7)
GYRO = (0.01, -0.02, 0.005)


def make_cal(db0=0.05, b1=2e-3, topics=('imu/temperature',), valid=(20.0, 40.0),
             frame_id='imu_link'):
    """Return a field + gyro-offset calibration with clearly visible corrections."""
    th = np.zeros((3, 6))
    th[:, 0], th[:, 1], th[:, 3], th[:, 4] = 2e-3, -5e-5, db0, b1
    k = len(topics)
    idx = [0, 1, 2] if k == 3 else [0, 0, 0]
    return Calibration(
        accel=FieldPolynomialModel([30.0] * 3, th),
        gyro=OffsetPolynomialModel([30.0] * 3, np.array([[1e-3, 1e-4, 0.0]] * 3), 'gyro'),
        inputs=[TemperatureInput(f't{i}', t) for i, t in enumerate(topics)],
        valid_range=np.array([valid] * k) if k else None, accel_input=idx, gyro_input=idx,
        frame_id=frame_id, accel_noise_std=np.array([1e-3, 2e-3, 3e-3]),
        gyro_noise_std=np.array([1e-4, 2e-4, 3e-4]))


def expected(cal, temp):
    """Return the core's result for the test sample at one temperature."""
    return cal.apply(np.array([ACCEL]), np.array([GYRO]), np.array([[temp]]))


def vec(m):
    """Return (accel, gyro) of an Imu message as arrays."""
    a, w = m.linear_acceleration, m.angular_velocity
    return np.array([a.x, a.y, a.z]), np.array([w.x, w.y, w.z])


class Rig:
    """A compensator plus a driver node publishing inputs and collecting the output."""

    def __init__(self, ros, **params):
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.ros = ros
        self.node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=overrides))
        self.driver = ros.node('driver')
        self.imu_pub = self.driver.create_publisher(Imu, 'imu/data_raw', 1000)
        self.temp_pub = self.driver.create_publisher(Temperature, 'imu/temperature', 100)
        self.cal_pub = self.driver.create_publisher(String, 'imu/calibration',
                                                    common.CALIBRATION_QOS)
        self.out = ros.collect(self.driver, Imu, 'imu/data_compensated', 1000)
        self.diag = ros.collect(self.driver, DiagnosticArray, '/diagnostics', 10)
        ros.wait_matched(self.imu_pub)
        ros.wait_matched(self.temp_pub)
        wait_for(lambda: self.node.pub.get_subscription_count() >= 1, WAIT, 'output subscriber')
        self.stamp = T0_NS

    def temperature(self, value, stamp=None):
        """Publish one temperature reading and wait until the node has it."""
        before = sum(self.node.temps.received)
        self.temp_pub.publish(temperature_msg(self.stamp if stamp is None else stamp, value))
        wait_for(lambda: sum(self.node.temps.received) > before, WAIT, 'the temperature reading')

    def send(self, n=1, dt=0.01, accel=ACCEL, gyro=GYRO):
        """Publish n IMU samples dt apart (stamps continue from the last ones)."""
        for _ in range(n):
            self.imu_pub.publish(imu_msg(self.stamp, accel, gyro))
            self.stamp += int(dt * S)

    def send_paced(self, n, dt=0.01, chunk=100):
        """Publish n IMU samples in chunks, each after the node has taken the one before.

        The inputs are best effort: a burst of more samples than the node takes at once can
        lose some (a clean clone's run lost samples of a 1200-sample burst). Returns the
        number the node received (``wait_count``: at most 1 % lost).
        """
        start = self.node.counts['received']
        for sent in range(0, n, chunk):
            if sent:
                wait_count(lambda: self.node.counts['received'] - start, sent,
                           f'the node taking {sent} samples')
            self.send(min(chunk, n - sent), dt)
        return wait_count(lambda: self.node.counts['received'] - start, n,
                          f'the node taking {n} samples')

    def receive(self, total, what='compensated messages'):
        """Wait until ``total`` IMU messages were received by the node; return the output."""
        wait_for(lambda: self.node.counts['received'] >= total, WAIT, f'{total} inputs')
        return self.out

    def diagnostics(self):
        """Wait for a fresh /diagnostics message of the node; return its values dict."""
        n = len(self.diag)
        wait_for(lambda: any(s.name.startswith('thermal_imu_compensator')
                             for d in self.diag[n:] for s in d.status), 5, 'diagnostics')
        st = [s for d in self.diag[n:] for s in d.status
              if s.name.startswith('thermal_imu_compensator')][-1]
        return st, {kv.key: kv.value for kv in st.values}


def test_no_calibration_passes_through_and_says_so(ros, tmp_path):
    rig = Rig(ros, calibration_file=str(tmp_path / 'none.yaml'))
    rig.send(5)
    wait_for(lambda: len(rig.out) >= 5, WAIT, '5 passed-through messages')
    for m in rig.out:
        a, w = vec(m)
        assert np.allclose(a, ACCEL) and np.allclose(w, GYRO)
        assert m.orientation_covariance[0] == -1.0
    st, values = rig.diagnostics()
    assert values['model_loaded'] == 'false'
    assert 'no calibration loaded' in st.message and st.level == common.WARN
    assert int(values['passthrough']) == 5


def test_compensates_with_core_result_header_and_covariance(ros, tmp_path):
    cal = make_cal()
    path = cal.save(tmp_path / 'cal.yaml')
    rig = Rig(ros, calibration_file=str(path))
    assert rig.node.active.id == cal.id
    rig.temperature(25.0)
    rig.send(20)
    wait_for(lambda: len(rig.out) >= 20, WAIT, '20 compensated messages')
    exp = expected(cal, 25.0)
    for i, m in enumerate(rig.out):
        a, w = vec(m)
        np.testing.assert_allclose(a, exp.accel[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(w, exp.gyro[0], rtol=0, atol=1e-12)
        assert common.stamp_to_ns(m.header.stamp) == T0_NS + i * S // 100
        assert m.header.frame_id == 'imu_link'
        assert m.orientation_covariance[0] == -1.0
        np.testing.assert_allclose(np.diag(m.linear_acceleration_covariance.reshape(3, 3)),
                                   exp.accel_std[0] ** 2)
        np.testing.assert_allclose(np.diag(m.angular_velocity_covariance.reshape(3, 3)),
                                   exp.gyro_std[0] ** 2)
    assert not np.allclose(exp.accel[0], ACCEL, atol=1e-3)
    st, values = rig.diagnostics()
    assert st.level == common.OK, st.message
    assert values['model_id'] == cal.id and values['model_loaded'] == 'true'
    assert int(values['compensated']) == 20


def test_temperature_is_interpolated_by_header_stamp(ros, tmp_path):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(24.0, T0_NS)
    rig.temperature(26.0, T0_NS + S)
    rig.stamp = T0_NS + S // 2  # halfway between the readings
    rig.send(1)
    wait_for(lambda: len(rig.out) >= 1, WAIT, 'the compensated message')
    np.testing.assert_allclose(vec(rig.out[0])[0], expected(cal, 25.0).accel[0], atol=1e-12)


def test_reload_from_file_and_service(ros, tmp_path):
    a, b = make_cal(db0=0.05), make_cal(db0=-0.08)
    path = tmp_path / 'cal.yaml'
    a.save(path)
    rig = Rig(ros, calibration_file=str(path))
    rig.temperature(30.0)
    b.save(path)
    resp = ros.call(rig.driver, Trigger, '/thermal_imu_compensator/reload')
    assert resp.success, resp.message
    assert b.id in resp.message
    rig.send(3)
    wait_for(lambda: len(rig.out) >= 3, WAIT, 'messages after reload')
    np.testing.assert_allclose(vec(rig.out[-1])[0], expected(b, 30.0).accel[0], atol=1e-12)
    # a bad file is refused with its reason; the model in use stays
    path.write_text('format: thermal_imu_calib/1\naccel: {kind: nope}\n')
    resp = ros.call(rig.driver, Trigger, '/thermal_imu_compensator/reload')
    assert not resp.success
    assert 'rejected' in resp.message and f'keeping calibration {b.id}' in resp.message
    assert rig.node.active.id == b.id
    rig.send(2)
    wait_for(lambda: len(rig.out) >= 5, WAIT, 'messages after the bad reload')
    np.testing.assert_allclose(vec(rig.out[-1])[0], expected(b, 30.0).accel[0], atol=1e-12)


def test_calibration_topic_applies_and_bad_ones_are_rejected(ros, tmp_path):
    a, b = make_cal(db0=0.05), make_cal(db0=-0.08)
    rig = Rig(ros, calibration_file=str(a.save(tmp_path / 'cal.yaml')))
    rig.temperature(28.0)
    rig.cal_pub.publish(String(data=b.to_yaml()))
    wait_for(lambda: rig.node.active.id == b.id, WAIT, 'the topic calibration to apply')
    assert rig.node.active.source == 'imu/calibration topic'
    bad = [
        ('not: [valid', 'not valid YAML'),
        (make_cal(topics=('imu/other_temperature',)).to_yaml(), 'not among temperature_topics'),
        (b.to_yaml().replace("format: thermal_imu_calib/1", "format: other/9"), 'format'),
    ]
    for i, (text, reason) in enumerate(bad):
        rig.cal_pub.publish(String(data=text))
        wait_for(lambda: rig.node.counts['calibrations_rejected'] >= i + 1, 10,
                 f'rejection of bad calibration {i}')
        assert reason in rig.node.last_rejection
        assert rig.node.active.id == b.id
    rig.send(4)
    wait_for(lambda: len(rig.out) >= 4, WAIT, 'messages after rejections')
    for m in rig.out:
        np.testing.assert_allclose(vec(m)[0], expected(b, 28.0).accel[0], atol=1e-12)
    _, values = rig.diagnostics()
    assert int(values['calibrations_rejected']) == 3
    assert 'format' in values['last_rejection']


def test_late_compensator_gets_latched_calibration(ros, tmp_path):
    cal = make_cal(db0=-0.03)
    pub_node = ros.node('latcher')
    pub = pub_node.create_publisher(String, 'imu/calibration', common.CALIBRATION_QOS)
    pub.publish(String(data=cal.to_yaml()))
    node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(tmp_path / 'absent.yaml'))]))
    wait_for(lambda: node.active is not None and node.active.id == cal.id, 10,
             'the latched calibration')


@pytest.mark.parametrize('policy', ['hold_last', 'passthrough', 'drop'])
def test_stale_and_missing_temperature_policies(ros, tmp_path, policy):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')),
              temperature_timeout=0.5, on_missing_temperature=policy)
    # never received: hold_last has nothing to hold, so it passes through
    rig.send(3)
    rig.receive(3)
    rig.temperature(25.0, T0_NS + 30_000_000)
    rig.send(3)           # fresh: 0.03 .. 0.05 s, age < 0.5 s
    rig.stamp += 2 * S    # the temperature is now 2 s old
    rig.send(4)           # stale
    rig.receive(10)
    n_out = 3 if policy == 'drop' else 10
    wait_for(lambda: len(rig.out) >= n_out, WAIT, f'{n_out} published messages')
    comp = expected(cal, 25.0).accel[0]
    got = [vec(m)[0] for m in rig.out]
    is_comp = [bool(np.allclose(g, comp, atol=1e-12)) for g in got]
    is_raw = [bool(np.allclose(g, ACCEL, atol=1e-12)) for g in got]
    assert all(c or r for c, r in zip(is_comp, is_raw))
    c = rig.node.counts
    if policy == 'hold_last':
        assert is_comp == [False] * 3 + [True] * 7
        assert c['temperature_held'] == 4 and c['temperature_missing'] == 3
    elif policy == 'passthrough':
        assert is_comp == [False] * 3 + [True] * 3 + [False] * 4
        assert c['temperature_missing'] == 7 and c['passthrough'] == 7
    else:
        assert is_comp == [True] * 3 and len(got) == 3
        assert c['dropped'] == 7
    st, values = rig.diagnostics()
    assert st.level == common.WARN and 'temperature stale' in st.message
    assert float(values['temperature_age_s[imu/temperature]']) >= 2.0


def test_out_of_range_is_clamped_and_counted(ros, tmp_path):
    cal = make_cal(valid=(20.0, 40.0))
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(55.0)
    rig.send(5)
    wait_for(lambda: len(rig.out) >= 5, WAIT, 'compensated messages')
    np.testing.assert_allclose(vec(rig.out[-1])[0], expected(cal, 40.0).accel[0], atol=1e-12)
    assert rig.node.counts['clamped'] == 5
    _, values = rig.diagnostics()
    assert int(values['clamped']) == 5


def test_non_finite_input_is_never_published(ros, tmp_path):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(25.0)
    rig.send(2)
    rig.send(1, accel=(float('nan'), 0.0, 9.8))
    rig.send(1, gyro=(0.0, float('inf'), 0.0))
    rig.temp_pub.publish(temperature_msg(rig.stamp, float('nan')))
    rig.send(2)
    rig.receive(6)
    wait_for(lambda: len(rig.out) >= 4, WAIT, 'the 4 finite messages')
    for m in rig.out:
        a, w = vec(m)
        assert np.all(np.isfinite(a)) and np.all(np.isfinite(w))
    assert rig.node.counts['invalid'] == 2
    wait_for(lambda: rig.node.temps.invalid == 1, WAIT, 'the NaN temperature to be counted')


def test_model_swap_never_mixes_parameters(ros, tmp_path):
    a, b = make_cal(db0=0.05), make_cal(db0=-0.08)
    b.gyro = OffsetPolynomialModel([30.0] * 3, np.array([[-2e-3, 0.0, 0.0]] * 3), 'gyro')
    rig = Rig(ros, calibration_file=str(a.save(tmp_path / 'cal.yaml')))
    rig.temperature(33.0)
    ea, eb = expected(a, 33.0), expected(b, 33.0)
    stop = threading.Event()

    def swapper():
        i = 0
        while not stop.is_set():
            rig.node.activate(a if i % 2 else b, 'test')
            i += 1
            stop.wait(0.0005)  # leave the GIL to the executor between swaps

    th = threading.Thread(target=swapper)
    th.start()
    try:
        for k in range(40):  # bursts, so batches see different models
            rig.send(10, dt=0.001)
            rig.receive(10 * (k + 1))
    finally:
        stop.set()
        th.join()
    wait_for(lambda: len(rig.out) >= 400, WAIT, '400 outputs')
    kinds = set()
    for m in rig.out:
        acc, gyr = vec(m)
        if np.allclose(acc, ea.accel[0], atol=1e-12):
            assert np.allclose(gyr, ea.gyro[0], atol=1e-12), 'accel from A, gyro not from A'
            kinds.add('a')
        else:
            np.testing.assert_allclose(acc, eb.accel[0], atol=1e-12)
            np.testing.assert_allclose(gyr, eb.gyro[0], atol=1e-12)
            kinds.add('b')
    assert kinds == {'a', 'b'}


def test_several_temperature_topics_map_by_name(ros, tmp_path):
    topics = ('imu/temperature/x', 'imu/temperature/y', 'imu/temperature/z')
    # the file lists absolute names; the node subscribes relative ones (in reverse order)
    cal = make_cal(topics=tuple('/' + t for t in topics))
    rig_node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal.save(tmp_path / 'cal.yaml'))),
        Parameter('temperature_topics', value=list(reversed(topics)))]))
    assert rig_node.active.columns == (2, 1, 0)
    driver = ros.node('driver3')
    pubs = {t: driver.create_publisher(Temperature, t, 10) for t in topics}
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 10)
    out = ros.collect(driver, Imu, 'imu/data_compensated', 10)
    for p in list(pubs.values()) + [imu_pub]:
        ros.wait_matched(p)
    wait_for(lambda: rig_node.pub.get_subscription_count() >= 1, WAIT, 'output subscriber')
    for t, v in zip(topics, (22.0, 27.0, 35.0)):
        pubs[t].publish(temperature_msg(T0_NS, v))
    wait_for(lambda: sum(rig_node.temps.received) >= 3, WAIT, 'three temperatures')
    imu_pub.publish(imu_msg(T0_NS, ACCEL, GYRO))
    wait_for(lambda: len(out) >= 1, WAIT, 'the compensated message')
    exp = cal.apply(np.array([ACCEL]), np.array([GYRO]), np.array([[22.0, 27.0, 35.0]]))
    np.testing.assert_allclose(vec(out[0])[0], exp.accel[0], atol=1e-12)


def test_stamps_jumping_back_start_a_new_temperature_timeline(ros, tmp_path):
    # a bag replayed again, or a second recording with earlier stamps: the temperature of
    # the old timeline must not be used for the new one
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(35.0)
    rig.send(3)
    rig.receive(3)
    rig.stamp = T0_NS - 3600 * S            # one hour earlier
    rig.temperature(25.0, stamp=rig.stamp)  # the new timeline's first reading
    rig.send(3)
    out = rig.receive(6)
    wait_for(lambda: len(out) >= 6, WAIT, '6 outputs')
    a_new, _ = vec(out[-1])
    np.testing.assert_allclose(a_new, expected(cal, 25.0).accel[0], atol=1e-9)
    assert rig.node.temps.time_resets == 1


def test_lagged_temperature_filter_runs_live(ros, tmp_path):
    # a calibration whose models see a 5-s lagged temperature: right after a step from 25
    # to 35 degC the compensation still uses ~25 degC, and it converges to 35 degC later
    from thermal_imu_calib.thermal_input import ThermalFilter
    cal = make_cal()
    cal.temperature_filter = ThermalFilter([5.0])
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(25.0)
    rig.send(10, dt=1.0)           # 10 s at 25 degC: the filter settles at 25
    rig.stamp -= int(0.01 * S)
    rig.send(1, dt=0.01)           # 10 ms before the step
    rig.temperature(35.0)          # the step
    rig.send(1, dt=0.01)           # at the step, 10 ms after the previous sample
    rig.temperature(35.0, stamp=rig.stamp + 60 * S)
    rig.stamp += 60 * S            # a minute later: settled at 35
    rig.send(1)
    out = rig.receive(13)
    wait_for(lambda: len(out) >= 13, WAIT, '13 outputs')
    just_after, _ = vec(out[11])
    settled, _ = vec(out[12])
    np.testing.assert_allclose(just_after, expected(cal, 25.0).accel[0], atol=2e-4)
    np.testing.assert_allclose(settled, expected(cal, 35.0).accel[0], atol=1e-6)


def test_state_file_resumes_the_lag_after_a_restart(ros, tmp_path):
    # a 60-s lagged temperature, 30 s after a 25 -> 35 degC step: the filter is half-way.
    # The node is destroyed (it writes state_file) and a new one started on the same
    # calibration resumes it: its first output equals what one uninterrupted stream gives
    # over the 5-s downtime; without the file it restarts at the reading (35 degC)
    from thermal_imu_calib.thermal_input import ThermalFilter
    cal = make_cal()
    cal.temperature_filter = ThermalFilter([60.0])
    path = str(cal.save(tmp_path / 'cal.yaml'))
    state = tmp_path / 'state.json'
    rig = Rig(ros, calibration_file=path, state_file=str(state), state_save_period=0.1)
    rig.temperature(25.0)
    rig.send(10, dt=1.0)
    rig.temperature(35.0)
    rig.send(31, dt=1.0)
    rig.receive(41)
    stamps = [rig.stamp - (41 - i) * S for i in range(41)]
    ros.remove(rig.node)
    ros.remove(rig.driver)
    assert state.is_file()
    saved = json.loads(state.read_text())
    assert saved['calibration_id'] == Calibration.load(path).id
    assert saved['node'] == '/thermal_imu_compensator'
    assert saved['stream']['t_last'] == pytest.approx(stamps[-1] * 1e-9)
    # the reference: one stream over the same samples and the first one after the restart
    after = rig.stamp + 5 * S
    t = np.array(stamps + [after]) * 1e-9
    temps = np.where(np.arange(len(t)) < 10, 25.0, 35.0)[:, None]
    loaded = Calibration.load(path)
    ref = loaded.stream().apply(t, np.tile(ACCEL, (len(t), 1)), np.tile(GYRO, (len(t), 1)),
                                temps)
    fresh = loaded.apply(np.array([ACCEL]), np.array([GYRO]), np.array([[35.0]]))
    rig2 = Rig(ros, calibration_file=path, state_file=str(state))
    rig2.stamp = after
    rig2.temperature(35.0)
    rig2.send(1)
    out = rig2.receive(1)
    wait_for(lambda: len(out) >= 1, WAIT, 'the first output after the restart')
    first, _ = vec(out[0])
    np.testing.assert_allclose(first, ref.accel[-1], atol=1e-9)
    assert np.max(np.abs(first - fresh.accel[0])) > 1e-3    # the lag was not forgotten


def test_despike_replaces_a_spike_before_compensation(ros, tmp_path):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')), despike=True)
    rig.temperature(30.0)
    rng = np.random.default_rng(0)
    n = 800                      # the gate learns the noise floor from the first 512
    for i in range(n):
        a = np.array(ACCEL) + rng.normal(0, 1e-3, 3)
        if i == 700:
            a[2] += 30.0                      # one ~3 g bump
        rig.send(1, accel=a)
    out = rig.receive(n - 3)     # the gate holds the last 3 samples back
    wait_for(lambda: len(out) >= n - 3, WAIT, 'outputs')
    az = np.array([vec(m)[0][2] for m in out])
    ref = expected(cal, 30.0).accel[0][2]
    assert np.max(np.abs(az - ref)) < 0.05, az
    st, values = rig.diagnostics()
    assert values['spikes_replaced'] == '1'


def test_fill_covariance_can_be_switched_off_at_run_time(ros, tmp_path):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(30.0)
    rig.send(1)
    out = rig.receive(1)
    wait_for(lambda: len(out) >= 1, WAIT, 'one output')
    assert out[0].linear_acceleration_covariance[0] == pytest.approx(1e-3 ** 2, rel=1e-6)
    rig.node.set_parameters([Parameter('fill_covariance', value=False)])
    rig.send(1)
    rig.receive(2)
    wait_for(lambda: len(out) >= 2, WAIT, 'two outputs')
    assert list(out[1].linear_acceleration_covariance) == [0.0] * 9   # as received


def test_output_reliability_best_effort(ros, tmp_path):
    # output_reliability: best_effort publishes with that QoS: a reliable subscriber is
    # incompatible (never matched), a best-effort one gets the compensated messages
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    cal = make_cal()
    node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal.save(tmp_path / 'cal.yaml'))),
        Parameter('output_reliability', value='best_effort')]))
    assert node.pub.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    driver = ros.node('driver')
    reliable = ros.collect(driver, Imu, 'imu/data_compensated', 10)
    best = ros.collect(driver, Imu, 'imu/data_compensated', QoSProfile(
        depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 100)
    temp_pub = driver.create_publisher(Temperature, 'imu/temperature', 10)
    ros.wait_matched(imu_pub)
    ros.wait_matched(temp_pub)
    wait_for(lambda: node.pub.get_subscription_count() >= 1, WAIT, 'the best-effort reader')
    temp_pub.publish(temperature_msg(T0_NS, 30.0))
    wait_for(lambda: sum(node.temps.received) >= 1, WAIT, 'the temperature reading')
    for i in range(20):
        imu_pub.publish(imu_msg(T0_NS + i * 10 ** 7, ACCEL, GYRO))
    wait_for(lambda: len(best) >= 1, WAIT, 'compensated messages at the best-effort reader')
    assert node.pub.get_subscription_count() == 1      # the reliable reader never matched
    assert reliable == []
    a, w = vec(best[0])
    ref = expected(cal, 30.0)
    np.testing.assert_allclose(a, ref.accel[0], rtol=1e-12)
    np.testing.assert_allclose(w, ref.gyro[0], rtol=1e-12)
    assert not np.allclose(w, GYRO)                   # the gyro correction is applied


def _wait_queued(ros, sub):
    """Wait (executor held) until ``sub`` has a message waiting, without taking it."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    def ready():
        with sub.handle, ros.context.handle:
            ws = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, ros.context.handle)
            ws.clear_entities()
            ws.add_subscription(sub.handle)
            ws.wait(10_000_000)
            return sub.handle.pointer in ws.get_ready_entities('subscription')
    wait_for(ready, WAIT, f'a message queued on {sub.topic_name}')


def test_queued_readings_are_taken_before_an_imu_batch(ros, tmp_path):
    # a backlog (a loaded machine): readings stamped within an IMU batch still wait in
    # their queue when the executor runs the IMU callback first; the batch must use them
    # (not the older reading held), and none stamped after the batch
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(24.0, T0_NS)
    with ros.paused():  # the executor is held: everything below queues up
        for k in range(1, 6):
            rig.temp_pub.publish(temperature_msg(T0_NS + k * S // 10, 24.0 + k))
        _wait_queued(ros, rig.node.temp_subs[0])
        rig.stamp = T0_NS + S // 10
        rig.send(5, dt=0.1)   # one sample at each reading's stamp: 25, 26, ... 29 degC
        _wait_queued(ros, rig.node.imu_sub)
    wait_for(lambda: len(rig.out) >= 5, WAIT, '5 compensated messages')
    for k, m in enumerate(rig.out):
        np.testing.assert_allclose(vec(m)[0], expected(cal, 25.0 + k).accel[0], atol=1e-12)
    _, values = rig.diagnostics()
    assert values['input_lost'] == '0' and values['compensated'] == '5'


def test_state_file_name_follows_the_node(ros, tmp_path):
    # {node} in state_file: one configured path, one file per compensator (namespace)
    from thermal_imu_calib.nodes.compensator_state import file_name
    assert file_name('/x/{node}.json', '/imu_left/thermal_imu_compensator') == \
        '/x/imu_left.thermal_imu_compensator.json'
    node = ros.add(CompensatorNode(context=ros.context, namespace='imu_left',
                                   parameter_overrides=[
                                       Parameter('calibration_file', value=''),
                                       Parameter('state_file',
                                                 value=str(tmp_path / '{node}.state.json'))]))
    assert node.state.path == str(tmp_path / 'imu_left.thermal_imu_compensator.state.json')


def test_repeated_and_earlier_stamps_are_compensated_as_compensate_does(ros, tmp_path):
    # a driver that repeats a stamp or jitters one back by 15 ms: the node and the CLI's
    # compensate both compensate those samples at their own stamp (the CLI passed them
    # through raw before 2026-11-29: a 0.35 m/s^2 step in the output on such a sample).
    # The calibration names its input as the node's parameter does (imu/temperature), the
    # log as ros2 bag record does (/imu/temperature): compensate finds it
    from thermal_imu_calib.app.compensate import compensate_log
    from thermal_imu_calib.io import cdr
    from thermal_imu_calib.io.bag import open_log
    from thermal_imu_calib.io.bag_writer import LogWriter
    from thermal_imu_calib.io.cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
    from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns
    cal = make_cal()
    cal_path = cal.save(tmp_path / 'cal.yaml')
    t_stamps = T0_NS + np.arange(6, dtype=np.int64) * S          # 25..30 degC, 1 Hz
    t_values = 25.0 + np.arange(6.0)
    stamps = T0_NS + np.arange(400, dtype=np.int64) * 10_000_000  # 100 Hz over 4 s
    odd = np.arange(50, 390, 37)
    stamps[odd] = stamps[odd - 1]                                 # repeated
    stamps[odd + 3] = stamps[odd + 2] - 15_000_000                # 15 ms behind
    n = len(stamps)
    accel = np.tile(ACCEL, (n, 1))
    gyro = np.tile(GYRO, (n, 1))
    log = tmp_path / 'jitter.mcap'
    with LogWriter(str(log)) as w:    # log time: arrival order (the stamps are the driver's)
        w.add_topic('/imu/temperature', TEMPERATURE_MSGTYPE)
        w.add_topic('/imu/data_raw', IMU_MSGTYPE)
        w.write_many('/imu/temperature', t_stamps - S,
                     cdr.encode_temperature(TemperatureColumns(t_stamps, t_values)))
        w.write_many('/imu/data_raw', T0_NS + np.arange(n, dtype=np.int64) * 10_000_000,
                     cdr.encode_imu(ImuColumns(stamps, accel, gyro, 'imu_link')))
    stats = compensate_log(str(log), str(tmp_path / 'out.mcap'), Calibration.load(cal_path))
    assert stats['compensated'] == n and stats['stamp_jumped_back'] == 0, stats
    assert stats['stamp_jumps'] == 2 * len(odd), stats
    offline = {}
    with open_log(str(tmp_path / 'out.mcap')) as r:
        for _, _, _, data in r.iter_raw(['/imu/data_compensated']):
            m = cdr.decode_imu([data])
            offline.setdefault(int(m.stamp_ns[0]), []).append(m.accel[0])
    truth = np.interp(stamps * 1e-9, t_stamps * 1e-9, t_values)
    rig = Rig(ros, calibration_file=str(cal_path))
    for s, v in zip(t_stamps, t_values):
        rig.temperature(float(v), stamp=int(s))
    for s in stamps:
        rig.imu_pub.publish(imu_msg(int(s), ACCEL, GYRO))
    out = rig.receive(n)
    wait_for(lambda: len(out) >= n, WAIT, f'{n} outputs')
    assert rig.node.counts['compensated'] == n, rig.node.counts
    live = {}
    for m in out:
        live.setdefault(common.stamp_to_ns(m.header.stamp), []).append(vec(m)[0])
    for i in np.concatenate([odd, odd + 3, [0, 10, 399]]):
        want = expected(cal, truth[i]).accel[0]
        for got in live[int(stamps[i])] + offline[int(stamps[i])]:
            np.testing.assert_allclose(got, want, atol=1e-9)


def test_a_temperature_on_another_topic_is_named_in_a_warning(ros, tmp_path):
    # the driver publishes imu/temp, the node listens on imu/temperature: every sample
    # goes out uncompensated; the log says why once, naming the topic to set
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    warned = []
    rig.node._warn_once = lambda key, text: warned.append((key, text))
    other = rig.driver.create_publisher(Temperature, '/imu/temp', 10)
    ros.wait_matched(other, 0)
    wait_for(lambda: '/imu/temp' in dict(rig.node.get_topic_names_and_types()), WAIT,
             'the /imu/temp publisher on the graph')
    other.publish(temperature_msg(rig.stamp, 30.0))
    got = rig.send_paced(1200, dt=0.001)
    assert got >= SILENT_WARN_AFTER
    # received and passthrough are counted once a batch is handled
    wait_for(lambda: rig.node.counts['passthrough'] >= got, WAIT,
             lambda: f'{got} passed through ({rig.node.counts})')
    assert rig.node.counts['compensated'] == 0
    assert rig.node.counts['passthrough'] == rig.node.counts['received'] == got
    texts = [t for k, t in warned if k == 'silent']
    assert texts, warned
    assert texts[0].startswith('no temperature reading has arrived on /imu/temperature '
                               '(1 publishers) while'), texts[0]   # the rig's, silent
    assert 'published uncompensated (on_missing_temperature hold_last)' in texts[0]
    assert "thermal-input topics on the graph: /imu/temp (set temperature_topics:='[/imu/temp]')" \
        in texts[0], texts[0]


def test_a_temperature_of_another_type_is_named_in_a_warning(ros, tmp_path, request):
    # a publisher of a type that is no thermal input (std_msgs/String) on imu/temperature:
    # DDS never connects it to the node's sensor_msgs/Temperature subscription, so nothing
    # arrives and the topic looked right. The log names the type, the publisher and what to
    # do. (A thermal type, std_msgs/Float32 say, is followed: the test above.)
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    warned = []
    rig.node._warn_once = lambda key, text: warned.append((key, text))
    # another participant, as a driver's process is (DDS refuses a second type on a topic
    # inside one participant)
    bare = other_participant(request, 'float_driver').create_publisher(
        String, '/imu/temperature', 10)

    def on_graph():      # with its node's name (discovered after the endpoint, at times)
        return any(i.topic_type == 'std_msgs/msg/String' and i.node_name == 'float_driver'
                   for i in rig.node.get_publishers_info_by_topic('/imu/temperature'))
    wait_for(on_graph, WAIT, 'the String publisher and its node on the graph')
    bare.publish(String(data='30.0'))
    got = rig.send_paced(1200, dt=0.001)   # the warning comes after SILENT_WARN_AFTER
    assert got >= SILENT_WARN_AFTER
    wait_for(lambda: rig.node.counts['passthrough'] >= got, WAIT,
             lambda: f'{got} passed through ({rig.node.counts})')
    assert rig.node.counts['compensated'] == 0
    texts = [t for k, t in warned if k == 'silent']
    assert texts, warned
    assert ('/imu/temperature is published as std_msgs/msg/String by /float_driver, not '
            'sensor_msgs/msg/Temperature, so none of it is received: publish '
            'sensor_msgs/msg/Temperature on it') in texts[0], texts[0]
    assert rig.node.type_follower.types == ['sensor_msgs/msg/Temperature']


def test_diagnostics_keep_coming_with_sim_time_and_no_clock(ros, tmp_path):
    # use_sim_time:=true and no /clock publisher: ROS time stays 0; /diagnostics (on a
    # ROS-time timer before 2026-11-29) never came. Compensation is timed by header stamps
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')), use_sim_time=True)
    assert rig.node.get_clock().now().nanoseconds == 0
    rig.temperature(30.0)
    rig.send(3)
    rig.receive(3)
    status, values = rig.diagnostics()
    assert values['compensated'] == '3', values


def test_no_imu_input_is_named_in_a_warning_with_the_imu_topics_on_the_graph(
        ros, tmp_path, monkeypatch):
    # the driver publishes imu/data, the node listens on imu/data_raw: the log says so once
    # (after input_hints.SILENT_IMU_AFTER_S, 10 s; shortened here)
    from thermal_imu_calib.nodes import input_hints
    monkeypatch.setattr(input_hints, 'SILENT_IMU_AFTER_S', 0.2)
    rig = Rig(ros, calibration_file=str(make_cal().save(tmp_path / 'cal.yaml')),
              diagnostics_period=0.2)
    warned = []
    rig.node._warn_once = lambda key, text: warned.append((key, text))
    other = rig.driver.create_publisher(Imu, '/imu/data', 10)
    wait_for(lambda: '/imu/data' in dict(rig.node.get_topic_names_and_types()), WAIT,
             'the /imu/data publisher on the graph')
    other.publish(imu_msg(rig.stamp, ACCEL, GYRO))
    wait_for(lambda: any(k == 'silent_imu' and '/imu/data ' in t for k, t in warned), WAIT,
             lambda: f'the silent-IMU warning naming /imu/data; got {warned}')
    text = next(t for k, t in warned if k == 'silent_imu')
    assert text.startswith('no IMU message on /imu/data_raw (1 publishers) after 0.2 s; '
                           'sensor_msgs/Imu topics on the graph: /imu/data'), text


def test_imu_input_in_g_or_deg_per_s_is_named_in_a_warning_and_the_diagnostics(ros, tmp_path):
    # a driver publishing g (and, later, a turn in deg/s): every output sample is wrong;
    # the node keeps compensating but says why, once per sensor, and in /diagnostics
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    warned = []
    rig.node._warn_once = lambda key, text: warned.append((key, text))
    rig.temperature(25.0)
    in_g = tuple(v / 9.80665 for v in ACCEL)
    rig.send(ACCEL_WINDOW - 1, accel=in_g)
    rig.receive(ACCEL_WINDOW - 1)
    assert not [k for k, _ in warned if k.startswith('unit_')]   # not yet a window's worth
    rig.send(1, accel=in_g)
    rig.receive(ACCEL_WINDOW)
    texts = dict(warned)
    assert 'its values look in g' in texts['unit_accel'], warned
    assert texts['unit_accel'].endswith('Every output sample is wrong until the driver '
                                        'publishes SI units: compensating anyway')
    st, values = rig.diagnostics()
    assert st.level == common.WARN and st.message.startswith('IMU input not in SI units: '
                                                             'the accelerometer reads')
    assert float(values['accel_median_over_g']) == pytest.approx(
        np.linalg.norm(ACCEL) / 9.80665 ** 2, rel=1e-5)
    rig.send(12, gyro=(0.0, 0.0, 180.0))       # pi rad/s published in deg/s
    rig.receive(ACCEL_WINDOW + 12)
    wait_for(lambda: 'unit_gyro' in dict(warned), WAIT, 'the deg/s warning')
    assert 'the gyro values look in deg/s' in dict(warned)['unit_gyro']
    st, values = rig.diagnostics()
    assert int(values['gyro_deg_per_s_samples']) == 12 and 'deg/s' in st.message
    assert rig.node.counts['compensated'] == ACCEL_WINDOW + 12


def test_imu_input_in_si_units_raises_no_unit_warning(ros, tmp_path):
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(25.0)
    rig.send(ACCEL_WINDOW + 10, gyro=(0.0, 0.0, 20.0))    # a fast spin in rad/s
    rig.receive(ACCEL_WINDOW + 10)
    st, values = rig.diagnostics()
    assert float(values['accel_median_over_g']) == pytest.approx(
        np.linalg.norm(ACCEL) / 9.80665, rel=1e-5)   # diagnostics print 6 digits
    assert int(values['gyro_deg_per_s_samples']) == 0 and 'SI units' not in st.message
    assert not [k for k in rig.node._warned if k.startswith('unit_')]


def _imu_clock_rig(ros, cal, tmp_path, temp_cls, params=()):
    """Return (node, temperature publisher, output, 15 IMU stamps 10 ms apart, imu(rows))
    for the tests of readings put on the IMU's clock; ``imu(rows)`` publishes those rows
    and waits until the node has them."""
    node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal.save(tmp_path / 'cal.yaml'))),
        *params]))
    driver = ros.node('clock_driver')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = (driver.create_publisher(temp_cls, 'imu/temperature', 100)
                if temp_cls is not None else None)      # None: the test publishes it
    out = ros.collect(driver, Imu, 'imu/data_compensated', 1000)
    ros.wait_matched(imu_pub)
    if temp_pub is not None:
        ros.wait_matched(temp_pub)
    wait_for(lambda: node.pub.get_subscription_count() >= 1, WAIT, 'output subscriber')
    stamps = [T0_NS + k * 10_000_000 for k in range(15)]

    def imu(rows):
        for k in rows:
            imu_pub.publish(imu_msg(stamps[k], ACCEL, GYRO))
        wait_for(lambda: node.counts['received'] >= rows[-1] + 1, WAIT, f'{rows[-1] + 1} IMU')
    return node, temp_pub, out, stamps, imu


def _clock_shown(node):
    """Return what /diagnostics says of the one temperature input's clock."""
    (how,) = [v for k, v in node.diagnostics_values()[2].items()
              if k.startswith('temperature_clock[')]
    return how


def _two_readings_on_the_imu_clock(node, cal, out, stamps, imu, publish):
    """After IMU messages 0-4: a reading of 25 degC, IMU 5-9, 35 degC, IMU 10-14. Each
    reading must take the stamp of the IMU message before it and apply from the next."""
    publish(25.0)                  # after IMU 4: waits for the next IMU message
    wait_for(lambda: node._clocks.clock._wait[0], WAIT, 'the reading at the node')
    assert node.temps.received == [0]
    imu(range(5, 10))
    assert node.temps.received == [1]
    assert node.temps.tracks[0].stamps_ns.tolist() == [stamps[4]]
    publish(35.0)
    wait_for(lambda: node._clocks.clock._wait[0], WAIT, 'the second reading at the node')
    imu(range(10, 15))
    assert node.temps.tracks[0].stamps_ns.tolist() == [stamps[4], stamps[9]]
    # wait for the messages checked, not a count: messages before the first reading may
    # come out too, so a count of 10 once let the check run before IMU 14's output arrived
    # (on a 2-core machine running make test next to a Dask fleet bench)
    wanted = {stamps[k] for k in (5, 9, 10, 14)}
    wait_for(lambda: wanted <= {common.stamp_to_ns(m.header.stamp) for m in list(out)},
             WAIT, lambda: f'the compensated messages (got {len(out)})')
    got = {common.stamp_to_ns(m.header.stamp): vec(m) for m in list(out)}
    for k, temp in [(5, 25.0), (9, 25.0), (10, 35.0), (14, 35.0)]:
        exp = expected(cal, temp)
        np.testing.assert_allclose(got[stamps[k]][0], exp.accel[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[stamps[k]][1], exp.gyro[0], rtol=0, atol=1e-12)


def test_a_headerless_float32_temperature_takes_the_stamp_of_the_imu_before_it(ros, tmp_path):
    # the um6/um7 drivers publish the temperature as std_msgs/Float32 on imu/temperature.
    # Each reading is put on the IMU's clock: the stamp of the IMU message published
    # before it (DDS source timestamps), so it applies from the next IMU message on
    from std_msgs.msg import Float32
    cal = make_cal()
    node, temp_pub, out, stamps, imu = _imu_clock_rig(
        ros, cal, tmp_path, Float32, [Parameter('temperature_types',
                                                value=['std_msgs/msg/Float32'])])
    assert _clock_shown(node) == "IMU's clock (no header)"
    imu(range(5))
    _two_readings_on_the_imu_clock(node, cal, out, stamps, imu,
                                   lambda v: temp_pub.publish(Float32(data=v)))
    assert node.counts['temperature_before_imu'] == 0
    temp_pub.publish(Float32(data=40.0))      # the IMU stream has ended: it waits, unused
    wait_for(lambda: node._clocks.clock._wait[0], WAIT, 'the third reading at the node')
    assert node.temps.received == [2]


def test_a_float32_temperature_is_followed_without_temperature_types(ros, tmp_path, request):
    # the same driver, and the node left at its default type (sensor_msgs/Temperature):
    # DDS never connects the two (the node only warned, naming temperature_types, while
    # calibrate read the same topic from a log). It now sees the publisher's type on the
    # graph, subscribes as Float32 and says so; the readings then go on the IMU's clock
    from std_msgs.msg import Float32
    cal = make_cal()
    node, _, out, stamps, imu = _imu_clock_rig(ros, cal, tmp_path, None)
    assert node.type_follower.types == ['sensor_msgs/msg/Temperature']
    temp_pub = other_participant(request, 'um7_driver').create_publisher(
        Float32, '/imu/temperature', 100)
    wait_for(lambda: temp_pub.get_subscription_count() >= 1 and node.type_follower.notes,
             WAIT, lambda: f'the node to subscribe as Float32 ({node.type_follower.notes})')
    assert node.type_follower.types == ['std_msgs/msg/Float32']
    note, = node.type_follower.notes
    assert note.startswith('/imu/temperature is published as std_msgs/msg/Float32 by '
                           '/um7_driver, not sensor_msgs/msg/Temperature: subscribed as '
                           'std_msgs/msg/Float32 (no header: each reading takes the header '
                           'stamp of the IMU message published before it)'), note
    assert "temperature_types:='[std_msgs/msg/Float32]'" in note
    values = node.diagnostics_values()[2]
    assert values['temperature_type[imu/temperature]'] == 'std_msgs/msg/Float32'
    assert _clock_shown(node) == "IMU's clock (no header)"
    imu(range(5))
    _two_readings_on_the_imu_clock(node, cal, out, stamps, imu,
                                   lambda v: temp_pub.publish(Float32(data=v)))


def test_a_temperature_stamped_0_is_put_on_the_imu_clock(ros, tmp_path):
    # a driver that never sets header.stamp: its sensor_msgs/Temperature readings cannot be
    # matched by stamp, so each takes the stamp of the IMU message published before it, as
    # a header-less reading (io.headerless.StampChoice; offline alike). A reading before
    # the first IMU message waits for one to judge its stamp by, and is then left out
    cal = make_cal()
    node, temp_pub, out, stamps, imu = _imu_clock_rig(ros, cal, tmp_path, Temperature)
    temp_pub.publish(temperature_msg(0, 20.0))      # before any IMU message: held
    wait_for(lambda: node._clocks.choices[0].waiting, WAIT, 'the held reading')
    assert node._clocks.choices[0].on_imu_clock is None and node.temps.received == [1]
    imu(range(5))
    assert node._clocks.choices[0].on_imu_clock is True and node._clocks.bare[0]
    assert node.counts['temperature_before_imu'] == 1
    assert _clock_shown(node) == "IMU's clock (header stamps 0 or on another clock)"
    _two_readings_on_the_imu_clock(node, cal, out, stamps, imu,
                                   lambda v: temp_pub.publish(temperature_msg(0, v)))


def test_a_temperature_on_the_imu_clock_keeps_its_stamps(ros, tmp_path):
    # the common case: readings stamped within seconds of the IMU's stamps keep them, those
    # before the first IMU message included, and the node stops tracking publish order
    cal = make_cal()
    rig = Rig(ros, calibration_file=str(cal.save(tmp_path / 'cal.yaml')))
    rig.temperature(24.0, T0_NS - 10 * S)    # a driver started 10 s before the IMU's
    rig.temperature(24.5, T0_NS - S // 2)
    rig.send(1)
    wait_for(lambda: rig.node._clocks.choices[0].on_imu_clock is False, WAIT, 'the choice')
    assert not rig.node._clocks.on and not rig.node._clocks.bare[0]
    assert _clock_shown(rig.node) == 'header stamps'
    assert rig.node.temps.tracks[0].stamps_ns.tolist() == [T0_NS - 10 * S, T0_NS - S // 2]


def test_a_calibration_of_a_followed_topic_waits_for_it_then_is_served_from_it(ros, tmp_path):
    # a calibration made on /imu/temp (calibrator_node followed it, or calibrate picked it
    # from a log) and the compensator with the shipped imu/temperature: refused at start
    # (nothing on the graph yet), it waits; once a driver publishes /imu/temp and nothing
    # is on imu/temperature, the node subscribes /imu/temp and activates it
    # (nodes/topic_follower.InputAdopter)
    cal = make_cal(topics=('/imu/temp',))
    node = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal.save(tmp_path / 'cal.yaml')))]))
    assert node._active is None and node.adopter.waiting is not None
    assert node.last_rejection.endswith("is not among temperature_topics ['imu/temperature']; "
                                        'add it to the parameter or remap it; it is activated '
                                        'once /imu/temp is published while nothing is on '
                                        '/imu/temperature'), node.last_rejection
    driver = ros.node('driver')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = driver.create_publisher(Temperature, '/imu/temp', 100)
    out = ros.collect(driver, Imu, 'imu/data_compensated', 1000)
    wait_for(lambda: node._active is not None and temp_pub.get_subscription_count() >= 1,
             WAIT, lambda: f'the calibration to activate ({node.last_rejection})')
    assert node.temperature_topics == ['/imu/temp'] and node.adopter.waiting is None
    ros.wait_matched(imu_pub)
    wait_for(lambda: node.pub.get_subscription_count() >= 1, WAIT, 'output subscriber')
    temp_pub.publish(temperature_msg(T0_NS, 30.0))
    wait_for(lambda: node.temps.received[0] >= 1, WAIT, 'the reading')
    imu_pub.publish(imu_msg(T0_NS + S // 100, ACCEL, GYRO))
    wait_for(lambda: out, WAIT, 'the compensated message')
    a, w = vec(out[0])
    exp = expected(cal, 30.0)
    np.testing.assert_allclose(a, exp.accel[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(w, exp.gyro[0], rtol=0, atol=1e-12)
    assert not np.allclose(exp.accel[0], ACCEL, atol=1e-3)


def test_a_calibration_of_another_robots_topic_is_not_followed(ros, tmp_path):
    # the same under a namespace: a calibration naming /robot1/imu/temp (another robot's
    # temperature) is not served from that topic by robot2's compensator, even while it is
    # published and nothing is on robot2's own input
    cal = make_cal(topics=('/robot1/imu/temp',))
    node = ros.add(CompensatorNode(context=ros.context, namespace='robot2',
                                   parameter_overrides=[Parameter(
                                       'calibration_file',
                                       value=str(cal.save(tmp_path / 'cal.yaml')))]))
    driver = ros.node('robot1_driver')
    driver.create_publisher(Temperature, '/robot1/imu/temp', 10)
    wait_for(lambda: node.get_publishers_info_by_topic('/robot1/imu/temp'), WAIT, 'the graph')
    assert not node.adopter.adopt('/robot1/imu/temp')
    assert node.temperature_topics == ['imu/temperature'] and node._active is None
    assert node.temp_subs[0].topic_name == '/robot2/imu/temperature'
