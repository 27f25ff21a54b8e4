"""The adapters stay thin: the command line, the node and the fleet share one calibrate.

``thermal-imu-calib calibrate`` (``cli.commands.cmd_calibrate``), the calibrator node's
``~/calibrate`` (``CalibratorNode._estimate``) and the fleet's reduce step
(``app.fleet.calibrate_unit``) each hand their settings to
``app.calibrate.calibrate_collected``; the command line and the node build those settings
as one ``CalibrateSettings``. Checked twice: on the source (``ast``: what the adapter
function calls, and that it stays a few statements), and at run time (a spy on
``calibrate_collected`` sees the CLI on a real log and the node on its live collection).
"""

import ast
import os

from _motion_data import recording

from thermal_imu_calib.app import calibrate as app_calibrate
from thermal_imu_calib.app.calibrate import CalibrateSettings
from thermal_imu_calib.cli import main
from thermal_imu_calib.cli.calibrate import settings_from_args
from thermal_imu_calib.collection.collected import Collected

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                    'thermal_imu_calib')
#: most statements (docstring aside, nested ones counted) an adapter function may hold
MAX_STATEMENTS = 12


def _function(relpath, name, cls=None):
    tree = ast.parse(open(os.path.join(ROOT, relpath)).read())
    scope = tree
    if cls:
        scope = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
    return next(n for n in scope.body
                if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == name)


def _calls(fn):
    """Return the dotted names of every call in ``fn`` (``a.b`` for ``a.b(...)``)."""
    out = []
    for node in ast.walk(fn):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name):
                out.append(f.id)
            elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
                out.append(f'{f.value.id}.{f.attr}')
    return out


def _statements(fn):
    body = fn.body[1:] if ast.get_docstring(fn) else fn.body
    return sum(isinstance(n, ast.stmt) for s in body for n in ast.walk(s))


def test_cmd_calibrate_is_a_few_lines_over_calibrate_logs():
    fn = _function('cli/commands.py', 'cmd_calibrate')
    calls = _calls(fn)
    assert calls.count('app_calibrate.calibrate_logs') == 1, calls
    assert 'settings_from_args' in calls, 'the options must become one CalibrateSettings'
    assert _statements(fn) <= MAX_STATEMENTS, f'cmd_calibrate has {_statements(fn)} statements'
    # and the use case it calls is the one the node and the fleet call
    assert 'calibrate_collected' in _calls(_function('app/calibrate.py', 'calibrate_logs'))


def test_the_node_calibrate_callback_is_a_few_lines_over_calibrate_collected():
    fn = _function('nodes/calibrator.py', '_estimate', 'CalibratorNode')
    calls = _calls(fn)
    assert calls.count('app.calibrate_collected') == 1, calls
    assert _statements(fn) <= MAX_STATEMENTS, f'_estimate has {_statements(fn)} statements'
    callback = _function('nodes/calibrator.py', '_on_calibrate', 'CalibratorNode')
    assert 'self._estimate' in ast.unparse(callback)


def test_the_node_progress_asks_the_calibrate_use_case():
    """~/progress says what calibrate would do through app.calibrate, with its settings."""
    calls = _calls(_function('nodes/calibrator.py', 'progress', 'CalibratorNode'))
    assert 'app.readiness' in calls and 'readiness' not in calls, calls


def test_the_fleet_reduce_is_the_same_calibrate():
    assert _calls(_function('app/fleet.py', 'calibrate_unit')) == ['calibrate_collected']
    assert 'app_fleet.calibrate_unit' in ast.unparse(
        _function('cli/fleet.py', 'cmd_fleet_calibrate'))


def test_cli_and_node_build_one_calibrate_settings():
    for path, name in (('cli/calibrate.py', 'settings_from_args'),
                       ('nodes/calibrator_params.py', 'settings')):
        ret = [n for n in _function(path, name).body if isinstance(n, ast.Return)]
        assert len(ret) == 1 and ast.unparse(ret[0].value.func) == 'CalibrateSettings', (
            f'{path}:{name} must return one CalibrateSettings(...)')


def _spy(monkeypatch):
    seen = []
    real = app_calibrate.calibrate_collected

    def spy(settings, collected, *args, **kw):
        seen.append((settings, collected))
        return real(settings, collected, *args, **kw)
    monkeypatch.setattr(app_calibrate, 'calibrate_collected', spy)
    return seen


def test_the_cli_runs_calibrate_collected_with_its_settings(tmp_path, monkeypatch):
    seen = _spy(monkeypatch)
    log = recording('demo', 3, repetitions=1).write(str(tmp_path / 'log.mcap'))
    argv = ['calibrate', log, '--model', 'field', '--order', '1', '-o', str(tmp_path / 'c.yaml')]
    assert main(argv) == 0
    from thermal_imu_calib.cli.commands import build_parser
    (settings, collected), = seen
    assert settings == settings_from_args(build_parser().parse_args(argv))
    assert settings.model == 'field' and settings.order == 1
    assert len(collected) == 1 and isinstance(collected[0], Collected)
    assert len(collected[0].windows) > 0
    assert os.path.isfile(tmp_path / 'c.yaml')


def test_the_node_runs_calibrate_collected_with_its_settings(ros, tmp_path, monkeypatch):
    from rclpy.parameter import Parameter
    from thermal_imu_calib.nodes.calibrator import CalibratorNode
    monkeypatch.setenv('HOME', str(tmp_path))
    seen = _spy(monkeypatch)
    node = ros.add(CalibratorNode(context=ros.context, parameter_overrides=[
        Parameter('temperature_topics', value=['']), Parameter('model', value='field')]))
    ok, message = node._estimate(*node.snapshot())
    (settings, collected), = seen
    assert settings == node.settings()
    assert settings == CalibrateSettings(model='field')
    assert len(collected) == 1 and isinstance(collected[0], Collected)
    # nothing collected: the shared use case refuses, and the node says so
    assert not ok and message.startswith(('refused:', 'failed:')), message
