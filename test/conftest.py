"""Shared ROS 2 fixtures: an isolated rclpy Context per test, a background executor, waits.

Isolation: every test gets its own rclpy ``Context`` on one ROS domain per test run (the
``ROS_DOMAIN_ID`` from the environment, e.g. set by ``make test``, else 1 + pid % 101, or
the next with no DDS participant on this host; under pytest-xdist one domain per worker,
see ``WORKER``), with discovery limited to localhost; the context is shut down after the
test, so no node of one test ever sees another's. Subprocesses started by tests inherit
the same domain.
"""

import atexit
import contextlib
import os
import shutil
import sys
import tempfile
import threading
import time
import traceback

import numpy as np
import pytest

from thermal_imu_calib.nodes.player import (imu_msg, Pacer, replay,  # noqa: F401
                                            temperature_msg)

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                'bench'))
import dds_domain  # noqa: E402

#: the pytest-xdist worker running this process ('gw0', 'gw1', ...; '' without -n)
WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
if WORKER:
    # ``make test`` runs two workers at once (``-n 2``). Each has a ROS domain of its own
    # and a temporary folder of its own, so the nodes of two tests running at the same time
    # never see each other and a test that looks at what is in the temporary folder sees
    # only its own worker's files. Subprocesses inherit both from the environment.
    _tmp = tempfile.mkdtemp(prefix=f'thermal-imu-test-{WORKER}-')
    os.environ['TMPDIR'] = tempfile.tempdir = _tmp
    atexit.register(shutil.rmtree, _tmp, True)
# The domain: the run's (ROS_DOMAIN_ID, e.g. from ``make test``; else 1 + the pid % 101, the
# parent's under xdist), or the first after it with no DDS participant on this host: worker
# k of n takes base + k, base + k + n, ... (``dds_domain.worker_domains``; without xdist
# k = 0, n = 1).
# A domain shared with another process's participants can hold ids 0..31 that
# rmw_fastrtps's localhost discovery needs (``dds_domain``: in CI on 2026-12-03 two live
# tests never matched their node), and its nodes would share the tests' topics.
_base = int(os.environ.get('ROS_DOMAIN_ID',
                           1 + (os.getppid() if WORKER else os.getpid()) % 101))
_k = int(WORKER.lstrip('gw') or 0) if WORKER else 0
_n = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', 1)) if WORKER else 1
_mine = dds_domain.worker_domains(_base, _k, _n)
os.environ['ROS_DOMAIN_ID'] = str(dds_domain.free_domain(_mine) or _mine[0])
DOMAIN_ID = int(os.environ['ROS_DOMAIN_ID'])
#: this worker's other domains: a live run moves to a free one when DOMAIN_ID fills up
#: (``live_replay.usable_domain``)
SPARE_DOMAINS = [d for d in _mine if d != DOMAIN_ID]


BIN = os.path.dirname(sys.executable)


def venv_exe(name):
    """Return the path of console script ``name`` installed next to the running interpreter.

    Tests run as ``.venv/bin/python -m pytest`` need not have the venv on PATH; a missing
    script is a failed install, so this fails rather than skips.
    """
    path = os.path.join(BIN, name)
    if not os.access(path, os.X_OK):
        pytest.fail(f'{name} is not installed next to {sys.executable} (run make install)')
    return path


def venv_env(**extra):
    """Return os.environ with the interpreter's bin directory first on PATH, plus ``extra``."""
    env = dict(os.environ, PATH=BIN + os.pathsep + os.environ.get('PATH', ''))
    env.update({k: str(v) for k, v in extra.items()})
    return env


def wait_for(predicate, timeout, what, poll=0.01):
    """Poll ``predicate`` until it is truthy; fail with ``what`` after ``timeout`` seconds.

    ``what`` may be a callable, evaluated at failure time (to show the state reached).
    """
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f'timed out after {timeout:.1f} s waiting for '
                        f'{what() if callable(what) else what}')
        time.sleep(poll)


def wait_count(count, target, what, stall=60.0, settle=5.0, loss=0.01):
    """Wait until ``count()`` reaches ``target``; return the count reached.

    Bounded by progress, not by a total time: it fails only when the count has not grown
    for ``stall`` seconds (a loaded machine is slow, a broken path does not move). The
    inputs of the nodes are best effort, which promises no delivery: once the count has
    stood still for ``settle`` seconds at ``(1 - loss) * target`` or more, that is accepted
    (the callers then assert what came through, not that everything did).
    """
    last, moved = count(), time.monotonic()
    while True:
        now = count()
        if now >= target:
            return now
        t = time.monotonic()
        if now != last:
            last, moved = now, t
        elif t - moved > settle and now >= (1.0 - loss) * target:
            return now
        elif t - moved > stall:
            pytest.fail(f'{what() if callable(what) else what}: stuck at {now} of {target} '
                        f'for {stall:.0f} s')
        time.sleep(0.01)


def replay_flow(imu_pub, imu, temperatures, rate, delivered, window=500, what='delivery',
                readings=None):
    """Replay like ``replay`` with back-pressure: at most ``window`` IMU messages in flight.

    The IMU columns are published in chunks of ``window // 2`` at ``rate``; before each
    chunk, ``delivered()`` (the receiver's count of IMU messages, cumulative over this
    call) must have caught up to within one chunk of what was sent. ``window`` stays below
    the subscribers' queue depth (1000), so a slow (loaded) receiver slows the replay
    instead of losing messages. Returns the number of IMU messages published.

    ``readings`` (optional): the receiver's cumulative count of temperature readings. Each
    chunk's readings are then published first and must all have arrived before its IMU
    messages are published, so every sample finds the reading of its own stamp (merged in
    stamp order, a sample's same-stamp reading follows it over another topic, and under
    load may arrive after the sample was processed). A lost reading fails the replay.
    """
    chunk = max(window // 2, 1)
    base = delivered()
    base_readings = readings() if readings else 0
    n = len(imu.stamp_ns)
    sent = sent_readings = 0
    for i0 in range(0, n, chunk):
        i1 = min(i0 + chunk, n)
        lo = -np.inf if i0 == 0 else imu.stamp_ns[i0]
        hi = np.inf if i1 == n else imu.stamp_ns[i1]
        temps = []
        for pub, stamps, values in temperatures:
            stamps, values = np.asarray(stamps), np.asarray(values)
            m = (stamps >= lo) & (stamps < hi)
            temps.append((pub, stamps[m], values[m]))
        if sent:
            wait_count(lambda: delivered() - base, sent - chunk, what)
        if readings:
            sent_readings += replay_readings(temps)
            wait_count(lambda: readings() - base_readings, sent_readings,
                       f'{what} (temperature readings)', loss=0.0)
            temps = []
        sent += replay(imu_pub, imu.slice(slice(i0, i1)), temps, rate)
    return sent


def replay_readings(temperatures):
    """Publish (publisher, stamp_ns, values) series in stamp order; return how many."""
    events = sorted((int(s), j, i) for j, (_, stamps, _) in enumerate(temperatures)
                    for i, s in enumerate(stamps))
    for stamp, j, i in events:
        pub, _, values = temperatures[j]
        pub.publish(temperature_msg(stamp, values[i]))
    return len(events)


class RosHarness:
    """Nodes of one test in one context, spun by a SingleThreadedExecutor in a thread.

    Single-threaded like the nodes' own mains: it is the executor they are built for.
    """

    def __init__(self, context):
        from rclpy.executors import SingleThreadedExecutor
        self.context = context
        self.executor = SingleThreadedExecutor(context=context)
        self.nodes = []
        self.errors = []
        # held around each spin_once: a node is removed and destroyed between two spins,
        # never while one of its callbacks runs (InvalidHandle otherwise)
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        while self.context.ok():
            try:
                with self._lock:
                    self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                break
            except Exception as e:  # noqa: B902 - a callback raised: keep it for the test
                if not self.context.ok():
                    break
                self.errors.append(e)
                traceback.print_exc()

    def paused(self):
        """Return the lock held around each spin: ``with ros.paused():`` runs between spins.

        No callback of any harness node runs inside it, and messages queue up meanwhile.
        """
        return self._lock

    def add(self, node):
        """Spin ``node`` (created with ``context=self.context``) and return it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name):
        """Create, spin and return a plain helper node."""
        from rclpy.node import Node
        return self.add(Node(name, context=self.context))

    def remove(self, node):
        """Stop spinning ``node`` and destroy it."""
        with self._lock:
            self.executor.remove_node(node)
            self.nodes.remove(node)
            node.destroy_node()

    def collect(self, node, msg_type, topic, qos=10):
        """Subscribe and return the list every received message is appended to."""
        got = []
        node.create_subscription(msg_type, topic, got.append, qos)
        return got

    def call(self, node, srv_type, name, request=None, timeout=30.0):
        """Call a service (waiting for it to appear) and return the response."""
        client = node.create_client(srv_type, name)
        wait_for(lambda: client.service_is_ready(), timeout, f'service {name}')
        future = client.call_async(request if request is not None else srv_type.Request())
        wait_for(future.done, timeout, f'the response of {name}')
        with self._lock:        # the client is in the executor's wait set: between spins
            node.destroy_client(client)
        return future.result()

    def wait_matched(self, publisher, count=1, timeout=10.0):
        """Wait until ``publisher`` has ``count`` subscriptions matched."""
        wait_for(lambda: publisher.get_subscription_count() >= count, timeout,
                 f'{count} subscriber(s) on {publisher.topic_name}')

    def shutdown(self):
        with self._lock:
            for node in list(self.nodes):
                try:
                    self.executor.remove_node(node)
                    node.destroy_node()
                except Exception:  # noqa: B902 - best effort at teardown
                    pass
            self.context.try_shutdown()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=1.0)


@contextlib.contextmanager
def participant(name):
    """Yield a node ``name`` on the test domain in a context of its own; destroy it after.

    Another participant, as a driver's process is (one participant refuses a second type
    on a topic it has). Nothing spins it: discovery is answered by DDS's own threads. The
    node is destroyed, not only its context shut down: a shut-down context keeps its
    participant, and its publishers stayed on the graph until the garbage collector ran, so
    a later test's node on the same domain saw them (a Float32 driver left on
    /imu/temperature made the next test's node switch type and never match its player;
    found 2026-12-03 with live_replay's driver).
    """
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    try:
        node = rclpy.create_node(name, context=context)
        try:
            yield node
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


def other_participant(request, name):
    """Return ``participant(name)``'s node, destroyed after the test."""
    stack = contextlib.ExitStack()
    request.addfinalizer(stack.close)
    return stack.enter_context(participant(name))


@pytest.fixture
def ros_domain_id():
    """Return the ROS domain id of this test run."""
    return DOMAIN_ID


@pytest.fixture
def ros():
    """Yield a RosHarness on a fresh rclpy Context; everything is shut down afterwards."""
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    harness = RosHarness(context)
    try:
        yield harness
    finally:
        harness.shutdown()
    assert not harness.errors, f'callbacks raised: {harness.errors!r}'


@pytest.fixture
def pacer():
    """Return the Pacer class."""
    return Pacer


@pytest.fixture(scope='module')
def month_windows():
    """Return (RobotMonth of 1.5 days, seed 3, the windows the detector gives on its stops).

    The lifelong tests' loop fixture (``test_lifelong._truth_active_on_20_holds``).
    """
    from _robot_month import detector_windows
    from thermal_imu_calib.sim.robot_month import robot_month
    m = robot_month(3, days=1.5)
    return m, detector_windows(m)


def calibrate_compensate_rig(ros, tmp_path, gravity, temperature_topic='imu/temperature'):
    """Start calibrator_node and compensator_node on one calibration file, and a player.

    Returns (calibrator, compensator, driver, imu_pub, temp_pub, out): the player node,
    its publishers on ``imu/data_raw`` and ``temperature_topic`` matched by both nodes, and
    the list every
    ``imu/data_compensated`` message is appended to (drained in batches).
    """
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Imu, Temperature
    from thermal_imu_calib.nodes import common
    from thermal_imu_calib.nodes.calibrator import CalibratorNode
    from thermal_imu_calib.nodes.compensator import CompensatorNode
    cal_file = tmp_path / 'calibration.yaml'
    calibrator = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal_file)),
        Parameter('collection_file', value=str(tmp_path / 'collection.jsonl')),
        Parameter('gravity', value=float(gravity))]))
    compensator = ros.add(CompensatorNode(context=ros.context, parameter_overrides=[
        Parameter('calibration_file', value=str(cal_file))]))
    driver = ros.node('player')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = driver.create_publisher(Temperature, temperature_topic, 100)
    out = []
    sub = driver.create_subscription(Imu, 'imu/data_compensated',
                                     lambda m: out.extend([m] + common.drain(sub, 999, driver)),
                                     10000)
    ros.wait_matched(imu_pub, 2)
    ros.wait_matched(temp_pub, 2)
    wait_for(lambda: compensator.pub.get_subscription_count() >= 1, 10, 'output subscriber')
    return calibrator, compensator, driver, imu_pub, temp_pub, out
