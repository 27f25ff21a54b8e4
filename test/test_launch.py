"""The launch file's arguments, remappings and parameters, with plain pytest.

``launch_ros`` has no PyPI wheel here, so a minimal fake ``launch_ros`` (and ``launch``
where it is missing too) is injected into sys.modules: its Node records the keyword
arguments. The real ``launch`` is used when it imports: DeclareLaunchArgument,
OpaqueFunction and LaunchConfiguration are then the real ones.
"""

import importlib.util
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                'bench'))
from launch_nodes import stand_ins  # noqa: E402

LAUNCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'launch',
                      'thermal_imu_calib.launch.py')


@pytest.fixture
def launch_module(monkeypatch):
    """Import the launch file with a recording launch_ros.actions.Node (bench/launch_nodes)."""
    fakes = stand_ins()
    for name in ('launch_ros', 'launch_ros.actions'):
        monkeypatch.setitem(sys.modules, name, fakes[name])
    try:
        import launch
        real = hasattr(launch, 'LaunchDescription')   # not the repository's launch/ folder
    except ImportError:
        real = False
    if not real:
        for name in ('launch', 'launch.actions', 'launch.substitutions'):
            monkeypatch.setitem(sys.modules, name, fakes[name])
    spec = importlib.util.spec_from_file_location('thermal_imu_calib_launch', LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.REAL_LAUNCH = real
    return mod


def _resolve(mod, undeclared=None, **given):
    """Build the description, apply ``name:=value`` arguments, return (declared, nodes).

    ``undeclared`` (dict): more launch configurations, as ``ros2 launch`` keeps arguments no
    launch file declares (or a parent launch file's).
    """
    import launch
    desc = mod.generate_launch_description()
    declared = {e.name: e for e in desc.entities if hasattr(e, 'default_value')}
    context = launch.LaunchContext()
    for name, arg in declared.items():
        default = arg.default_value
        if not isinstance(default, str):       # real launch: a list of substitutions
            default = ''.join(s.perform(context) for s in default)
        context.launch_configurations[name] = given.get(name, default)
    context.launch_configurations.update(undeclared or {})
    opaque = [e for e in desc.entities if not hasattr(e, 'default_value')]
    assert len(opaque) == 1
    fn = getattr(opaque[0], 'function', None) or opaque[0]._OpaqueFunction__function
    return declared, [n.kwargs for n in fn(context)]


def test_arguments_declared(launch_module):
    declared, nodes = _resolve(launch_module)
    assert set(declared) == {'namespace', 'imu_topic', 'temperature_topics',
                             'temperature_types', 'params_file',
                             'calibration_file', 'use_sim_time', 'gravity', 'latitude',
                             'lifelong', 'cmd_vel_topic', 'odom_topic', 'still_topic',
                             'nodes'}
    assert [n['executable'] for n in nodes] == ['compensator_node', 'calibrator_node']
    for n in nodes:
        assert n['remappings'] == [('imu/data_raw', 'imu/data_raw')]
        assert n['namespace'] == ''
        params_file, overrides = n['parameters']
        assert os.path.basename(params_file) in ('compensator.yaml', 'calibrator.yaml')
        assert os.path.isfile(params_file)
        assert overrides == {'use_sim_time': False}


def test_imu_topic_and_overrides(launch_module):
    _, nodes = _resolve(launch_module, imu_topic='/my_imu/data_raw', namespace='left',
                        temperature_topics='[/left/temp, /left/gyro_resonance]',
                        calibration_file='~/cal.yaml', use_sim_time='true',
                        params_file='/tmp/p.yaml', nodes='compensator')
    assert len(nodes) == 1
    n = nodes[0]
    assert n['name'] == 'thermal_imu_compensator' and n['namespace'] == 'left'
    assert n['remappings'] == [('imu/data_raw', '/my_imu/data_raw')]
    assert n['parameters'] == ['/tmp/p.yaml', {
        'use_sim_time': True, 'temperature_topics': ['/left/temp', '/left/gyro_resonance'],
        'calibration_file': os.path.expanduser('~/cal.yaml')}]


def _start(ros, described):
    """Start the node a launch description entry describes, with its parameters."""
    import importlib
    from rclpy.parameter import Parameter
    params_file, overrides = described['parameters']
    module = importlib.import_module('thermal_imu_calib.nodes.' + described['executable'][:-5])
    cls = {'compensator_node': 'CompensatorNode', 'calibrator_node': 'CalibratorNode'}
    return ros.add(getattr(module, cls[described['executable']])(
        context=ros.context, cli_args=['--ros-args', '--params-file', params_file],
        parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()]))


def test_no_temperature_topics(launch_module, ros, tmp_path, monkeypatch):
    """``temperature_topics:='[]'`` starts both nodes without a thermal input."""
    _, nodes = _resolve(launch_module, temperature_topics='[]')
    monkeypatch.setenv('HOME', str(tmp_path))
    for n in nodes:
        assert n['parameters'][1]['temperature_topics'] == ['']
        assert _start(ros, n).temperature_topics == []


def test_a_headerless_temperature_type_reaches_both_nodes(launch_module, ros, tmp_path,
                                                          monkeypatch):
    """``temperature_types:='[std_msgs/msg/Float32]'`` (the um6/um7 drivers): both nodes
    subscribe imu/temperature as std_msgs/Float32, as the wrong-type hint tells."""
    _, nodes = _resolve(launch_module, temperature_types='[std_msgs/msg/Float32]')
    monkeypatch.setenv('HOME', str(tmp_path))
    for n in nodes:
        assert n['parameters'][1]['temperature_types'] == ['std_msgs/msg/Float32']
        subs = {s.topic_name: s.msg_type.__name__ for s in _start(ros, n).subscriptions}
        assert subs['/imu/temperature'] == 'Float32', subs


def _assert_follows_um7_float32(node):
    """``node`` subscribes /imu/temperature as Float32, followed from /um7_driver's."""
    subs = {s.topic_name: s.msg_type.__name__ for s in node.subscriptions}
    assert subs['/imu/temperature'] == 'Float32', subs
    assert node.type_follower.types == ['std_msgs/msg/Float32']
    note, = node.type_follower.notes
    assert note.startswith('/imu/temperature is published as std_msgs/msg/Float32 by '
                           '/um7_driver, not sensor_msgs/msg/Temperature'), note


def test_both_nodes_in_one_process_follow_a_float32_temperature(
        launch_module, ros, tmp_path, monkeypatch, request):
    """Both nodes with the shipped types in one context (``bringup``: one DDS participant,
    which refuses a second type on a topic) and a um7 driver publishing std_msgs/Float32 on
    imu/temperature: both re-subscribe as Float32, switched together (``thermal_types``)."""
    from std_msgs.msg import Float32
    from conftest import other_participant, wait_for
    _, nodes = _resolve(launch_module)
    monkeypatch.setenv('HOME', str(tmp_path))
    started = [_start(ros, n) for n in nodes]
    assert len(started) == 2
    pub = other_participant(request, 'um7_driver').create_publisher(
        Float32, '/imu/temperature', 10)
    wait_for(lambda: pub.get_subscription_count() >= 2
             and all(n.type_follower.notes for n in started), 60,
             lambda: f'both nodes to subscribe as Float32 '
                     f'({[n.type_follower.types for n in started]})')
    for node in started:
        _assert_follows_um7_float32(node)


def test_both_nodes_in_one_process_follow_a_late_float32_temperature(
        launch_module, ros, tmp_path, monkeypatch, request):
    """Both launched nodes in one context, the IMU published without a temperature until the
    calibrator decides to collect without one (``absent_inputs``); then a um7 driver starts
    publishing std_msgs/Float32 on imu/temperature: the compensator's input and the
    calibrator's watched one are re-subscribed as Float32 together (one participant refuses
    two types on a topic), and the calibrator takes the input at its first reading
    (``late_inputs``)."""
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Float32
    from conftest import other_participant, replay_flow, wait_for
    from thermal_imu_calib import sim
    from thermal_imu_calib.nodes import absent_inputs
    monkeypatch.setattr(absent_inputs, 'GRACE_S', 1.0)
    _, nodes = _resolve(launch_module)
    monkeypatch.setenv('HOME', str(tmp_path))
    comp, calib = [_start(ros, n) for n in nodes]
    driver = other_participant(request, 'imu_driver')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    wait_for(lambda: imu_pub.get_subscription_count() >= 2, 60, 'both nodes on the IMU')
    imu = sim.simulate('demo', 5, hold_s=(14.0, 15.0), transition_s=(1.5, 2.0),
                       repetitions=1).imu()
    sent = replay_flow(imu_pub, imu.slice(slice(0, 4000)), [], 2000.0,
                       lambda: calib.progress()['imu_received'], what='the calibrator input')
    wait_for(lambda: calib.progress()['imu_received'] >= sent and calib.k == 0, 60,
             'the decision without a temperature')
    pub = other_participant(request, 'um7_driver').create_publisher(
        Float32, '/imu/temperature', 10)
    wait_for(lambda: pub.get_subscription_count() >= 2, 60,
             lambda: f'both nodes to subscribe as Float32 '
                     f'({comp.type_follower.types}, {calib._late_inputs.types})')
    pub.publish(Float32(data=24.0))
    # the adoption's note is its last step (the node's k changes first): wait on it
    wait_for(lambda: calib.k == 1 and [n for n in calib.input_notes()
                                       if 'the first reading came' in n], 60,
             'the calibrator to take the late temperature')
    assert calib._clocks.bare == [True]
    for node in (comp, calib):
        _assert_follows_um7_float32(node)


def test_both_nodes_follow_a_temperature_under_another_name(
        launch_module, ros, tmp_path, monkeypatch, request):
    """Both launched nodes, a driver publishing its temperature on /imu/temp (the IMU on
    imu/data_raw, nothing on the shipped imu/temperature): the calibrator subscribes
    /imu/temp, as calibrate picks a log's temperature, and calibrates with it; the
    compensator takes that calibration by subscribing its input (``topic_follower``) and
    compensates."""
    from sensor_msgs.msg import Imu, Temperature
    from std_srvs.srv import Trigger
    from conftest import other_participant, replay_flow, wait_for
    from thermal_imu_calib import sim
    _, nodes = _resolve(launch_module)
    monkeypatch.setenv('HOME', str(tmp_path))
    comp, calib = [_start(ros, n) for n in nodes]
    driver = other_participant(request, 'imu_driver')
    imu_pub = driver.create_publisher(Imu, 'imu/data_raw', 1000)
    temp_pub = driver.create_publisher(Temperature, '/imu/temp', 100)
    wait_for(lambda: temp_pub.get_subscription_count() >= 1
             and imu_pub.get_subscription_count() >= 2, 60,
             lambda: f'the calibrator to follow /imu/temp ({calib.temperature_topics})')
    assert calib.temperature_topics == ['/imu/temp']
    assert comp.temperature_topics == ['imu/temperature'] and comp._active is None
    rec = sim.simulate('demo', 5, hold_s=(14.0, 15.0), transition_s=(1.5, 2.0),
                       repetitions=1)
    (_, tc), = rec.temperatures.items()
    replay_flow(imu_pub, rec.imu(), [(temp_pub, tc.stamp_ns, tc.temperature)], 2000.0,
                lambda: calib.progress()['imu_received'], what='the calibrator input',
                readings=lambda: calib.progress()['temperature_readings'])
    resp = ros.call(ros.node('caller'), Trigger, '/thermal_imu_calibrator/calibrate',
                    timeout=180)
    assert resp.success, resp.message
    wait_for(lambda: comp._active is not None, 60,
             lambda: f'the compensator to take the calibration ({comp.last_rejection})')
    assert comp.temperature_topics == ['/imu/temp']
    assert comp._active.calibration.temperature_topics == ['/imu/temp']
    # more data (stamped later: a copy of what was passed through would be taken for the
    # node's own output coming back), compensated with the readings from /imu/temp
    from thermal_imu_calib.io.columns import ImuColumns
    tail = rec.imu().slice(slice(-200, None))
    shift = int(rec.imu().stamp_ns[-1] - rec.imu().stamp_ns[0]) + 10 ** 9
    tail = ImuColumns(tail.stamp_ns + shift, tail.accel, tail.gyro, tail.frame_id)
    m = tc.stamp_ns >= tail.stamp_ns[0] - shift
    replay_flow(imu_pub, tail, [(temp_pub, tc.stamp_ns[m] + shift, tc.temperature[m])],
                2000.0, lambda: comp.counts['received'], what='the compensator input')
    wait_for(lambda: comp.counts['compensated'] >= 100, 60,
             lambda: f'compensated messages ({comp.counts})')


def test_gravity_and_latitude_reach_the_calibrator(launch_module, ros, tmp_path,
                                                   monkeypatch, capfd):
    # the new user sets only gravity; ros2 launch keeps an undeclared argument
    # without a word, so gravity:= must be declared, and a node parameter given as an
    # argument this file does not take is named in a warning
    _, nodes = _resolve(launch_module, gravity='9.81')
    comp, calib = nodes
    assert 'gravity' not in comp['parameters'][1]
    assert calib['parameters'][1]['gravity'] == 9.81
    assert 'use_latitude' not in calib['parameters'][1]
    _, (calib,) = _resolve(launch_module, nodes='calibrator', latitude='48.1')
    assert calib['parameters'][1]['latitude'] == 48.1
    assert calib['parameters'][1]['use_latitude'] is True
    _, (comp, calib) = _resolve(launch_module, lifelong='true', cmd_vel_topic='/cmd_vel')
    assert calib['parameters'][1]['lifelong'] is True
    assert calib['parameters'][1]['cmd_vel_topic'] == '/cmd_vel'
    assert 'lifelong' not in comp['parameters'][1]
    monkeypatch.setenv('HOME', str(tmp_path))

    def start(**arguments):      # the calibrator as the launch file describes it
        _, (calib,) = _resolve(launch_module, nodes='calibrator', **arguments)
        return _start(ros, calib)
    assert start(gravity='9.81').gravity == 9.81
    node = start(lifelong='true', cmd_vel_topic='/cmd_vel')
    assert node.lifelong is not None
    assert '/cmd_vel' in {s.topic_name for s in node.subscriptions}
    capfd.readouterr()
    # order: a calibrator parameter; robot_model: a parent launch file's argument
    _, nodes = _resolve(launch_module, undeclared={'order': '1', 'robot_model': 'x'})
    err = capfd.readouterr().err
    assert 'order given as launch argument(s) but not applied to thermal_imu_calibrator' in err
    assert 'robot_model' not in err and 'params_file:=FILE' in err
    assert 'order' not in nodes[1]['parameters'][1]


@pytest.mark.parametrize('argument, value, says', [
    ('nodes', 'compensater', 'must name some of compensator, calibrator'),
    ('use_sim_time', 'maybe', 'not true or false'),
    ('temperature_topics', '{a: 1}', 'not a list of topics'),
    ('temperature_types', '[1]', 'not a list of message types'),
    ('gravity', '981', 'gravity:=981 must be a number in 9.7..9.9'),
    ('latitude', 'north', 'latitude:=north must be a number'),
    ('lifelong', 'on', 'lifelong:=on is not true or false')])
def test_bad_arguments_say_what_is_wrong(launch_module, argument, value, says):
    with pytest.raises(ValueError, match=says):
        _resolve(launch_module, **{argument: value})


def test_package_xml_declares_every_runtime_dependency():
    """Every install_requires entry has an exec_depend rosdep key or is listed as keyless."""
    import re
    import xml.etree.ElementTree as ET
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    deps = {e.text for e in ET.parse(os.path.join(root, 'package.xml')).getroot()
            .iter('exec_depend')}
    keys = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'PyYAML': 'python3-yaml',
            'scikit-learn': 'python3-sklearn', 'tqdm': 'python3-tqdm',
            'matplotlib': 'python3-matplotlib'}
    keyless = {'rosbags', 'mcap', 'mcap-ros2-support', 'allantools', 'dask', 'setuptools'}
    text = open(os.path.join(root, 'setup.py')).read()
    block = text[text.index('install_requires=['):text.index(']', text.index('install_requires'))]
    reqs = {re.split(r'[<>=\[ ]', r)[0] for r in re.findall(r"'([^']+)'", block)}
    assert reqs - set(keys) - keyless == set(), 'a new dependency needs a rosdep key or a note'
    assert set(keys.values()) <= deps
    assert {'rclpy', 'launch', 'launch_ros', 'ament_index_python', 'sensor_msgs'} <= deps
    notes = open(os.path.join(root, 'docs', 'export.md')).read()
    assert all(k in notes for k in keyless - {'setuptools'})
