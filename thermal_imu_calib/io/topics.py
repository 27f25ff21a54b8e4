"""Topic selection in a log: which topic is the IMU, which are temperatures.

Shared by the offline pipelines and lab mode; raises LogError naming the
topics present.
"""

from dataclasses import dataclass

from . import cdr
from .log_info import LogError
from .cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
from .headerless import HEADERLESS_MSGTYPES, THERMAL_MSGTYPES


def resolve_topics(reader, imu_topic, temperature_topics, notes=None):
    """Check the IMU topic and pick the temperature topics.

    None picks the IMU's (``imu_temperatures``); an empty name is no input, so ``['']``
    means none. Named thermal-input topics may be any scalar of ``THERMAL_MSGTYPES`` (e.g. a
    proxy on sensor_msgs/Temperature or FluidPressure; std_msgs/Float32 or Float64 without a
    header, put on the IMU's clock by ``headerless``). Returns the temperature
    topic list; raises LogError naming the topics present. ``notes`` (a list) receives
    what was chosen among several Temperature topics, and why.
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
        temperature_topics = imu_temperatures(reader, imu_topic, notes)
    else:
        temperature_topics = [in_log(types, t) for t in temperature_topics if t]
        reader.check_topics(temperature_topics, THERMAL_MSGTYPES)
    return imu_topic, list(temperature_topics)


#: messages read at most to find the first message (its frame_id) of each topic
PEEK_MESSAGES = 200_000


def imu_temperatures(reader, imu_topic, notes=None):
    """Return the temperature topics of a log that are the IMU's (``choose_temperatures``).

    Raises LogError naming the candidates when none of several is the IMU's; the choice is
    appended to ``notes``.
    """
    types = reader.topic_types()
    counts = reader.topics()
    published = {t: ty for t, ty in types.items() if counts[t].count != 0}
    found = sorted(t for t, ty in published.items() if ty == TEMPERATURE_MSGTYPE)
    frames = _first_frames(reader, [imu_topic] + found) if found else {}
    try:
        choice = choose_temperatures(published, imu_topic, frames)
    except AmbiguousTemperature as e:
        raise LogError(f'{reader.path}: {e}') from None
    if notes is not None and choice.note:
        notes.append(choice.note)
    return choice.topics


class AmbiguousTemperature(ValueError):
    """Several thermal topics could be the IMU's and none is singled out (the text says so)."""


@dataclass(frozen=True)
class TemperatureChoice:
    """The topics chosen as the IMU's temperature: ``topics``, ``how`` and a ``note``.

    ``how``: 'only' (the one sensor_msgs/Temperature topic), 'frame' (its header.frame_id
    is the IMU's), 'namespace' (in the IMU topic's namespace), 'headerless' (a Float32 /
    Float64 'temp...' topic in the IMU topic's namespace) or '' (none).
    """

    topics: list
    how: str = ''
    note: str = ''


def choose_temperatures(published, imu_topic, frames=None):
    """Return the TemperatureChoice of the IMU's temperature among ``published`` topics.

    The one rule of ``calibrate`` (a log's topics) and the nodes (the topics on the graph,
    ``nodes.topic_follower``). ``published``: topic -> type of the topics that carry
    messages; ``frames``: topic -> header.frame_id of its first message (the IMU's too),
    where known. One sensor_msgs/Temperature topic: it (noted when neither its frame_id nor
    its namespace is the IMU's). Several (a robot's bag also has a battery's, a motor's, a
    CPU's): those whose header.frame_id is the IMU's, else those in the IMU topic's
    namespace (``/imu/temperature`` for ``/imu/data_raw``); with neither,
    AmbiguousTemperature naming them: a temperature of something else would become the
    thermal model's input. None: a std_msgs/Float32 or Float64 topic in the IMU topic's
    namespace named 'temp...' (``/imu/temperature`` of the um6/um7 drivers); several such:
    AmbiguousTemperature.
    """
    frames = frames or {}
    found = sorted(t for t, ty in published.items() if ty == TEMPERATURE_MSGTYPE)
    space = imu_topic.rsplit('/', 1)[0]
    if not found:
        return _headerless_temperature(published, space)
    imu_frame = frames.get(imu_topic, '')
    by_frame = [t for t in found if imu_frame and frames.get(t) == imu_frame]
    by_space = [t for t in found if t.rsplit('/', 1)[0] == space]
    if len(found) == 1:
        note = ''
        if not (by_frame or by_space or not imu_frame or not frames.get(found[0])):
            note = (f'temperature input {found[0]}, the log\'s only Temperature topic, '
                    f'though its frame_id {frames.get(found[0])!r} is not the IMU\'s '
                    f'({imu_frame!r}) nor is it in the IMU topic\'s namespace '
                    f"{space or '/'}: if it is not the IMU's temperature, pass "
                    "--temperature-topic '' (no thermal input)")
        return TemperatureChoice(found, 'only', note)
    chosen, how, why = (
        (by_frame, 'frame', f'header.frame_id {imu_frame!r}, the IMU\'s') if by_frame else
        (by_space, 'namespace', f'in the IMU topic\'s namespace {space or "/"}') if by_space
        else ([], '', ''))
    listed = ', '.join(f'{t} (frame_id {frames.get(t, "?")!r})' for t in found)
    if not chosen:
        raise AmbiguousTemperature(
            f'several sensor_msgs/Temperature topics, {listed}, and '
            f'none is the IMU\'s ({imu_topic}: frame_id {imu_frame!r}, namespace '
            f'{space or "/"}); name the IMU\'s temperature with --temperature-topic '
            "TOPIC, or pass --temperature-topic '' for none")
    return TemperatureChoice(chosen, how, (
        f'temperature input {", ".join(chosen)} ({why}) of the Temperature topics '
        f'{listed}; name others with --temperature-topic'))


def _headerless_temperature(published, space):
    """Return the choice of the IMU's header-less temperature topic (no Temperature topic).

    A std_msgs/Float32 or Float64 topic in the IMU topic's namespace whose name starts with
    'temp' (``/imu/temperature`` of the um6/um7 drivers) is the IMU's; several such topics
    raise AmbiguousTemperature naming them.
    """
    bare = sorted(t for t, ty in published.items()
                  if ty in HEADERLESS_MSGTYPES and t.rsplit('/', 1)[0] == space
                  and t.rsplit('/', 1)[1].lower().startswith('temp'))
    if len(bare) > 1:
        raise AmbiguousTemperature(
            f'several header-less temperature topics in the IMU topic\'s '
            f'namespace {space or "/"}: {", ".join(bare)}; name the IMU\'s with '
            "--temperature-topic TOPIC, or pass --temperature-topic '' for none")
    if not bare:
        return TemperatureChoice([])
    return TemperatureChoice(bare, 'headerless', (
        f'temperature input {bare[0]} ({published[bare[0]]}, no header: each reading '
        'takes the stamp of the IMU message logged before it); name another '
        "with --temperature-topic, or pass --temperature-topic '' for none"))


def _first_frames(reader, topics):
    """Return topic -> header.frame_id of its first message (topics not seen are absent)."""
    out = {}
    for i, (topic, msgtype, _, raw) in enumerate(reader.iter_raw(topics)):
        if topic not in out:
            try:
                cols = (cdr.decode_imu([raw]) if msgtype == IMU_MSGTYPE
                        else cdr.decode_temperature([raw]))
                out[topic] = cols.frame_id
            except ValueError:
                out[topic] = ''
        if len(out) == len(topics) or i >= PEEK_MESSAGES:
            break
    return out


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
