"""Topic selection in a log: which topic is the IMU, which are temperatures.

Shared by the offline pipelines and lab mode; raises LogError naming the
topics present.
"""

from .log_info import LogError
from .cdr import IMU_MSGTYPE, SCALAR_MSGTYPES, TEMPERATURE_MSGTYPE


def resolve_topics(reader, imu_topic, temperature_topics):
    """Check the IMU topic and pick temperature topics (all Temperature topics when None).

    Named thermal-input topics may be any header-stamped scalar of ``SCALAR_MSGTYPES``
    (e.g. a proxy on sensor_msgs/Temperature or FluidPressure). Returns the temperature
    topic list; raises LogError naming the topics present.
    """
    types = reader.topic_types()
    if imu_topic is None:
        imus = [t for t, ty in types.items() if ty == IMU_MSGTYPE]
        if len(imus) > 1:
            raise LogError(f'{reader.path}: pass --imu-topic; Imu topics present: '
                           f'{", ".join(imus)}')
        if not imus:
            alike = [f'{t} [{ty}]' for t, ty in types.items() if ty.endswith('Imu')]
            raise LogError(f'{reader.path}: no {IMU_MSGTYPE} topic' + (
                f'; {", ".join(alike)} carries another schema name (a ROS 1 or renamed type): '
                'convert the log to ROS 2 types (e.g. rosbags-convert)' if alike else
                f'; topics present: {reader._describe_topics()}; pass --imu-topic naming '
                'the IMU topic'))
        imu_topic = imus[0]
    imu_topic = in_log(types, imu_topic)
    reader.check_topics([imu_topic], IMU_MSGTYPE)
    if temperature_topics is None:
        temperature_topics = sorted(t for t, ty in types.items() if ty == TEMPERATURE_MSGTYPE)
    else:
        temperature_topics = [in_log(types, t) for t in temperature_topics]
        reader.check_topics(temperature_topics, SCALAR_MSGTYPES)
    return imu_topic, list(temperature_topics)


def in_log(types, name):
    """Return the log's topic for ``name``: itself, else the resolved form of a relative name.

    A node's parameters name topics relative to its namespace (``imu/temperature``, as
    the shipped config and the calibration files ``calibrator_node`` writes do), and
    ``ros2 bag record`` stores them resolved: ``/imu/temperature`` in the root namespace,
    ``/robot1/imu/temperature`` under a namespace. A relative name is found as ``/name``,
    else as the one topic ending in ``/name``. ``types`` maps the log's topics to their
    types; a name not found (or found under several namespaces) is returned as given, and
    the caller's check names the topics present.
    """
    if name in types or not name or name.startswith('/'):
        return name
    if '/' + name in types:
        return '/' + name
    under = [t for t in types if t.endswith('/' + name)]
    return under[0] if len(under) == 1 else name
