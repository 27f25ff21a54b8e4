"""Helpers shared by the nodes: QoS, parameters, message <-> array conversion, diagnostics.

Nothing here computes a calibration or a correction; it only moves data between ROS
messages and the numpy columns the core works on.
"""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import FluidPressure, Illuminance, RelativeHumidity, Temperature
from std_msgs.msg import Float32, Float64

from ..input_units import broadcast_units
from ..io import gate
from ..io.align import TemperatureTrack
from ..io.cdr import SCALAR_MSGTYPES

NS = 1_000_000_000
OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR

# ------------------------------------------------------------------------------------ QoS


def steady_timer(node, period_s, callback, callback_group=None):
    """Return a timer of ``node`` on the steady (wall) clock.

    The nodes' own cadence (processing queued input, progress, /diagnostics) must not
    follow ``use_sim_time``: with sim time and no ``/clock`` publisher (a bag played
    without ``--clock``) a ROS-time timer never fires and the node took in nothing.
    Data are timed by their header stamps, never by these timers.
    """
    return node.create_timer(period_s, callback, callback_group=callback_group,
                             clock=Clock(clock_type=ClockType.STEADY_TIME))


def sensor_qos(depth):
    """Best-effort, volatile, keep-last ``depth``: accepts sensor-data and reliable publishers."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def output_qos(reliability, depth):
    """Output profile: ``reliability`` is 'reliable' or 'best_effort'."""
    rel = (ReliabilityPolicy.RELIABLE if reliability == 'reliable'
           else ReliabilityPolicy.BEST_EFFORT)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth), reliability=rel,
                      durability=DurabilityPolicy.VOLATILE)


#: the calibration topic: latched (a late subscriber gets the last calibration), reliable
CALIBRATION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)

# ----------------------------------------------------------------------------- parameters


class Parameters:
    """Declare parameters with descriptions and ranges; validate choices on change.

    ``apply`` (optional) is called with ``{name: value}`` after a successful runtime change.
    """

    def __init__(self, node, apply=None):
        self.node = node
        self.choices = {}
        self.validators = {}
        self.apply = apply
        node.add_on_set_parameters_callback(self._validate)
        if hasattr(node, 'add_post_set_parameters_callback'):
            node.add_post_set_parameters_callback(self._post_set)

    def declare(self, name, default, description, lo=None, hi=None, choices=None,
                read_only=False, validator=None):
        """Declare ``name`` and return its (validated) value."""
        desc = description
        if choices:
            desc += ' One of: ' + ', '.join(choices) + '.'
            self.choices[name] = tuple(choices)
        d = ParameterDescriptor(description=desc, read_only=read_only)
        if lo is not None and isinstance(default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
        elif lo is not None and isinstance(default, int) and not isinstance(default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        if validator is not None:
            self.validators[name] = validator
        value = self.node.declare_parameter(name, default, d).value
        reason = self._check(name, value)
        if reason:
            raise ValueError(f'parameter {name}: {reason}')
        return value

    def _check(self, name, value):
        if name in self.choices and value not in self.choices[name]:
            return f'{value!r} is not one of {", ".join(self.choices[name])}'
        if name in self.validators:
            return self.validators[name](value)
        return None

    def _validate(self, params):
        for p in params:
            reason = self._check(p.name, p.value)
            if reason:
                return SetParametersResult(successful=False, reason=f'{p.name}: {reason}')
        return SetParametersResult(successful=True)

    def _post_set(self, params):
        if self.apply is not None:
            self.apply({p.name: p.value for p in params})


def log(node, ok, text, failure='error'):
    """Log ``text`` as info when ``ok``, else as ``failure`` ('warning' or 'error').

    rclpy forbids one call site from logging at different severities, hence the branches.
    """
    logger = node.get_logger()
    if ok:
        logger.info(text)
    elif failure == 'warning':
        logger.warning(text)
    else:
        logger.error(text)


# ----------------------------------------------------------------------- message <-> array


def stamp_to_ns(stamp):
    """Return a builtin_interfaces/Time as int nanoseconds."""
    return stamp.sec * NS + stamp.nanosec


def imu_to_arrays(msgs):
    """Return (stamp_ns (n,) int64, accel (n, 3), gyro (n, 3)) of a list of Imu messages."""
    n = len(msgs)
    rows = [(m.header.stamp.sec, m.header.stamp.nanosec,
             m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z,
             m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in msgs]
    a = np.array(rows, dtype=np.float64).reshape(n, 8)
    stamps = np.array([r[0] * NS + r[1] for r in rows], dtype=np.int64)
    return stamps, a[:, 2:5], a[:, 5:8]


def write_imu(msgs, accel, gyro, accel_var=None, gyro_var=None):
    """Overwrite the vectors (and covariance diagonals, when given) of ``msgs`` in place.

    Orientation and header stay as received. A covariance with variances set has zero
    off-diagonal terms.
    """
    al = accel.tolist()
    gl = gyro.tolist()
    acov = _diag9(accel_var)
    gcov = _diag9(gyro_var)
    for i, m in enumerate(msgs):
        v = m.linear_acceleration
        v.x, v.y, v.z = al[i]
        w = m.angular_velocity
        w.x, w.y, w.z = gl[i]
        if acov is not None:
            m.linear_acceleration_covariance = acov[i]
        if gcov is not None:
            m.angular_velocity_covariance = gcov[i]


def _diag9(var):
    if var is None:
        return None
    out = np.zeros((var.shape[0], 9))
    out[:, (0, 4, 8)] = var
    return out


def drain(subscription, limit, node=None, with_info=False):
    """Take up to ``limit`` further waiting messages of ``subscription`` without the executor.

    Called from the subscription's own callback. Processing a burst as one batch keeps the
    per-message executor overhead off the hot path when input queues up; when idle it
    returns nothing and costs one failed take. Only done under a SingleThreadedExecutor:
    taking on a worker thread while a MultiThreadedExecutor waits on the same participant
    loses samples of *other* subscriptions (seen with rclpy 7.1.6 / rmw_fastrtps), so with
    any other executor (or none known, when ``node`` is given) this returns nothing.
    ``with_info``: (message, message info) pairs, the info a dict with the DDS
    ``source_timestamp`` (ns) as a two-argument callback gets it.
    """
    if node is not None and not isinstance(node.executor, SingleThreadedExecutor):
        return []
    out = []
    try:
        handle = subscription.handle
        with handle:
            for _ in range(limit):
                taken = handle.take_message(subscription.msg_type, subscription.raw)
                if taken is None:
                    break
                out.append(taken if with_info else taken[0])
    except Exception:  # noqa: B902 - destroyed handle at shutdown: nothing more to take
        pass
    return out


# ---------------------------------------------------------------------------- temperature


#: header stamps stepping back by more than this (s) start a new timeline
JUMP_S = gate.JUMP_S
#: header-stamped scalars a thermal input may arrive as: type name -> (class, value field)
SCALAR_TYPES = {name: (cls, SCALAR_MSGTYPES[name]) for name, cls in (
    ('sensor_msgs/msg/Temperature', Temperature),
    ('sensor_msgs/msg/FluidPressure', FluidPressure),
    ('sensor_msgs/msg/Illuminance', Illuminance),
    ('sensor_msgs/msg/RelativeHumidity', RelativeHumidity))}
#: header-less scalars a thermal input may arrive as (``io.headerless``): each reading
#: takes the header stamp of the IMU message published before it (DDS source timestamps)
HEADERLESS_TYPES = {'std_msgs/msg/Float32': (Float32, 'data'),
                    'std_msgs/msg/Float64': (Float64, 'data')}
THERMAL_TYPES = {**SCALAR_TYPES, **HEADERLESS_TYPES}


def headerless(cls):
    """Return True for a thermal-input message class without a header (``HEADERLESS_TYPES``)."""
    return any(cls is c for c, _ in HEADERLESS_TYPES.values())


def declare_thermal_inputs(p, topics, description_suffix='', read_only=True):
    """Declare ``temperature_units`` and ``temperature_types`` next to ``temperature_topics``.

    Returns (units, [(message class, value field)]) aligned with ``topics``; a single entry
    applies to every topic. Raises ValueError with what to change.
    """
    units = list(p.declare(
        'temperature_units', ['degC'],
        'Unit of each temperature_topics entry, same order (one entry: all): degC for a '
        'temperature, or a thermal proxy\'s unit such as Hz (a gyro resonance frequency '
        'published in the temperature field). Kelvin/Fahrenheit are refused: publish degC.'
        + description_suffix, read_only=read_only))
    types = list(p.declare(
        'temperature_types', ['sensor_msgs/msg/Temperature'],
        'Message type of each temperature_topics entry (one entry: all): a header-stamped '
        'scalar, one of ' + ', '.join(SCALAR_TYPES) + ', or a header-less '
        + ' or '.join(HEADERLESS_TYPES) + ' (as the um6/um7 drivers publish), whose readings '
        'take the header stamp of the IMU message published before each. The type subscribed '
        'first: an input whose topic is published only as another of these types is '
        're-subscribed as that type once its publisher is seen on the graph (readings '
        'published before are not received).',
        read_only=read_only))
    units = broadcast_units(units, topics)
    if len(types) == 1:
        types = types * len(topics)
    if len(types) != len(topics) or any(t not in THERMAL_TYPES for t in types):
        raise ValueError(f'temperature_types {types} must give one of {list(THERMAL_TYPES)} '
                         f'per temperature_topics entry ({len(topics)}), or one for all')
    return units, [THERMAL_TYPES[t] for t in types]


class TemperatureInputs:
    """One hold/interpolate track per subscribed temperature topic (header stamps)."""

    def __init__(self, topics, history_s=60.0):
        self.topics = list(topics)
        self.tracks = [TemperatureTrack(history_s) for _ in self.topics]
        self.received = [0] * len(self.topics)
        self.invalid = 0
        self.time_resets = 0

    def check_time(self, stamp_ns):
        """Forget all readings when header stamps jumped back by more than ``JUMP_S``.

        A replayed bag restarting, a second recording or a reset clock must not be
        compensated with temperatures from the other timeline. Returns True on a reset.
        """
        newest = [tr.newest_ns for tr in self.tracks if tr.newest_ns is not None]
        if newest and stamp_ns < max(newest) - int(JUMP_S * NS):
            for tr in self.tracks:
                tr.clear()
            self.time_resets += 1
            return True
        return False

    def add(self, index, stamp_ns, value):
        """Add one reading; non-finite readings are counted and ignored."""
        if not math.isfinite(value):
            self.invalid += 1
            return
        self.check_time(stamp_ns)
        self.received[index] += 1
        self.tracks[index].add(stamp_ns, value)

    def resolve(self, stamps_ns, columns, max_gap_s):
        """Return (temps (n, k), age_s (n, k)) of the given track columns at IMU stamps."""
        n, k = len(stamps_ns), len(columns)
        temps = np.empty((n, k))
        age = np.empty((n, k))
        for j, c in enumerate(columns):
            temps[:, j], age[:, j] = self.tracks[c].interpolate(stamps_ns, max_gap_s)
        return temps, age

    def age_at(self, stamp_ns):
        """Return {topic: seconds since the newest reading} at a stamp (inf if none)."""
        out = {}
        for topic, tr in zip(self.topics, self.tracks):
            newest = tr.newest_ns
            out[topic] = math.inf if newest is None else (stamp_ns - newest) / NS
        return out


def match_topics(node, wanted, available):
    """Map calibration input topics to indices in ``available`` (the subscribed names).

    Names are compared as written, then with a leading '/' removed, then fully resolved
    in the node's namespace, so relative names keep working under namespaces and
    remapping. Returns (indices, None) or (None, reason).
    """
    def variants(name):
        out = {name, name.lstrip('/')}
        try:
            out.add(node.resolve_topic_name(name))
        except Exception:  # noqa: B902 - an invalid name simply does not match
            pass
        return out

    avail = [variants(a) for a in available]
    idx = []
    for w in wanted:
        wv = variants(w)
        hits = [i for i, av in enumerate(avail) if wv & av]
        if not hits:
            return None, (f'temperature input topic {w!r} is not among temperature_topics '
                          f'{list(available)}; add it to the parameter or remap it')
        idx.append(hits[0])
    return idx, None


# ----------------------------------------------------------------------------- diagnostics


class RateMeter:
    """Count events and report the rate since the last report."""

    def __init__(self):
        self.total = 0
        self._last_total = 0
        self._last_t = time.monotonic()

    def add(self, n=1):
        """Count ``n`` events."""
        self.total += n

    def rate(self):
        """Return events per second since the previous call."""
        now = time.monotonic()
        dt = max(now - self._last_t, 1e-9)
        r = (self.total - self._last_total) / dt
        self._last_total, self._last_t = self.total, now
        return r


def diagnostic_status(name, hardware_id, level, message, values):
    """Build a DiagnosticStatus from a dict of values (formatted as strings)."""
    st = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id)
    st.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
    return st


def _fmt(v):
    if isinstance(v, float):
        return 'inf' if math.isinf(v) else f'{v:.6g}'
    if isinstance(v, bool):
        return 'true' if v else 'false'
    return str(v)


class Diagnostics:
    """Publish DiagnosticArray on /diagnostics (diagnostic_updater's topic and QoS)."""

    def __init__(self, node):
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)

    def publish(self, statuses):
        """Publish the given DiagnosticStatus list, stamped now."""
        arr = DiagnosticArray()
        arr.header.stamp = self.node.get_clock().now().to_msg()
        arr.status = list(statuses)
        self.pub.publish(arr)


def topic_list(value):
    """Return a topic-list parameter as a list: [] (read as unset) and '' entries are none.

    ROS 2 cannot type an empty array, so ``temperature_topics: []`` arrives unset and the
    launch file passes ``['']`` for it; both mean no thermal input.
    """
    return [t for t in (value or []) if t]
