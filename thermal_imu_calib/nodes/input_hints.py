"""What a node says when an input never arrives: the topic to set, found on the ROS graph.

A driver that publishes ``imu/temp`` or ``imu/data`` while the node listens on
``imu/temperature`` or ``imu/data_raw`` otherwise shows only as "no stationary segments
were found" (the calibrator) or uncompensated output (the compensator). These helpers
name the silent subscription, its publishers and the topics of the right type on the
graph. The graph is a hint only: an error reading it gives no hint, never a failure.
"""

import time

from . import common
from .thermal_types import type_name


def thermal_topics_hint(node, subscriptions):
    """Return '; thermal-input topics on the graph: ... (set ...)' for a silent input, or ''.

    Names the topics of a ``common.SCALAR_TYPES`` type that ``node`` does not subscribe to
    (``subscriptions``: its temperature subscriptions), and those of a header-less type
    (``common.HEADERLESS_TYPES``) named 'temp...': a driver publishing ``imu/temp`` when
    the node listens on ``imu/temperature`` is found this way. The graph is a hint only; an
    error reading it gives ''.
    """
    ours = {s.topic_name for s in subscriptions}

    def thermal(topic, types):
        return [ty for ty in types if ty in common.SCALAR_TYPES or (
            ty in common.HEADERLESS_TYPES
            and topic.rsplit('/', 1)[-1].lower().startswith('temp'))]
    try:
        seen = sorted((t, thermal(t, types)[0]) for t, types in node.get_topic_names_and_types()
                      if t not in ours and thermal(t, types))
    except Exception:  # noqa: B902 - the graph is only a hint
        return ''
    if not seen:
        return ''
    topic, typ = seen[0]
    kind = (f" temperature_types:='[{typ}]'" if typ != 'sensor_msgs/msg/Temperature'
            else '')
    return (f'; thermal-input topics on the graph: {", ".join(t for t, _ in seen)} (set '
            f"temperature_topics:='[{topic}]'{kind})")


def wrong_type_hint(node, subscriptions):
    """Return '; /imu/temperature is published as std_msgs/msg/Float32 (by ...) ...', or ''.

    A publisher of another message type on a topic the node subscribes to never connects
    (DDS matches types), so its messages are silently not received; the publisher shows on
    the graph only. Says which type and node, and what to do: another scalar type the node
    reads (``common.THERMAL_TYPES``, std_msgs/Float32 and Float64 included) is set with
    ``temperature_types``. The graph is a hint only; an error reading it gives ''.
    """
    out = []
    try:
        for sub in subscriptions:
            ours = type_name(sub.msg_type)
            others = sorted({(i.topic_type, (i.node_namespace.rstrip('/') + '/' + i.node_name))
                             for i in node.get_publishers_info_by_topic(sub.topic_name)
                             if i.topic_type != ours})
            for typ, by in others:
                if typ in common.THERMAL_TYPES:
                    todo = f"set temperature_types:='[{typ}]'"
                else:
                    todo = f'publish {ours} on it'
                out.append(f'; {sub.topic_name} is published as {typ} by {by}, not {ours}, '
                           f'so none of it is received: {todo}')
    except Exception:  # noqa: B902 - the graph is only a hint
        return ''
    return ''.join(out)


def imu_topics_hint(node, subscription):
    """Return '; sensor_msgs/Imu topics on the graph: ... (set imu_topic:=...)', or ''."""
    def from_a_driver(topic):     # not only a compensator's output (imu/data_compensated)
        return any(not i.node_name.startswith('thermal_imu_compensator')
                   for i in node.get_publishers_info_by_topic(topic))
    try:
        seen = sorted(t for t, types in node.get_topic_names_and_types()
                      if t != subscription.topic_name and 'sensor_msgs/msg/Imu' in types
                      and from_a_driver(t))
    except Exception:  # noqa: B902 - the graph is only a hint
        return ''
    return (f'; sensor_msgs/Imu topics on the graph: {", ".join(seen)} (remap: '
            f'ros2 launch ... imu_topic:={seen[0]})' if seen else '')


def collection_problem(node):
    """Return why no IMU sample is collected: no IMU input, or no temperature ('' if not).

    Said first when ``~/calibrate`` is refused and logged once while collecting: a
    driver publishing under another name (``imu/data``, ``imu/temp``) otherwise reads as
    "no stationary segments were found". Names the topics of the right type on the
    graph that this node does not subscribe to, and what to set.
    """
    received, samples = node._rate.total, node.counts['samples']
    stale = node.counts['stale_temperature']
    if not received:
        return (f'no IMU message arrived on {node.imu_sub.topic_name} '
                f'({node.imu_sub.get_publisher_count()} publishers)'
                + wrong_type_hint(node, [node.imu_sub]) + imu_topics_hint(node, node.imu_sub))
    if not node.k or not stale or stale < samples:
        return ''
    silent = [i for i, n in enumerate(node.readings_per_topic) if n == 0]
    hint = (wrong_type_hint(node, [node.temp_subs[i] for i in silent])
            + thermal_topics_hint(node, node.temp_subs))
    if silent:
        names = ', '.join(f'{node.temp_subs[i].topic_name} '
                          f'({node.temp_subs[i].get_publisher_count()} publishers)'
                          for i in silent)
        return (f'no temperature reading arrived on {names} while {received} IMU '
                f'messages did, so no IMU sample was collected{hint}; or set '
                "temperature_topics:='[]' to calibrate without a temperature")
    return (f'{stale} IMU samples had no temperature reading within temperature_timeout '
            f'({node.temperature_timeout:g} s of header stamps) and {samples} had one, so '
            'most were not collected: the IMU and temperature header stamps must share a '
            'clock, and the temperature must be published at least every '
            f'{node.temperature_timeout:g} s (or raise temperature_timeout)')


#: seconds (steady clock) after the start with no IMU message before a node says why
SILENT_IMU_AFTER_S = 10.0


def silent_imu(node, started, received):
    """Return a warning when no IMU message came ``SILENT_IMU_AFTER_S`` after ``started``.

    ``started``: ``time.monotonic()`` at the node's start; ``received``: IMU messages so
    far. '' while messages come (or before the delay): the caller logs the text once.
    """
    if received or time.monotonic() - started < SILENT_IMU_AFTER_S:
        return ''
    return (f'no IMU message on {node.imu_sub.topic_name} '
            f'({node.imu_sub.get_publisher_count()} publishers) after '
            f'{SILENT_IMU_AFTER_S:g} s' + wrong_type_hint(node, [node.imu_sub])
            + imu_topics_hint(node, node.imu_sub))
