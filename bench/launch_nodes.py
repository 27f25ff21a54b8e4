"""Start the package's nodes as ``launch/thermal_imu_calib.launch.py`` describes them.

There is no ``ros2 launch`` (launch/launch_ros wheels) here, so the launch file is imported
with a minimal stand-in for ``launch``/``launch_ros`` (as ``test/test_launch.py`` does): its
``make_nodes`` is run on the given ``name:=value`` arguments and each Node's keyword
arguments are turned into the command line launch_ros would run:
``<executable> --ros-args -r __node:=NAME [-r __ns:=/NS] --params-file FILE ... -r FROM:=TO``,
a dict of parameters written to a temporary params file under ``/**`` (launch_ros does the
same with dict parameters).
"""

import importlib.util
import os
import sys
import types

import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAUNCH = os.path.join(ROOT, 'launch', 'thermal_imu_calib.launch.py')


class _Context:
    def __init__(self, values):
        self.launch_configurations = dict(values)


def stand_ins():
    """Return sys.modules entries for launch, launch.actions, launch.substitutions, launch_ros."""
    launch = types.ModuleType('launch')
    actions = types.ModuleType('launch.actions')
    subs = types.ModuleType('launch.substitutions')
    ros = types.ModuleType('launch_ros')
    ros_actions = types.ModuleType('launch_ros.actions')

    class LaunchDescription:
        def __init__(self, entities):
            self.entities = list(entities)

    class DeclareLaunchArgument:
        def __init__(self, name, default_value='', description=''):
            self.name, self.default_value, self.description = name, default_value, description

    class OpaqueFunction:
        def __init__(self, function):
            self.function = function

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context.launch_configurations[self.name]

    class Node:
        def __init__(self, **kwargs):
            self.kwargs = kwargs

    class LaunchContext(_Context):
        def __init__(self):
            super().__init__({})

    launch.LaunchDescription, launch.LaunchContext = LaunchDescription, LaunchContext
    actions.DeclareLaunchArgument, actions.OpaqueFunction = DeclareLaunchArgument, OpaqueFunction
    subs.LaunchConfiguration = LaunchConfiguration
    ros_actions.Node = Node
    launch.actions, launch.substitutions, ros.actions = actions, subs, ros_actions
    return {'launch': launch, 'launch.actions': actions, 'launch.substitutions': subs,
            'launch_ros': ros, 'launch_ros.actions': ros_actions}


def resolve(**given):
    """Return the Node keyword arguments the launch file makes for ``name=value`` arguments."""
    saved = {k: sys.modules.get(k) for k in stand_ins()}
    sys.modules.update(stand_ins())
    try:
        spec = importlib.util.spec_from_file_location('thermal_imu_calib_launch_bench', LAUNCH)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        desc = mod.generate_launch_description()
        declared = {e.name: e.default_value for e in desc.entities
                    if hasattr(e, 'default_value')}
        unknown = set(given) - set(declared)
        if unknown:
            raise ValueError(f'not launch arguments: {sorted(unknown)}')
        ctx = _Context({**declared, **given})
        fn, = [e.function for e in desc.entities if hasattr(e, 'function')]
        return [n.kwargs for n in fn(ctx)]
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


def command(node, workdir, extra=None, bindir=None):
    """Return the argv launch_ros would run for one Node's kwargs.

    ``extra`` (dict) is appended as one more parameters dict (e.g. ``gravity``), the way a
    user adds a parameter to the launch description's list.
    """
    bindir = bindir or os.path.dirname(sys.executable)
    argv = [os.path.join(bindir, node['executable']), '--ros-args',
            '-r', f'__node:={node["name"]}']
    if node.get('namespace'):
        argv += ['-r', f'__ns:=/{node["namespace"].strip("/")}']
    params = list(node.get('parameters', [])) + ([extra] if extra else [])
    for i, p in enumerate(params):
        if isinstance(p, dict):
            path = os.path.join(workdir, f'{node["name"]}_params_{i}.yaml')
            with open(path, 'w') as f:
                yaml.safe_dump({'/**': {'ros__parameters': p}}, f)
            p = path
        argv += ['--params-file', str(p)]
    for a, b in node.get('remappings', []):
        argv += ['-r', f'{a}:={b}']
    return argv
