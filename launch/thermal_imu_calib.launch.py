"""Start the compensator and the calibrator with the package defaults (like ``bringup``)."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    """Return both nodes, each with its config/*.yaml."""
    config = os.path.join(get_package_share_directory('thermal_imu_calib'), 'config')
    return LaunchDescription([
        Node(package='thermal_imu_calib', executable='compensator_node',
             name='thermal_imu_compensator', output='screen',
             parameters=[os.path.join(config, 'compensator.yaml')]),
        Node(package='thermal_imu_calib', executable='calibrator_node',
             name='thermal_imu_calibrator', output='screen',
             parameters=[os.path.join(config, 'calibrator.yaml')]),
    ])
