"""One set of defaults: the shipped config files repeat the code's, the CLI and node share them.

``config/<node>.yaml`` is what ``ros2 launch`` loads by default. A value there that differs
from the node's declared default silently gives the ROS path other settings than the
command line (the old detector settings found no holds where ``calibrate`` found 15). Each
node is created with no parameters (HOME in a temporary folder, so nothing of the user's is
touched) and every declared value is compared with the file's; a differing value is allowed
only on a line whose comment says ``differs:`` and why.
"""

import os
import re

import pytest
import yaml

from thermal_imu_calib.app.calibrate import CalibrateSettings
from thermal_imu_calib.cli.calibrate import calibrate_defaults, settings_from_args

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NODES = {'calibrator.yaml': ('thermal_imu_calib.nodes.calibrator', 'CalibratorNode'),
         'compensator.yaml': ('thermal_imu_calib.nodes.compensator', 'CompensatorNode')}
#: parameters every rclpy node declares itself
BUILTIN = {'use_sim_time', 'start_type_description_service'}


def _config(name):
    path = os.path.join(ROOT, 'config', name)
    text = open(path).read()
    (node_name, body), = yaml.safe_load(text).items()
    explained = {m.group(1) for m in re.finditer(r'^\s+(\w+):.*#.*differs:', text, re.M)}
    return node_name, body['ros__parameters'], explained


@pytest.mark.parametrize('name', sorted(NODES))
def test_config_file_equals_the_code_defaults(ros, tmp_path, monkeypatch, name):
    import importlib
    monkeypatch.setenv('HOME', str(tmp_path))
    module, cls = NODES[name]
    node_name, params, explained = _config(name)
    node = ros.add(getattr(importlib.import_module(module), cls)(context=ros.context))
    assert node.get_name() == node_name
    declared = {n: p.value for n, p in node._parameters.items() if n not in BUILTIN}
    unknown = set(params) - set(declared)
    assert not unknown, f'{name} sets parameters the node does not declare: {sorted(unknown)}'
    missing = set(declared) - set(params)
    assert not missing, f'{name} leaves out declared parameters: {sorted(missing)}'
    differ = {n: (params[n], declared[n]) for n in params
              if n not in explained and _normal(params[n]) != _normal(declared[n])}
    assert not differ, (f'{name}: value (file, code default) differs without a "differs:" '
                        f'comment: {differ}')


def _normal(v):
    if isinstance(v, (list, tuple)):
        return [_normal(x) for x in v]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return v
    return float(v)


def test_command_line_defaults_are_the_shared_settings():
    """``calibrate`` without options gives exactly CalibrateSettings() (gravity aside)."""
    assert settings_from_args(calibrate_defaults()) == CalibrateSettings()


def test_node_settings_without_parameters_are_the_shared_settings(ros, tmp_path, monkeypatch):
    """The calibrator's parameters at their defaults (no temperature topic) give the same."""
    from thermal_imu_calib.nodes.calibrator import CalibratorNode
    from rclpy.parameter import Parameter
    monkeypatch.setenv('HOME', str(tmp_path))
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('temperature_topics', value=[''])]))
    assert node.temperature_topics == []
    assert node.settings() == CalibrateSettings()


def test_the_temperature_gap_is_one_default_on_every_path(ros, tmp_path, monkeypatch):
    """calibrate's --max-gap, compensate's --temperature-timeout (its --max-gap) and both
    nodes' temperature_timeout: a 0.25-Hz temperature gave live != offline with 2 s in the
    calibrator (docs/bad_input.md)."""
    import importlib
    from thermal_imu_calib.cli.commands import build_parser
    monkeypatch.setenv('HOME', str(tmp_path))
    gap = CalibrateSettings().max_gap_s
    assert calibrate_defaults().max_gap == gap
    args = build_parser().parse_args(['compensate', 'in.mcap', '--calibration', 'c.yaml',
                                      '-o', 'out.mcap'])
    assert args.temperature_timeout is None and args.max_gap == gap   # None: --max-gap
    for name in sorted(NODES):
        module, cls = NODES[name]
        node = ros.add(getattr(importlib.import_module(module), cls)(context=ros.context))
        assert node.temperature_timeout == gap, name
