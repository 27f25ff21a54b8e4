"""Import layering: data flows one way and the core imports no ROS (docs/architecture.md).

Every module of the package is parsed with ``ast`` (nothing is imported) and given a layer;
a module may import only from its own layer or the ones below. The test fails on an upward
import, on an import cycle between modules, on rclpy (or any ROS client) outside the
adapters, and on a module over 500 lines whose docstring has no line starting "Cohesive:"
saying why it is one piece.
"""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PKG = 'thermal_imu_calib'
MAX_LINES = 500

#: layers, bottom first; a module's layer is that of its longest matching prefix
LAYERS = [
    ('helpers', ['gravity', 'input_units', 'thermal_input', 'rotations']),
    ('io', ['io']),
    ('models', ['models']),
    ('calibration', ['calibration', 'formats']),
    ('collection', ['collection']),
    ('estimation', ['estimation']),
    ('selection', ['selection']),
    # below the use cases: the simulator, the report pages, the fleet's inputs and registry
    ('support', ['sim', 'report', 'fleet']),
    # one module per use case (calibrate, collect, compensate, evaluate, noise, fleet steps,
    # lifelong calibration)
    ('app', ['app', 'lifelong']),
    # parse, call one use case, format: the command line, the ROS nodes, the Dask runner
    ('adapters', ['cli', 'nodes', 'fleet.runner', 'report.cli']),
    ('package', ['']),
]
#: layers that must not import a ROS client library
NO_ROS = {'helpers', 'io', 'models', 'calibration', 'collection', 'estimation', 'selection',
          'support', 'app'}
ROS_MODULES = ('rclpy', 'rosidl_runtime_py', 'launch', 'launch_ros')


def _modules():
    out = {}
    base = os.path.join(ROOT, PKG)
    for dp, dn, fn in os.walk(base):
        dn[:] = [d for d in dn if d != '__pycache__']
        for f in fn:
            if f.endswith('.py'):
                parts = os.path.relpath(os.path.join(dp, f), base)[:-3].split(os.sep)
                is_pkg = parts[-1] == '__init__'
                if is_pkg:
                    parts = parts[:-1]
                out['.'.join(parts)] = (os.path.join(dp, f), is_pkg)
    return out


def _layer(mod):
    best, rank = None, None
    for i, (name, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            top = mod.split('.')[0]
            if p.endswith('*'):
                hit = top.startswith(p[:-1])
            else:
                hit = mod == p or (p and mod.startswith(p + '.'))
            if hit and (best is None or len(p) > len(best)):
                best, rank = p, i
    return rank


def _imports(mod, path, is_pkg, modules):
    """Package modules imported by ``mod`` (function-level imports included) and ROS hits."""
    tree = ast.parse(open(path).read(), path)
    deps, ros = set(), set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split('.')[0] in ROS_MODULES:
                    ros.add(a.name)
                if a.name.startswith(PKG + '.'):
                    names.append((a.name[len(PKG) + 1:], None))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split('.') if mod else []
                if not is_pkg:
                    base = base[:-1]
                up = node.level - 1
                base = base[:len(base) - up] if up else base
                target = '.'.join(base + ([node.module] if node.module else []))
            elif (node.module or '').split('.')[0] in ROS_MODULES:
                ros.add(node.module)
                continue
            elif node.module == PKG or (node.module or '').startswith(PKG + '.'):
                target = node.module[len(PKG) + 1:]
            else:
                continue
            for a in node.names:
                sub = f'{target}.{a.name}' if target else a.name
                names.append((sub, None) if sub in modules else (target, None))
        for target, _ in names:
            if target and target != mod:   # the package root only holds the version
                deps.add(target)
    return deps, ros


def _graph():
    modules = _modules()
    graph, ros = {}, {}
    for mod, (path, is_pkg) in modules.items():
        graph[mod], ros[mod] = _imports(mod, path, is_pkg, modules)
    return modules, graph, ros


def test_every_module_has_a_layer():
    modules, _, _ = _graph()
    missing = sorted(m for m in modules if _layer(m) is None)
    assert not missing, (f'modules without a layer: {missing}; add their prefix to LAYERS '
                         f'in test/test_layering.py and to docs/architecture.md')


def test_every_layer_prefix_names_a_module():
    """No stale prefix: a layer names modules that exist (a moved module moves its prefix)."""
    modules = _modules()
    stale = [p for _, prefixes in LAYERS for p in prefixes
             if p and not any(m == p or m.startswith(p + '.') for m in modules)]
    assert not stale, f'LAYERS names modules that do not exist: {stale}'


def test_no_upward_imports():
    modules, graph, _ = _graph()
    bad = []
    for mod, deps in graph.items():
        lm = _layer(mod)
        for d in deps:
            ld = _layer(d)
            if lm is not None and ld is not None and ld > lm:
                bad.append(f'{mod} ({LAYERS[lm][0]}) imports {d} ({LAYERS[ld][0]})')
    assert not bad, 'upward imports (move the code down or the import up):\n' + '\n'.join(
        sorted(bad))


def test_no_import_cycles():
    _, graph, _ = _graph()
    index, low, stack, on, sccs = {}, {}, [], set(), []

    def visit(v):      # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not sccs, f'import cycles between modules: {sccs}'


def test_core_imports_no_ros():
    _, _, ros = _graph()
    bad = {m: sorted(r) for m, r in ros.items()
           if r and _layer(m) is not None and LAYERS[_layer(m)][0] in NO_ROS}
    assert not bad, f'ROS imported below the adapters (move it to nodes/): {bad}'


def test_modules_are_short_or_say_why():
    modules = _modules()
    long = []
    for mod, (path, _) in sorted(modules.items()):
        text = open(path).read()
        n = text.count('\n')
        if n <= MAX_LINES:
            continue
        doc = ast.get_docstring(ast.parse(text)) or ''
        if not any(line.strip().startswith('Cohesive:') for line in doc.splitlines()):
            long.append(f'{mod}: {n} lines')
    assert not long, ('modules over 500 lines without a "Cohesive:" docstring line saying why '
                      'they are one piece (or split them):\n' + '\n'.join(long))


def test_the_checker_sees_a_violation(tmp_path):
    """The rules can fail: an upward import and an rclpy import are both reported."""
    modules = {'io.fake': None, 'app.collect': None}
    path = tmp_path / 'fake.py'
    path.write_text('import rclpy\nfrom ..app.collect import collect_windows\n')
    deps, ros = _imports('io.fake', str(path), False, modules)
    assert deps == {'app.collect'} and ros == {'rclpy'}
    assert _layer('app.collect') > _layer('io.fake')


def test_the_compensator_node_starts_without_scipy():
    """The compensator (and ``compensate``) never fits: importing its node loads no scipy.

    scipy.special and scipy.optimize took about 0.8 of the node module's 1.4 s of import
    (``python -X importtime``); they are imported where a fit or a derived detector
    setting needs them (``collection.outliers``, ``collection.detector_config``).
    """
    import subprocess
    import sys
    code = ('import sys, thermal_imu_calib.nodes.compensator, thermal_imu_calib.app.compensate; '
            'print(sorted(m for m in sys.modules if m.split(".")[0] == "scipy"))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == '[]', out.stdout + out.stderr
