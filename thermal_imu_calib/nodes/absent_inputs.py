"""No temperature published at all: the calibrator collects without one, as calibrate does.

``calibrate`` calibrates a log without a temperature topic without one (a
temperature-independent calibration). The calibrator, with the shipped
``temperature_topics: [imu/temperature]`` and nothing published on it, collected nothing
(every IMU sample waits for a temperature) and ``~/calibrate`` named
``temperature_topics:='[]'`` to set: live and offline differed on such a recording with the
shipped config. Now the node decides once, before it collects anything:

* **with its inputs** as soon as one has a reading or a matched publisher; also when a
  publisher of any type is on an input's topic, or a thermal topic is on the graph under
  another name (``input_hints.thermal_topics_hint``), once ``GRACE_S`` have passed (the
  type follower may switch; otherwise the refusal names what is there, as before);
* **without** them when ``GRACE_S`` after the first IMU message (or at ``~/calibrate``) no
  input has a reading or a publisher of any type and no thermal topic is on the graph: the
  node then runs as with ``temperature_topics: []`` and says so once.

Until then the IMU messages wait in the node's queue (at most ``GRACE_S`` of them), so the
holds are those ``calibrate`` finds from the first message. Lifelong mode waits the same
way (its temperature may be followed under another name) but never drops its inputs: its
store learns a thermal model, so without a reading it collects nothing and the node warns
as for any input without readings. Not for a collection resumed from its file, or a node
without inputs (decided at the start); a
collection made without the inputs (a restart in such a session) is resumed once decided
(``made_without``). A temperature first published after a decision without it is taken
then, as ``calibrate`` takes a log's late temperature (``late_inputs``).
"""

import json
import os
import time

from . import input_hints, late_inputs, topic_follower
from ..io.headerless import LiveClocks

#: seconds (steady clock) after the first IMU message before deciding without a temperature:
#: a temperature driver started with the IMU's is on the graph well within it; the IMU
#: messages wait meanwhile (10 s at 1 kHz: 10000 messages)
GRACE_S = 10.0

PRESENT, ABSENT, UNDECIDED = 'with inputs', 'without inputs', ''


def decided_at_start(node):
    """Return True when ``node``'s (the calibrator's) inputs need no decision.

    No inputs, or a collection resumed from its file; in lifelong mode a list the user set
    (lifelong keeps its inputs: with the default list it may only follow another name).
    """
    return (not node.k or node.resumed_holds > 0
            or (node.lifelong is not None
                and not topic_follower.follows(node.temperature_topics)))


def settle(node, force=False):
    """Decide ``node``'s inputs when ``decide`` can (each tick); return True once decided.

    Follows the IMU's temperature under another name first (``topic_follower``); without
    inputs the node collects without them (not in lifelong mode, which waits for a
    reading, still looking for one under another name: ``follow_late``); a collection
    waiting to be resumed is resumed then.
    """
    if node._imu_seen_at is None and node._rate.total:
        node._imu_seen_at = time.monotonic()
    if node._name_follower and node._name_follower(node):
        node._name_follower = None
    how, why = decide(node, node._imu_seen_at, force)
    if how == UNDECIDED:
        return False
    if how == ABSENT and node.lifelong is None:
        drop_inputs(node, why)
    if how != ABSENT or node.lifelong is None:
        node._name_follower = node._name_follower and node._name_follower.close(node)
    if node._resume_later:       # before anything is collected (the queue waits)
        node._resume_later = False
        with node._lock:
            node._resume_all()
    node._inputs_decided = True
    if node.lifelong is not None:
        node.lifelong.inputs_decided()
    return True


def follow_late(node):
    """Lifelong mode without a reading: follow a temperature published later, renamed.

    The IMU's temperature under another name is followed when its driver starts publishing
    it after the decision, until a reading comes on the input. Nothing was collected
    meanwhile (every IMU sample waits for a temperature), so the input moves as before the
    decision, and the store's calibrations name the new topic.
    """
    if any(node.readings_per_topic):
        node._name_follower = node._name_follower.close(node)
    elif node._name_follower(node):
        node._name_follower = None
        node.lifelong.inputs_decided()


def decide(node, imu_seen_at, force=False, now=None):
    """Return (PRESENT, ABSENT or UNDECIDED, why) for ``node``'s thermal inputs.

    ``imu_seen_at``: ``time.monotonic()`` when the first IMU message was seen (None: none
    yet); ``force``: decide now (``~/calibrate``). The graph is read as a hint: an error
    reading it counts as something on it.
    """
    now = time.monotonic() if now is None else now
    if any(node.readings_per_topic) or any(node._pending_temp):
        return PRESENT, ''
    try:
        if any(s.get_publisher_count() for s in node.temp_subs):
            return PRESENT, ''
        on_topics = any(node.get_publishers_info_by_topic(s.topic_name) for s in node.temp_subs)
    except Exception:  # noqa: B902 - the graph is only a hint
        on_topics = True
    waited = imu_seen_at is not None and now - imu_seen_at >= GRACE_S
    if not (force or waited):
        return UNDECIDED, ''
    if on_topics or input_hints.thermal_topics_hint(node, node.temp_subs):
        return PRESENT, ''
    if imu_seen_at is None:         # nothing to decide on yet, even at ~/calibrate
        return UNDECIDED, ''
    names = ', '.join(s.topic_name for s in node.temp_subs)
    when = (f'{now - imu_seen_at:.1f} s after the first IMU message' if not waited
            else f'{GRACE_S:g} s after the first IMU message')
    return ABSENT, (f'no temperature is published: nothing on {names} and no thermal topic on '
                    f'the graph {when}, so the node collects without a temperature, as '
                    'calibrate does a log without one (a temperature-independent '
                    'calibration); one published later is taken from its first reading '
                    "(set temperature_topics:='[]' to say none will come)")


def drop_inputs(node, why):
    """Run ``node`` (the calibrator) as with ``temperature_topics: []`` from here on.

    Only before anything is collected: its subscriptions are destroyed, the inputs
    forgotten, and a new collection without them takes the IMU messages still queued.
    """
    node._absent_topics = [s.topic_name for s in node.temp_subs]
    node._warned_late = False
    # the inputs stay subscribed: a first reading brings them back (``late_inputs``)
    node._late_inputs = late_inputs.LateInputs(node, node.temp_subs)
    for s in node.temp_subs:
        node.destroy_subscription(s)
    node.type_follower.clear()
    with node._lock:
        node._restart_with([], [], [], [], LiveClocks([], []))
        node._late_inputs.shadow(node)      # from the first IMU message on, as offline
    node._write_inputs_signature()
    node._input_notes.append(why)
    node.get_logger().warning(why)


def made_without(node):
    """Return True when ``node``'s collection file was made with inputs the decision may change.

    A calibrator restarted in a session without a temperature: the file's inputs are none
    (``drop_inputs`` wrote them) while the node has its configured ones; or in a session
    whose temperature was followed under another name (``topic_follower``): the file has
    one other topic while the node has the default one. The resume then waits for the
    decision: with the file's inputs it goes on with that collection, with others it is
    moved aside, as any collection of other inputs.
    """
    path = node._collection_path()
    if not node.k or not path or not os.path.exists(path):
        return False
    try:
        with open(path + '.inputs.json') as f:
            topics = json.load(f).get('temperature_topics')
    except (OSError, ValueError, AttributeError):
        return False
    # lifelong mode never collects without its inputs, but follows another name
    return (topics == [] and node.lifelong is None) or (
        topic_follower.follows(node.temperature_topics) and isinstance(topics, list)
        and len(topics) == 1 and topics != list(node.temperature_topics))
