"""Follow a thermal input's message type on the ROS graph, as ``calibrate`` reads it from a log.

DDS connects a subscription only to publishers of its own type. A driver publishing its
temperature as ``std_msgs/Float32`` (the um6/um7 drivers) on the topic a node subscribes
as ``sensor_msgs/Temperature`` was never received: the node warned and named the
``temperature_types`` value to set, while ``calibrate`` read the same topic from a log of
that driver as it was recorded. Now a node re-subscribes such an input as the type its
topic is published as, when every publisher of it on the graph uses one other thermal
type (``common.THERMAL_TYPES``), and says so once. Readings published before that are
not received; ``temperature_types`` still sets the type subscribed from the start.
"""

import time

from . import common

#: seconds (steady clock) between looks at the graph for inputs without a publisher
FOLLOW_PERIOD_S = 0.2


def type_name(cls):
    """Return 'pkg/msg/Name' of a message class (e.g. 'sensor_msgs/msg/Temperature')."""
    return f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'


def type_to_follow(node, subscription):
    """Return (type name, publishers) of a topic published as one other thermal type.

    ('', []) unless every publisher of the subscription's topic uses one thermal type
    (``common.THERMAL_TYPES``) other than the subscription's, and the subscription has no
    matched publisher. The graph is a hint only: an error reading it gives ('', []).
    """
    try:
        if subscription.get_publisher_count():
            return '', []
        infos = node.get_publishers_info_by_topic(subscription.topic_name)
    except Exception:  # noqa: B902 - the graph is only a hint
        return '', []
    types = {i.topic_type for i in infos}
    if len(types) != 1 or type_name(subscription.msg_type) in types:
        return '', []
    typ, = types
    if typ not in common.THERMAL_TYPES:
        return '', []
    return typ, sorted({i.node_namespace.rstrip('/') + '/' + i.node_name for i in infos})


class TypeFollower:
    """Look at the graph now and then for thermal inputs published as another type.

    ``resubscribe(index, type name)`` is the node's: it replaces ``subscriptions[index]``
    (and whatever depends on the type); when it raises, the input must be left subscribed
    as before, and that type is not tried again. ``types``: the type name subscribed per input,
    updated here (for /diagnostics).
    """

    def __init__(self, node, subscriptions, resubscribe, period_s=FOLLOW_PERIOD_S):
        self.node = node
        self.subscriptions = subscriptions      # the node's list, replaced entries seen
        self.resubscribe = resubscribe
        self.types = [type_name(s.msg_type) for s in subscriptions]
        self.period_s = float(period_s)
        self.notes = []                         # what was followed, as logged
        self._failed = set()                    # (input, type) that could not be subscribed
        self._next = 0.0

    def __call__(self, now=None):
        """Re-subscribe the inputs to follow (at most once per period); return their notes."""
        now = time.monotonic() if now is None else now
        if now < self._next:
            return []
        self._next = now + self.period_s
        notes = []
        for i, sub in enumerate(list(self.subscriptions)):
            typ, by = type_to_follow(self.node, sub)
            if not typ:
                continue
            topic = sub.topic_name         # before the subscription is destroyed
            old = self.types[i]
            if (i, typ) in self._failed:
                continue
            try:
                self.resubscribe(i, typ)
            except Exception as e:  # noqa: B902 - the node keeps its input as it was
                self._failed.add((i, typ))
                self.node.get_logger().warning(
                    f'{topic} is published as {typ}, but subscribing as that type '
                    f'failed ({e}); still subscribed as {old}')
                continue
            self.types[i] = typ
            bare = (' (no header: each reading takes the header stamp of the IMU message '
                    'published before it)' if typ in common.HEADERLESS_TYPES else '')
            notes.append(f'{topic} is published as {typ} by {", ".join(by)}, not '
                         f'{old}: subscribed as {typ}{bare}, as calibrate reads such a topic '
                         'from a log; readings published before now were not received (set '
                         f"temperature_types:='[{typ}]' to subscribe so from the start)")
        for note in notes:
            self.node.get_logger().warning(note)
        self.notes += notes
        return notes

    def describe(self):
        """Return {topic: the type subscribed} (for /diagnostics)."""
        return {s.topic_name: t for s, t in zip(self.subscriptions, self.types)}


def resubscribe(node, subscriptions, index, typ, subscribe):
    """Destroy ``subscriptions[index]``, then ``subscribe(typ)`` (the node's: it sets the entry).

    The old one goes first: DDS refuses a second type on a topic in one participant. When
    ``subscribe(typ)`` fails, ``subscribe`` runs again with the old type and the error is
    raised.
    """
    old = type_name(subscriptions[index].msg_type)
    node.destroy_subscription(subscriptions[index])
    try:
        subscribe(typ)
    except Exception:
        subscribe(old)
        raise
