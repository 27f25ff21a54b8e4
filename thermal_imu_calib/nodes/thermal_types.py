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
import weakref

from . import common

#: seconds (steady clock) between looks at the graph for inputs without a publisher
FOLLOW_PERIOD_S = 0.2
#: the name the graph gives a publisher whose node it has not discovered yet (rmw)
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'
#: seconds (steady clock) a switch waits for the publishers' node names, to name them
NAME_WAIT_S = 1.0


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
    return typ, sorted({i.node_namespace.rstrip('/') + '/' + i.node_name
                        if i.node_name != UNKNOWN_NODE else UNKNOWN_NODE for i in infos})


class TypeFollower:
    """Look at the graph now and then for thermal inputs published as another type.

    ``subscribe(index, type name)`` is the node's: it creates ``subscriptions[index]`` as
    that type (and sets whatever depends on the type); the follower has destroyed the old
    one first. DDS refuses a second type on a topic in one participant, so every
    follower's input on that topic in the same context (``bringup``: the calibrator and
    the compensator in one process) is switched at once: all old subscriptions destroyed,
    then all new ones made. When one cannot be made, all go back to the old type, and
    that type is not tried again. ``types``: the type subscribed per input (for
    /diagnostics, keyed as the node's other per-input values).
    """

    def __init__(self, node, subscriptions, subscribe, period_s=FOLLOW_PERIOD_S):
        self.node = node
        self.subscriptions = subscriptions      # the node's list, replaced entries seen
        self.subscribe = subscribe
        self.topics = [s.topic_name for s in subscriptions]     # resolved names
        self.types = [type_name(s.msg_type) for s in subscriptions]
        self.period_s = float(period_s)
        self.notes = []                         # what was followed, as logged
        self._failed = set()                    # (topic, type) that could not be subscribed
        self._unnamed = {}                      # (topic, type) -> when seen without a name
        self._next = 0.0
        _FOLLOWERS.add(self)

    def __call__(self, now=None):
        """Re-subscribe the inputs to follow (at most once per period); return their notes."""
        now = time.monotonic() if now is None else now
        if now < self._next:
            return []
        self._next = now + self.period_s
        notes = []
        for i, sub in enumerate(list(self.subscriptions)):
            typ, by = type_to_follow(self.node, sub)
            if not typ or (self.topics[i], typ) in self._failed:
                continue
            if UNKNOWN_NODE in by:        # the endpoint is known before its node's name
                first = self._unnamed.setdefault((self.topics[i], typ), now)
                if now - first < NAME_WAIT_S:
                    continue
            notes += self._switch(self.topics[i], self.types[i], typ, by)
        return notes

    def clear(self):
        """Forget every input (the node has destroyed its subscriptions and has none)."""
        del self.topics[:], self.types[:]

    def moved(self, index, typ):
        """Follow input ``index`` where its owner re-subscribed it (another topic, ``typ``)."""
        self.topics[index] = self.subscriptions[index].topic_name
        self.types[index] = typ

    def take(self, subscriptions, notes=()):
        """Follow ``subscriptions`` from now on (the node's new list), with ``notes`` said.

        For a node that took inputs another follower watched (``late_inputs``); that one
        lets go of them (``clear``), so a switch has one follower per input.
        """
        self.subscriptions = subscriptions
        self.topics[:] = [s.topic_name for s in subscriptions]
        self.types[:] = [type_name(s.msg_type) for s in subscriptions]
        self.notes += [n for n in notes if n not in self.notes]

    def _peers(self, topic, old):
        """Return (follower, index) of every input on ``topic`` as ``old`` in this context."""
        context = self.node.context

        def alive(f, j):         # not of a destroyed node (its subscriptions are gone)
            return any(x is f.subscriptions[j] for x in f.node.subscriptions)
        return [(f, j) for f in [self] + [f for f in list(_FOLLOWERS) if f is not self]
                if f.node.context is context
                for j, (t, ty) in enumerate(zip(f.topics, f.types))
                if t == topic and ty == old and alive(f, j)]

    def _switch(self, topic, old, typ, by):
        peers = self._peers(topic, old)
        for f, j in peers:
            f.node.destroy_subscription(f.subscriptions[j])
        made = []
        try:
            for f, j in peers:
                f.subscribe(j, typ)
                made.append((f, j))
        except Exception as e:  # noqa: B902 - every input goes back to the old type
            for f, j in made:
                f.node.destroy_subscription(f.subscriptions[j])
            for f, j in peers:
                f.subscribe(j, old)
                f._failed.add((topic, typ))
            self.node.get_logger().warning(
                f'{topic} is published as {typ}, but subscribing as that type failed ({e}); '
                f'still subscribed as {old}')
            return []
        bare = (' (no header: each reading takes the header stamp of the IMU message '
                'published before it)' if typ in common.HEADERLESS_TYPES else '')
        note = (f'{topic} is published as {typ} by {", ".join(by)}, not {old}: subscribed as '
                f'{typ}{bare}, as calibrate reads such a topic from a log; readings published '
                f"before now were not received (set temperature_types:='[{typ}]' to subscribe "
                'so from the start)')
        for f, j in peers:
            f.types[j] = typ
            if note not in f.notes:
                f.node.get_logger().warning(note)
                f.notes.append(note)
        return [note]


#: every follower of the process (the peers of a switch are found among them)
_FOLLOWERS = weakref.WeakSet()
