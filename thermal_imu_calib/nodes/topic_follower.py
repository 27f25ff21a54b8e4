"""Follow the IMU's temperature under another topic name, as ``calibrate`` picks it from a log.

``calibrate`` without ``--temperature-topic`` takes the log's only sensor_msgs/Temperature
topic as the IMU's (of several: the one with the IMU's frame_id, else the one in the IMU
topic's namespace; a Float32/Float64 ``temp...`` topic beside the IMU's when there is
none): ``io.topics.choose_temperatures``. ``calibrator_node`` subscribed its
``temperature_topics`` only. A driver publishing ``/temperature`` (Xsens, the BNO055 USB
stick) or ``imu/temp``, or ``ros2 bag play`` of its bag, with the shipped
``temperature_topics: [imu/temperature]`` gave no reading and ``~/calibrate`` refused,
naming the topic to set, while ``calibrate`` on the same bag calibrated with it.

Now, while its thermal input is undecided (``absent_inputs``) and only with the default
``temperature_topics`` (one input, ``DEFAULT_TOPICS``; a list the user chose otherwise is
never second-guessed), the calibrator looks at the topics the IMU topic's own publishers
publish (the driver's, or the bag player's: the log's topics), and when nothing at all is
published on its input's topic it applies that same rule to them: the topic chosen (the
same for ``SETTLE_S``) is subscribed instead (as the type it is published as), with a
warning and a note in the calibration file; the IMU messages wait meanwhile, as for the
decision. A restart in such a session resumes the collection
(``absent_inputs.made_without``). The rule's frame_id test needs messages: of several
Temperature topics, each is probed (subscribed until its first message, at most
``PROBE_S``) and the IMU messages' frame_id is compared with theirs, as ``calibrate``
compares the first messages in a log; none singled out: nothing is followed and
``~/calibrate`` names them, as before. A temperature published by another node than the
IMU's is not followed (on a robot that is a battery's or a motor's as often as the
IMU's), nor one outside the node's namespace (another robot's); its name is in the
refusal. In lifelong mode too (its store's calibrations then name the followed topic);
not for a collection resumed from its file (decided at the start).

``compensator_node`` with the default list takes such a calibration by subscribing its
input's topic (``InputAdopter``).
"""

import time

from . import common
from .thermal_types import UNKNOWN_NODE
from ..io.cdr import TEMPERATURE_MSGTYPE
from ..io.topics import AmbiguousTemperature, choose_temperatures

#: the code's default ``temperature_topics`` (both nodes); only that list is followed
DEFAULT_TOPICS = ('imu/temperature',)


def follows(topics):
    """Return True when a node with these ``temperature_topics`` may follow another name."""
    return tuple(topics) == DEFAULT_TOPICS


def candidates(node, imu_sub, temp_sub):
    """Return ({topic: type}, publishers) the IMU's temperature may be found among, or None.

    None when something of any type is published on ``temp_sub``'s topic, or the IMU
    subscription's publishers are not on the graph with their node names yet; else the
    thermal topics (one type each) those nodes publish inside ``node``'s namespace (not
    another robot's) and the nodes' names. The graph is a hint only: an error reading it
    gives None.
    """
    try:
        if node.get_publishers_info_by_topic(temp_sub.topic_name):
            return None
        infos = node.get_publishers_info_by_topic(imu_sub.topic_name)
        if not infos or any(i.node_name == UNKNOWN_NODE for i in infos):
            return None
        publishers = sorted({(i.node_name, i.node_namespace) for i in infos})
        space = node.get_namespace().rstrip('/') + '/'
        published = {}
        for name, ns in publishers:
            for topic, types in node.get_publisher_names_and_types_by_node(name, ns):
                if (len(types) == 1 and types[0] in common.THERMAL_TYPES
                        and topic.startswith(space)):      # not another robot's
                    published[topic] = types[0]
    except Exception:  # noqa: B902 - the graph is only a hint
        return None
    return published, [ns.rstrip('/') + '/' + name for name, ns in publishers]


def topic_to_follow(node, imu_sub, temp_sub, frames=None, found=None):
    """Return (topic, type, how, publishers) of the IMU's temperature under another name.

    ('', '', '', []) unless ``candidates`` (or ``found``, their result already read) single
    out one thermal topic other than ``temp_sub``'s by ``choose_temperatures``, with the
    ``frames`` known (topic -> header.frame_id of its first message, the IMU topic's among
    them; on the graph alone none are).
    """
    found = candidates(node, imu_sub, temp_sub) if found is None else found
    if not found:
        return ('', '', '', [])
    published, by = found
    try:
        choice = choose_temperatures(published, imu_sub.topic_name, frames)
    except AmbiguousTemperature:
        return ('', '', '', [])
    if len(choice.topics) != 1 or choice.topics[0] == temp_sub.topic_name:
        return ('', '', '', [])
    topic, = choice.topics
    return topic, published[topic], choice.how, by


def note(old, topic, typ, how, by):
    """Return the warning (and calibration-file note) of a followed topic name."""
    why = {'only': 'the only sensor_msgs/Temperature topic it publishes',
           'frame': ("the one of its Temperature topics whose header.frame_id is the IMU "
                     "messages'"),
           'namespace': "the one of its Temperature topics in the IMU topic's namespace",
           'headerless': ("its header-less 'temp...' topic in the IMU topic's namespace (each "
                          'reading takes the header stamp of the IMU message published '
                          'before it)')}.get(how, how)
    return (f'nothing is published on {old}; {topic} ({typ}), published with the IMU topic '
            f'by {", ".join(by)}, is {why}: subscribed to it instead, as calibrate picks a '
            "log's temperature; readings published before now were not received (set "
            f"temperature_topics:='[{topic}]' to subscribe so from the start, "
            "or temperature_topics:='[]' for no thermal input)")


#: seconds (steady clock) the same topic must be singled out before it is followed: the
#: graph learns a driver's publishers one by one, and a second Temperature topic may
#: change the choice
SETTLE_S = 0.5
#: seconds (steady clock) the probes of several Temperature topics wait for their first
#: messages' frame_ids before the rule runs with those known (``calibrate`` reads the
#: first message of every topic in the log)
PROBE_S = 3.0


class NameFollower:
    """Follow the calibrator's one input to the IMU's temperature under another name, once.

    Called while the inputs are undecided (``absent_inputs``), before anything is collected
    (in lifelong mode also after a decision without a reading, until one comes:
    ``absent_inputs.follow_late``); returns True when it followed a topic (then it is not
    called again). The old subscription is destroyed, the input's topic, clock choice and
    pending readings start afresh, the collection file's inputs are rewritten (by the
    deferred resume when one waits), and the note is logged and kept for the calibration
    file. With a ``target`` (``late_inputs``: the node decided without a temperature and
    watches its inputs), the watched input is moved instead, and taken at its first
    reading.
    """

    @classmethod
    def for_node(cls, node):
        """Return a follower for a calibrator whose inputs are undecided and default, else None."""
        return cls() if not node._inputs_decided and follows(node.temperature_topics) else None

    def __init__(self, settle_s=SETTLE_S, target=None):
        self.settle_s = float(settle_s)
        #: None: the node's own input; else the inputs ``late_inputs`` watches (its
        #: ``subs[0]`` judged, its ``follow_name`` switched)
        self.target = target
        self._seen = None                 # ((topic, type, how, publishers), since)
        self.frames = {}                  # topic -> frame_id of its first message (probes)
        self._probes = {}                 # topic -> a probe subscription
        self._probing_since = None        # steady clock at the first probe

    def __call__(self, node, now=None):
        """Follow the topic singled out for ``SETTLE_S`` (``topic_to_follow``); True if so.

        Of several Temperature topics, each is probed first (``_probe``): the rule runs
        once their frame_ids and the IMU messages' are known, or ``PROBE_S`` after the
        probes began, with what is known then.
        """
        now = time.monotonic() if now is None else now
        temp_sub = node.temp_subs[0] if self.target is None else self.target.subs[0]
        among = candidates(node, node.imu_sub, temp_sub)
        several = [t for t, ty in (among[0] if among else {}).items()
                   if ty == TEMPERATURE_MSGTYPE]
        if len(several) > 1:
            self._probe(node, several, now)
            if now - self._probing_since < PROBE_S and (
                    not node._seen_frame or any(t not in self.frames for t in several)):
                return False
        frames = dict(self.frames)
        if node._seen_frame:
            frames[node.imu_sub.topic_name] = node._seen_frame
        found = topic_to_follow(node, node.imu_sub, temp_sub, frames, among or ())
        if not found[0]:
            self._seen = None
            return False
        if self._seen is None or self._seen[0] != found:
            self._seen = (found, now)
        if now - self._seen[1] < self.settle_s:
            return False
        self.close(node)
        if self.target is None:
            _switch(node, *found)
        else:
            self.target.follow_name(*found)
        return True

    def _probe(self, node, topics, now):
        """Subscribe each of ``topics`` not yet probed, to learn its first frame_id."""
        from sensor_msgs.msg import Temperature
        for topic in topics:
            if topic in self._probes:
                continue

            def first(msg, topic=topic):
                self.frames.setdefault(topic, msg.header.frame_id)
            self._probes[topic] = node.create_subscription(
                Temperature, topic, first, common.sensor_qos(10),
                callback_group=node._data_group)
            if self._probing_since is None:
                self._probing_since = now

    def close(self, node):
        """Destroy the probes (the inputs are decided); return None."""
        for sub in self._probes.values():
            node.destroy_subscription(sub)
        self._probes.clear()


def _resubscribe(node, topic, typ):
    """Move ``node``'s one input to ``topic`` as ``typ`` (``_subscribe_as``); return the old."""
    old = node.temp_subs[0].topic_name
    node.destroy_subscription(node.temp_subs[0])
    node._subscribe_as(0, typ, topic)
    node.type_follower.moved(0, typ)
    return old


def _switch(node, topic, typ, how, by):
    text = note(node.temp_subs[0].topic_name, topic, typ, how, by)
    node._input_notes.append(text)      # first: a reader seeing the new topic sees the note
    _resubscribe(node, topic, typ)
    if not node._resume_later:    # else the resume compares the file's inputs, then writes
        node._write_inputs_signature()
    node.get_logger().warning(text)


class InputAdopter:
    """compensator_node: serve a calibration whose one input was followed under another name.

    A calibration made on a followed topic (above, or by ``calibrate`` on a log) names it
    as its input; a compensator with the default ``temperature_topics`` refused it ("not
    among temperature_topics"), so ``~/calibrate`` handed the calibrator's result to a
    compensator that would not take it. Now, with the default list only, the compensator
    subscribes its one input to the calibration's topic instead when nothing is published
    on its own and the calibration's is published as one thermal type. When that is not
    yet so (at start the graph is still empty), the calibration waits: ``poll`` activates
    it once it is. A calibration activated meanwhile ends the wait. Not with
    ``registry_dir`` (one subscription serves every unit), nor a topic outside the node's
    namespace (another robot's).
    """

    def __init__(self, node):
        self.node = node
        self.enabled = follows(node.temperature_topics) and not node.registry_dir
        self.waiting = None             # (calibration, source) until its input is published

    def applies(self, cal):
        """Return True when ``cal``'s one input may be adopted (the default list here)."""
        return self.enabled and len(cal.temperature_topics) == 1

    def adopt(self, topic):
        """Subscribe the input to ``topic`` if ours is silent and it is published; True if so."""
        node = self.node
        try:
            resolved = node.resolve_topic_name(topic)
            space = node.get_namespace().rstrip('/') + '/'
            if not resolved.startswith(space):       # another robot's, under a namespace
                return False
            if node.get_publishers_info_by_topic(node.temp_subs[0].topic_name):
                return False
            types = {i.topic_type for i in node.get_publishers_info_by_topic(resolved)}
        except Exception:  # noqa: B902 - the graph is only a hint
            return False
        if len(types) != 1 or not types <= set(common.THERMAL_TYPES):
            return False
        typ, = types
        old = _resubscribe(node, topic, typ)
        node.get_logger().warning(
            f'nothing is published on {old}; the calibration\'s input {topic} is published '
            f'as {typ}: subscribed to it instead (set temperature_topics:=\'[{topic}]\' to '
            'subscribe so from the start)')
        return True

    def poll(self):
        """Activate the waiting calibration once its input can be adopted; return its result."""
        if self.waiting is None:
            return None
        cal, source = self.waiting
        if not self.adopt(cal.temperature_topics[0]):
            return None
        self.waiting = None
        return self.node.activate(cal, source)
