"""The calibrator's decision to collect without a temperature nobody publishes (unit level).

``nodes/absent_inputs.decide`` on a stand-in node: its subscriptions, counters and graph.
Over DDS: ``test_live_offline.py::test_live_calibration_equals_offline[none_shipped_config]``.
"""

from types import SimpleNamespace

from thermal_imu_calib.nodes import absent_inputs as ai


class _Sub:
    def __init__(self, topic, matched=0):
        self.topic_name, self.matched = topic, matched

    def get_publisher_count(self):
        return self.matched


def _node(matched=0, readings=0, on_topic=(), graph=()):
    """A stand-in calibrator: one input on /imu/temperature."""
    return SimpleNamespace(
        temp_subs=[_Sub('/imu/temperature', matched)], readings_per_topic=[readings],
        _pending_temp=[[]],
        get_publishers_info_by_topic=lambda t: list(on_topic),
        get_topic_names_and_types=lambda: list(graph))


def test_a_reading_or_a_matched_publisher_decides_with_the_inputs_at_once():
    assert ai.decide(_node(readings=1), None)[0] == ai.PRESENT
    assert ai.decide(_node(matched=1), None)[0] == ai.PRESENT


def test_nothing_published_decides_without_them_after_the_grace_or_at_calibrate():
    n = _node()
    assert ai.decide(n, None, force=True)[0] == ai.UNDECIDED      # no IMU message yet
    assert ai.decide(n, 100.0, now=100.0 + ai.GRACE_S - 0.1)[0] == ai.UNDECIDED
    how, why = ai.decide(n, 100.0, now=100.0 + ai.GRACE_S)
    assert how == ai.ABSENT
    assert why.startswith('no temperature is published: nothing on /imu/temperature and no '
                          f'thermal topic on the graph {ai.GRACE_S:g} s after the first IMU '
                          'message')
    assert "temperature_topics:='[]'" in why
    how, why = ai.decide(n, 100.0, force=True, now=101.5)        # ~/calibrate
    assert how == ai.ABSENT and '1.5 s after the first IMU message' in why


def test_something_on_the_graph_keeps_the_inputs():
    # a publisher of another type on the topic (the follower or the refusal names it), or
    # a thermal topic under another name (the refusal names it): never without the inputs
    other = _node(on_topic=[object()])
    assert ai.decide(other, 100.0, now=101.0)[0] == ai.UNDECIDED
    assert ai.decide(other, 100.0, now=100.0 + ai.GRACE_S)[0] == ai.PRESENT
    elsewhere = _node(graph=[('/imu/temp', ['sensor_msgs/msg/Temperature'])])
    assert ai.decide(elsewhere, 100.0, force=True, now=101.0)[0] == ai.PRESENT
    bare = _node(graph=[('/imu/temp_c', ['std_msgs/msg/Float32'])])
    assert ai.decide(bare, 100.0, force=True, now=101.0)[0] == ai.PRESENT
    battery = _node(graph=[('/battery/voltage', ['std_msgs/msg/Float32'])])   # not temp*
    assert ai.decide(battery, 100.0, force=True, now=101.0)[0] == ai.ABSENT
