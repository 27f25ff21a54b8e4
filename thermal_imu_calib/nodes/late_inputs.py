"""A temperature first published after the calibrator decided to collect without one.

``absent_inputs`` decides ``GRACE_S`` after the first IMU message that no temperature is
published, and the node collects without one, as ``calibrate`` does a log without a
temperature topic. A temperature driver started later than that (its own launch file, a
board sensor's node) used to be named in a warning and not used until the node was
restarted, while ``calibrate`` on the same log uses it: the IMU samples logged more than
``temperature_timeout`` before its first reading are not collected (no temperature to give
them, ``io.align.fresh_rows``), the rest are, with it.

Now the dropped inputs stay subscribed (``LateInputs``), as the type they were configured
with (or followed, below), and a *shadow* aligner (``io.align.StreamAligner`` with those
inputs) takes every IMU row the node processes, as the node would have with the inputs:
until a reading comes it releases only rows with no temperature (stale, ``max_wait_s``
behind the newest). At the first reading the node takes the inputs back (``adopt``): the
collection made without them is moved aside
(``<collection_file>.without_temperature-TIME``), a new one starts with the shadow aligner
and its rows still pending, and the readings go through the node's own callbacks from then
on. What it then collects is what the node with the inputs from the start would have
collected, so ``~/calibrate`` equals ``calibrate`` on the log whenever every message
arrives (``test_live_offline.py``, ``late_temperature``). Readings published before the
node's subscription matched the new publisher are lost, as any first messages of a
publisher (a player should wait for the match, as ``ros2 bag play --delay`` does).

A header-less input (std_msgs/Float32 or Float64) is taken the same way: its readings go on
the IMU's clock (the stamp of the IMU message published before each), so while the inputs
are watched the node keeps the IMU messages' publish order for them (``_ShadowClocks``).
A late publisher of another thermal type than the input's (a Float32 driver on a topic the
node subscribes as sensor_msgs/Temperature) is followed as at the start
(``thermal_types.TypeFollower``) and then taken; so is the IMU's temperature under another
name when the IMU's driver starts publishing it late (``topic_follower.NameFollower``, with
the default ``temperature_topics`` only, by the rule ``calibrate`` picks a log's with).
Still named in a warning (``warn_late``) and used only after a restart: a publisher of a
type that is not a thermal one, or of several types at once. A jump back of the IMU stamps
or ``~/reset`` gives the shadow a fresh aligner and fresh clocks, at once (``shadow``).
"""

import copy
import time

from . import common, topic_follower
from .thermal_types import TypeFollower, type_name
from ..io.align import StreamAligner
from ..io.columns import TemperatureColumns
from ..io.headerless import LiveClocks


class _Shadowed:
    """The node's aligner (no inputs), also feeding every IMU row to the watched inputs'."""

    def __init__(self, own, late):
        self.own, self.late = own, late

    def push_columns(self, imu, temps, extra=None):
        self.late.take(self.late.aligner.push_columns(imu, self.late.no_readings))
        return self.own.push_columns(imu, temps, extra)

    def finish(self):
        self.late.take(self.late.aligner.finish())
        return self.own.finish()

    def __deepcopy__(self, memo):
        """Copy the node's own aligner only (a snapshot finishes its rows, not the shadow's)."""
        return copy.deepcopy(self.own, memo)


class _ShadowClocks:
    """The node's clocks (no inputs), also feeding every IMU message to the watched inputs'.

    The node keeps its IMU messages' DDS source timestamps while ``on``: here while the
    watched inputs' clocks need them (a header-less input, or one whose stamps are not
    judged yet), so a first reading is put on the IMU's clock as it would have been with
    the inputs from the start.
    """

    def __init__(self, own, late):
        self.own, self.late = own, late

    @property
    def on(self):
        return self.late.clocks.on

    def add_imu(self, source_ns, stamp_ns):
        self.late.clocks.add_imu(source_ns, stamp_ns)
        self.own.add_imu(source_ns, stamp_ns)

    def __getattr__(self, name):          # bare, notes, describe, fresh, ...: the node's own
        return getattr(self.own, name)


class LateInputs:
    """The thermal inputs ``absent_inputs.drop_inputs`` dropped, still subscribed."""

    def __init__(self, node, subs):
        """Keep ``node``'s inputs (before they are dropped) and re-subscribe ``subs``' topics."""
        self.topics = list(node.temperature_topics)
        self.units = list(node.temperature_units)
        self.inputs = list(node.inputs)
        self.k = node.k
        self.timeout = node.temperature_timeout
        self.node = node
        self.no_readings = [TemperatureColumns.empty() for _ in range(self.k)]
        self.held = [[] for _ in range(self.k)]     # (message, info) until adopted
        self.forward = None                         # then the node's own callbacks
        self.stale = 0                              # shadow rows released without a reading
        #: the inputs' clocks once taken back, fed the IMU messages meanwhile
        #: (``_ShadowClocks``), so the stamps' clock is chosen and applied at the first
        #: readings as offline
        self.clocks = LiveClocks(self.topics, [common.headerless(s.msg_type) for s in subs])
        self.since = time.monotonic()
        self.aligner = StreamAligner(self.k, self.timeout)
        self.wrapper = self.clock_wrapper = None
        self.types = [type_name(s.msg_type) for s in subs]     # common.THERMAL_TYPES keys
        self.subs = [self._subscription(i, typ) for i, typ in enumerate(self.types)]
        #: a late publisher of another thermal type is followed, as at the start
        self.follower = TypeFollower(node, self.subs, self._subscribe_as)
        #: so is the IMU's temperature under another name (the default topics only)
        self.name_follower = (topic_follower.NameFollower(target=self)
                              if topic_follower.follows(self.topics) else None)
        self.notes = []                  # what was followed (the file's notes at adoption)

    def _subscription(self, index, typ):
        node = self.node
        return node.create_subscription(common.THERMAL_TYPES[typ][0], self.topics[index],
                                        self._callback(index), common.sensor_qos(node._in_depth),
                                        callback_group=node._data_group)

    def _subscribe_as(self, index, typ, topic=None):
        """Subscribe input ``index`` as ``typ`` (the old subscription is destroyed)."""
        self.topics[index] = topic or self.topics[index]
        self.subs[index] = self._subscription(index, typ)
        self.types[index] = typ
        with self.node._lock:
            self.clocks.retype(index, common.headerless(common.THERMAL_TYPES[typ][0]), topic)
            self.held[index] = []

    def follow_name(self, topic, typ, how, by):
        """Move the one watched input to ``topic`` as ``typ`` (``topic_follower``)."""
        text = topic_follower.note(self.subs[0].topic_name, topic, typ, how, by)
        self.node.destroy_subscription(self.subs[0])
        self._subscribe_as(0, typ, topic)
        self.follower.moved(0, typ)
        self.notes.append(text)
        self.node.get_logger().warning(text)

    def _callback(self, index):
        def cb(msg, info):
            if self.forward is not None:
                self.forward[index](msg, info)
            else:
                self.held[index].append((msg, info))
        return cb

    def take(self, chunks):
        """Count the shadow's released rows (no reading has come: none is fresh)."""
        self.stale += sum(len(c.imu) for c in chunks)

    def shadow(self, node):
        """Put the shadow under ``node``'s aligner and clocks again when the node replaced them.

        Called under ``node._lock``: at each tick, and where the node replaces them (a jump
        back of the IMU stamps, ``~/reset``), so no IMU message between that and the next
        tick is missing from the watched inputs' clocks.
        """
        if node.aligner is not self.wrapper:
            if self.wrapper is not None:        # a jump back or ~/reset: a new timeline
                self.aligner = StreamAligner(self.k, self.timeout)
            self.wrapper = node.aligner = _Shadowed(node.aligner, self)
        if node._clocks is not self.clock_wrapper:
            if self.clock_wrapper is not None:  # ~/reset: stamps judged afresh
                self.clocks = self.clocks.fresh()
            self.clock_wrapper = node._clocks = _ShadowClocks(node._clocks, self)


def adopt(node, late):
    """Take the inputs back into ``node`` (the calibrator) at their first reading."""
    with node._lock:
        aside = node._move_aside('without_temperature')
        # the shadow aligner holds the rows of the last max_wait_s, as with the inputs
        node._restart_with(late.topics, late.units, late.inputs, late.subs, late.clocks,
                           late.aligner)
        node.counts['samples'] = 0
        node.counts['stale_temperature'] = late.stale
    # the node's follower takes the inputs over (the late one lets go of them: one switch)
    node.type_follower.take(node.temp_subs, late.follower.notes)
    late.follower.clear()
    late.forward = [node._temperature_cb(i, common.THERMAL_TYPES[typ][1])
                    for i, typ in enumerate(late.types)]
    held, late.held = late.held, [[] for _ in range(late.k)]
    for i, items in enumerate(held):
        for msg, info in items:
            late.forward[i](msg, info)
    node._write_inputs_signature()
    node._absent_topics = []
    topics = ', '.join(s.topic_name for s in late.subs)
    why = (f'{topics}: the first reading came {time.monotonic() - late.since:.1f} s after '
           f'the node decided to collect without a temperature; the node '
           'collects with it from here, as calibrate does a log whose temperature starts '
           f'late (IMU samples more than {late.timeout:g} s before its first reading are not '
           'collected)' + (f'; the holds collected without it were moved to {aside}'
                           if aside else ''))
    node._input_notes[:] = ([n for n in node._input_notes
                             if not n.startswith('no temperature is published')]
                            + late.notes + [why])
    node.get_logger().warning(why)


def watch(node):
    """Each tick after a decision without the inputs: adopt them, or warn (``warn_late``)."""
    late = node._late_inputs
    if late.forward is None:
        if any(late.held):
            adopt(node, late)
            return
        late.follower()                   # another thermal type: re-subscribed as it
        if late.name_follower is not None and late.name_follower(node):
            late.name_follower = None     # the IMU's temperature under another name
        with node._lock:                  # the node's aligner is replaced under it too
            late.shadow(node)
    if not node._warned_late:
        warn_late(node, late)


def _taken(types, watched):
    """Return True when publishers of ``types`` on a watched topic (as ``watched``) are taken.

    Those of the watched type are (their first reading); those of one other thermal type
    are followed first (``thermal_types``).
    """
    return watched is not None and (types <= {watched} or (
        len(types) == 1 and next(iter(types)) in common.THERMAL_TYPES))


def warn_late(node, late):
    """Say once that a temperature the node will not take appeared on an input's topic."""
    watched = dict(zip((s.topic_name for s in late.subs), late.types))
    try:
        published = {t: {i.topic_type for i in node.get_publishers_info_by_topic(t)}
                     for t in node._absent_topics}
    except Exception:  # noqa: B902 - the graph is only a hint
        published = {}
    late_topics = [t for t, types in published.items()
                   if types and not _taken(types, watched.get(t))]
    if late_topics:
        node._warned_late = True
        node.get_logger().warning(
            f'{", ".join(late_topics)} is published now, after the node decided to collect '
            'without a temperature ('
            + '; '.join(f'as {", ".join(sorted(published[t]))}' for t in late_topics)
            + ', not one thermal type); it is not used: restart the node to calibrate with it')
