"""The one rule that picks the IMU's temperature topic (``io.topics.choose_temperatures``).

``calibrate`` applies it to a log's topics with the frame ids of their first messages; the
nodes apply it to the topics the IMU's publishers publish on the ROS graph, without frame
ids (``nodes/topic_follower``). Both must agree where the frame ids decide nothing.
"""

import pytest

from thermal_imu_calib.io.topics import AmbiguousTemperature, choose_temperatures

T, F32, IMU = 'sensor_msgs/msg/Temperature', 'std_msgs/msg/Float32', 'sensor_msgs/msg/Imu'


@pytest.mark.parametrize('published, frames, topics, how', [
    ({'/imu/data_raw': IMU, '/temperature': T}, {}, ['/temperature'], 'only'),
    ({'/imu/data_raw': IMU, '/battery/temperature': T, '/imu/temp': T}, {}, ['/imu/temp'],
     'namespace'),
    ({'/imu/data_raw': IMU, '/battery/temperature': T, '/imu/temp': T},
     {'/imu/data_raw': 'imu_link', '/battery/temperature': 'imu_link', '/imu/temp': 'x'},
     ['/battery/temperature'], 'frame'),                 # offline: the frame id first
    ({'/imu/data_raw': IMU, '/imu/temperature': F32}, {}, ['/imu/temperature'], 'headerless'),
    ({'/imu/data_raw': IMU, '/board/temperature': F32}, {}, [], ''),   # not beside the IMU
    ({'/imu/data_raw': IMU}, {}, [], ''),
])
def test_the_rule(published, frames, topics, how):
    choice = choose_temperatures(published, '/imu/data_raw', frames)
    assert choice.topics == topics and choice.how == how


def test_the_only_temperature_topic_is_noted_when_nothing_says_it_is_the_imus():
    choice = choose_temperatures({'/imu/data_raw': IMU, '/battery/temperature': T},
                                 '/imu/data_raw', {'/imu/data_raw': 'imu_link',
                                                   '/battery/temperature': 'battery'})
    assert choice.topics == ['/battery/temperature']
    assert "the log's only Temperature topic, though its frame_id 'battery'" in choice.note


@pytest.mark.parametrize('published', [
    {'/imu/data_raw': IMU, '/battery/temperature': T, '/motor/temperature': T},
    {'/imu/data_raw': IMU, '/imu/temp_a': F32, '/imu/temp_b': F32},
])
def test_several_and_none_singled_out_are_refused_naming_them(published):
    with pytest.raises(AmbiguousTemperature) as e:
        choose_temperatures(published, '/imu/data_raw')
    for t in published:
        if t != '/imu/data_raw':
            assert t in str(e.value)
