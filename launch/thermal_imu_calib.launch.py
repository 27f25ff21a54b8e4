"""Start the compensator and/or the calibrator; every setting a user reaches for is an argument.

    ros2 launch thermal_imu_calib thermal_imu_calib.launch.py imu_topic:=/my_imu/data_raw
    ros2 launch thermal_imu_calib thermal_imu_calib.launch.py nodes:=compensator \\
        namespace:=left temperature_topics:='[/left/temp]' calibration_file:=~/cal.yaml

    ros2 launch thermal_imu_calib thermal_imu_calib.launch.py nodes:=calibrator gravity:=9.81

Arguments: namespace, imu_topic (remapped onto the nodes' ``imu/data_raw``),
temperature_topics and temperature_types (YAML lists), params_file (default: the
package's config/<node>.yaml), calibration_file (default: the one in the params file),
use_sim_time, the calibrator's gravity, latitude, lifelong and motion hints
(cmd_vel_topic, odom_topic, still_topic), and nodes (comma list of compensator,
calibrator). ``ros2 launch``
silently keeps an argument a launch file does not declare, so a node parameter given as
``name:=value`` (e.g. ``order:=1``) is not applied: this file prints a warning naming it
and how to set it.
"""

import os
import sys

import yaml
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'thermal_imu_calib'
NODES = {'compensator': ('compensator_node', 'thermal_imu_compensator'),
         'calibrator': ('calibrator_node', 'thermal_imu_calibrator')}
ARGUMENTS = (
    ('namespace', '', 'namespace of the nodes (and of their relative topics)'),
    ('imu_topic', 'imu/data_raw', 'sensor_msgs/Imu input, remapped onto imu/data_raw'),
    ('temperature_topics', '', 'YAML list of thermal input topics, e.g. [imu/temperature]; '
                               '[] for none (empty: the params file\'s)'),
    ('temperature_types', '', 'YAML list of their message types, one for all or one each, e.g. '
                              '[std_msgs/msg/Float32] for a driver publishing the temperature '
                              'without a header (empty: the params file\'s, '
                              'sensor_msgs/msg/Temperature)'),
    ('params_file', '', 'parameters file for the nodes (empty: config/<node>.yaml of the '
                        'package)'),
    ('calibration_file', '', 'calibration YAML the compensator loads and the calibrator writes '
                             '(empty: the params file\'s)'),
    ('use_sim_time', 'false', 'use /clock (true when playing a bag with --clock)'),
    ('gravity', '', 'calibrator: local gravity in m/s^2, e.g. 9.81 (empty: the params file\'s; '
                    '0 there: standard gravity)'),
    ('latitude', '', 'calibrator: geodetic latitude in degrees, for normal gravity and the '
                     'earth\'s rotation (empty: the params file\'s, not used unless '
                     'use_latitude)'),
    ('lifelong', '', 'calibrator: true to learn from everyday stops (docs/lifelong.md; '
                     'empty: the params file\'s)'),
    ('cmd_vel_topic', '', 'calibrator, lifelong: geometry_msgs/Twist motion hint (empty: the '
                          'params file\'s)'),
    ('odom_topic', '', 'calibrator, lifelong: nav_msgs/Odometry motion hint (empty: the '
                       'params file\'s)'),
    ('still_topic', '', 'calibrator, lifelong: std_msgs/Bool motion hint, true = commanded '
                        'still (empty: the params file\'s)'),
    ('nodes', 'compensator,calibrator',
     'comma list of the nodes to start: compensator, calibrator'),
)


def _config_dir():
    try:
        from ament_index_python.packages import get_package_share_directory
        return os.path.join(get_package_share_directory(PACKAGE), 'config')
    except Exception:   # noqa: B902 - not installed (source tree): the repository's config/
        return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                            'config')


def _bool(text, name):
    t = str(text).strip().lower()
    if t not in ('true', 'false', '1', '0', 'yes', 'no'):
        raise ValueError(f'{name}:={text} is not true or false')
    return t in ('true', '1', 'yes')


def make_nodes(context):
    """Return the Node actions for the resolved launch arguments (OpaqueFunction body)."""
    v = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    wanted = [n.strip() for n in v['nodes'].split(',') if n.strip()]
    unknown = [n for n in wanted if n not in NODES]
    if unknown or not wanted:
        raise ValueError(f'nodes:={v["nodes"]} must name some of {", ".join(NODES)}')
    overrides = {'use_sim_time': _bool(v['use_sim_time'], 'use_sim_time')}
    if v['temperature_topics'].strip():
        topics = _names(v['temperature_topics'], 'temperature_topics', 'topics',
                        '[imu/temperature]')
        # ROS 2 cannot type an empty array: [''] is the nodes' spelling of "no input"
        overrides['temperature_topics'] = topics or ['']
    if v['temperature_types'].strip():
        overrides['temperature_types'] = _names(
            v['temperature_types'], 'temperature_types', 'message types',
            '[std_msgs/msg/Float32]') or ['sensor_msgs/msg/Temperature']
    if v['calibration_file'].strip():
        overrides['calibration_file'] = os.path.expanduser(v['calibration_file'])
    calibrator = {}
    if v['gravity'].strip():
        calibrator['gravity'] = _number(v['gravity'], 'gravity', 9.7, 9.9, zero=True)
    if v['latitude'].strip():
        calibrator['latitude'] = _number(v['latitude'], 'latitude', -90.0, 90.0)
        calibrator['use_latitude'] = True
    if v['lifelong'].strip():
        calibrator['lifelong'] = _bool(v['lifelong'], 'lifelong')
    for name in ('cmd_vel_topic', 'odom_topic', 'still_topic'):
        if v[name].strip():
            calibrator[name] = v[name].strip()
    actions = []
    for which in wanted:
        executable, name = NODES[which]
        params = v['params_file'] or os.path.join(_config_dir(), f'{which}.yaml')
        _warn_unapplied(context, params, name)
        actions.append(Node(package=PACKAGE, executable=executable, name=name,
                            namespace=v['namespace'], output='screen',
                            parameters=[params, {**overrides, **(
                                calibrator if which == 'calibrator' else {})}],
                            remappings=[('imu/data_raw', v['imu_topic'])]))
    return actions


def _names(text, name, what, example):
    """Return the YAML list (or single name) ``text`` as a list of strings."""
    names = yaml.safe_load(text)
    names = [names] if isinstance(names, str) else names
    if not isinstance(names, list) or not all(isinstance(t, str) for t in names):
        raise ValueError(f'{name}:={text} is not a list of {what}, e.g. "{example}"')
    return names


def _number(text, name, lo, hi, zero=False):
    try:
        x = float(text)
    except ValueError:
        x = float('nan')
    if not (lo <= x <= hi or (zero and x == 0.0)):
        raise ValueError(f'{name}:={text} must be a number in {lo:g}..{hi:g}'
                         + (' (or 0)' if zero else ''))
    return x


def _warn_unapplied(context, params, name):
    """Print which given launch arguments are parameters of node ``name`` it will not get."""
    try:
        with open(params) as f:
            declared = yaml.safe_load(f) or {}
        keys = set((declared.get(name) or {}).get('ros__parameters') or {})
    except (OSError, yaml.YAMLError, AttributeError):
        return
    ours = {a for a, _, _ in ARGUMENTS}
    given = sorted(k for k in context.launch_configurations if k in keys and k not in ours)
    if given:
        print(f'[thermal_imu_calib.launch.py] warning: {", ".join(given)} given as launch '
              f'argument(s) but not applied to {name}: this launch file takes only '
              f'{", ".join(sorted(ours))}. Set node parameters in a copy of {params} '
              '(params_file:=FILE) or with ros2 param set.', file=sys.stderr, flush=True)


def generate_launch_description():
    """Return the argument declarations and the nodes built from them."""
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=desc)
         for name, default, desc in ARGUMENTS] + [OpaqueFunction(function=make_nodes)])
