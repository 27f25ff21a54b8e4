"""Shared ROS 2 fixtures: an isolated rclpy Context per test, a background executor, waits.

Isolation: every test gets its own rclpy ``Context`` on one ROS domain per test run (the
``ROS_DOMAIN_ID`` from the environment, e.g. set by ``make test``, else 1 + pid % 101),
with discovery limited to localhost; the context is shut down after the test, so no node
of one test ever sees another's. Subprocesses started by tests inherit the same domain.
"""

import math
import os
import threading
import time
import traceback

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))
DOMAIN_ID = int(os.environ['ROS_DOMAIN_ID'])


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
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                break
            except Exception as e:  # noqa: B902 - a callback raised: keep it for the test
                if not self.context.ok():
                    break
                self.errors.append(e)
                traceback.print_exc()

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
        node.destroy_client(client)
        return future.result()

    def wait_matched(self, publisher, count=1, timeout=10.0):
        """Wait until ``publisher`` has ``count`` subscriptions matched."""
        wait_for(lambda: publisher.get_subscription_count() >= count, timeout,
                 f'{count} subscriber(s) on {publisher.topic_name}')

    def shutdown(self):
        for node in list(self.nodes):
            try:
                self.executor.remove_node(node)
                node.destroy_node()
            except Exception:  # noqa: B902 - best effort at teardown
                pass
        self.context.try_shutdown()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=1.0)


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


class Pacer:
    """Sleep so that event i happens at ``start + i / rate`` (evenly paced replay)."""

    def __init__(self, rate):
        self.period = 1.0 / rate if rate and math.isfinite(rate) else 0.0
        self.start = time.perf_counter()

    def wait(self, i):
        """Block until event ``i`` is due (returns at once when behind schedule)."""
        if not self.period:
            return
        delay = self.start + i * self.period - time.perf_counter()
        if delay > 0.0005:
            time.sleep(delay)


@pytest.fixture
def pacer():
    """Return the Pacer class."""
    return Pacer


def imu_msg(stamp_ns, accel, gyro, frame_id='imu_link'):
    """Build a sensor_msgs/Imu with unknown orientation (orientation_covariance[0] = -1)."""
    from sensor_msgs.msg import Imu
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    m.header.frame_id = frame_id
    m.orientation_covariance[0] = -1.0
    v, w = m.linear_acceleration, m.angular_velocity
    v.x, v.y, v.z = (float(x) for x in accel)
    w.x, w.y, w.z = (float(x) for x in gyro)
    return m


def temperature_msg(stamp_ns, value, frame_id='imu_link'):
    """Build a sensor_msgs/Temperature."""
    from sensor_msgs.msg import Temperature
    m = Temperature()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    m.header.frame_id = frame_id
    m.temperature = float(value)
    return m


def replay(imu_pub, imu, temperatures=(), rate=None, frame_id='imu_link'):
    """Publish IMU columns and temperature series merged in stamp order, evenly paced.

    ``imu`` has ``stamp_ns``, ``accel``, ``gyro``; ``temperatures`` is a sequence of
    (publisher, stamp_ns, values). ``rate`` is IMU messages per second (None: as fast as
    possible). Returns the number of IMU messages published.
    """
    events = [(int(s), 0, i) for i, s in enumerate(imu.stamp_ns)]
    for j, (_, stamps, _) in enumerate(temperatures):
        events += [(int(s), j + 1, i) for i, s in enumerate(stamps)]
    events.sort()
    accel, gyro = imu.accel.tolist(), imu.gyro.tolist()
    pace = Pacer(rate)
    count = 0
    for stamp, kind, i in events:
        if kind == 0:
            pace.wait(count)
            imu_pub.publish(imu_msg(stamp, accel[i], gyro[i], frame_id))
            count += 1
        else:
            pub, _, values = temperatures[kind - 1]
            pub.publish(temperature_msg(stamp, values[i], frame_id))
    return count
