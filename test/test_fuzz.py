"""Hypothesis fuzzing of what hostile input reaches: loader, bag readers, node callbacks, CLI.

Targets: the calibration loader (YAML text, and parsed dicts), the log readers (mutated
bytes of a real MCAP and a real rosbag2 sqlite3 bag), the compensator's and calibrator's
callbacks (Imu, Temperature and calibration messages), the CLI's outputs against its
inputs (every writing subcommand, hostile paths: inputs, special files, foreign files,
paths inside input directories, the same path spelt another way) and the fleet's inputs
(sensor ids and hand-edited registry indexes). Allowed outcomes are
the documented refusals (CalibrationError, LogError); anything else is a crash. Every case
runs under a hard time limit (SIGALRM; a hang fails the case), and no compensated message
may carry NaN/Inf.

``make fuzz`` runs ``THERMAL_FUZZ_EXAMPLES=10000`` cases per target; the normal test run
takes a small sample (default 30 per target).
"""

import contextlib
import math
import os
import shutil
import signal

from hypothesis import HealthCheck, given, settings, strategies as st
import numpy as np
import pytest
import yaml

from _hostile import bad_calibrations, good_calibration, recording, write_bag
from thermal_imu_calib.calibration import Calibration, CalibrationError
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.log_info import LogError

EXAMPLES = int(os.environ.get('THERMAL_FUZZ_EXAMPLES', '30'))
#: per-case wall-clock limit, s (a loader case takes ~ms; a bag case ~50 ms)
CASE_LIMIT_S = float(os.environ.get('THERMAL_FUZZ_CASE_LIMIT_S', '10'))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=False,
                suppress_health_check=list(HealthCheck), print_blob=True)


class CaseTimeout(Exception):
    """A fuzz case ran longer than CASE_LIMIT_S: a hang."""


@contextlib.contextmanager
def time_limit(seconds=CASE_LIMIT_S):
    """Raise CaseTimeout in the main thread after ``seconds`` (SIGALRM, interval timer)."""
    def on_alarm(signum, frame):
        raise CaseTimeout(f'case exceeded {seconds} s')
    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ------------------------------------------------------------------ calibration loader
GOOD = good_calibration()
GOOD_TEXT = GOOD.to_yaml()
GOOD_DICT = GOOD.to_dict()
SEEDS = [t if isinstance(t, str) else t.decode('utf-8', 'replace')
         for k, (t, _) in bad_calibrations().items() if k != 'too_large'] + [GOOD_TEXT]
TOKENS = ['&a ', '*a', '&b [*a, *a, *a]', '[', ']', '{', '}', ': ', '- ', '\n', '  ', 'nan',
          '.nan', '.inf', '-.inf', '1e300', '-1e308', '0', '~', 'null', '!!binary aGVsbG8=',
          '!!python/object:os.system', '"', "'", '? ', '|', '>', '%YAML 1.1\n', '---\n',
          '...\n', '\t', '\x00', '\ufeff', 'garbage', 'true', '<<: *a', '!!set {a, b}',
          '2026-11-24', '0x1F', '1_000', '[' * 200]


def _check_accepted(cal):
    """An accepted calibration compensates finite samples anywhere in its valid range."""
    if cal.inputs:
        lo, hi = cal.valid_range[:, 0], cal.valid_range[:, 1]
        temps = lo + np.linspace(0, 1, 5)[:, None] * (hi - lo)
    else:
        temps = np.zeros((5, 0))
    res = cal.apply(np.tile([0.1, -0.2, 9.8], (5, 1)), np.full((5, 3), 0.01), temps)
    assert np.isfinite(res.accel).all() and np.isfinite(res.gyro).all()
    assert cal.id and Calibration.from_yaml(cal.to_yaml()).id == cal.id


def _load_text(text):
    with time_limit():
        try:
            cal = Calibration.from_yaml(text, 'fuzz')
        except CalibrationError as e:
            assert str(e).startswith('fuzz')
            return
        _check_accepted(cal)


@st.composite
def mutated_text(draw):
    text = draw(st.sampled_from(SEEDS))
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 40)))
        new = draw(st.one_of(st.sampled_from(TOKENS), st.text(max_size=20)))
        text = text[:i] + new + text[j:]
    return text


@FUZZ
@given(st.one_of(mutated_text(), st.text(max_size=400),
                 st.binary(max_size=400), st.sampled_from(SEEDS)))
def test_fuzz_loader_yaml_text(text):
    _load_text(text)


def _paths(d, prefix=()):
    yield prefix
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _paths(v, prefix + (i,))


PATHS = list(_paths(GOOD_DICT))[1:]
PLAIN = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=10),
              st.sampled_from([1e300, -1e300, math.nan, math.inf, -80.1, 200.1, 0, -1, 3])),
    lambda inner: st.one_of(st.lists(inner, max_size=6),
                            st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=20)


@st.composite
def mutated_dict(draw):
    import copy
    d = copy.deepcopy(GOOD_DICT)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        x = d
        try:
            for key in path[:-1]:
                x = x[key]
            if draw(st.booleans()) and isinstance(x, dict):
                x.pop(path[-1], None)
            else:
                x[path[-1]] = draw(PLAIN)
        except (KeyError, IndexError, TypeError):
            pass
    return d


@FUZZ
@given(st.one_of(mutated_dict(), PLAIN))
def test_fuzz_loader_dicts(d):
    with time_limit():
        try:
            cal = Calibration.from_dict(d, 'fuzz')
        except CalibrationError:
            return
        _check_accepted(cal)


# ------------------------------------------------------------------ bag readers
def _first(n):
    """Return a ``write_bag`` edit keeping the first ``n`` IMU samples and their temperatures."""
    def cut(a):
        m = int(np.searchsorted(a['temp_stamp_ns'], a['stamp_ns'][n - 1]))
        for k in ('stamp_ns', 'accel', 'gyro'):
            a[k] = a[k][:n]
        a['temp_stamp_ns'], a['temperature'] = a['temp_stamp_ns'][:m], a['temperature'][:m]
    return cut


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """Real logs, small: the first 2000 IMU samples of a simulated recording, both storages."""
    imu, temp = recording(8)
    d = tmp_path_factory.mktemp('fuzzbags')
    cut = _first(2000)
    mcap = write_bag(str(d / 'small.mcap'), imu, temp, cut)
    bag = write_bag(str(d / 'small_bag'), imu, temp, cut, storage='sqlite3')
    db3 = next(os.path.join(bag, n) for n in os.listdir(bag) if n.endswith('.db3'))
    return _Bags({'mcap': open(mcap, 'rb').read(), 'db3': open(db3, 'rb').read(), 'dir': d})


class _Bags(dict):
    """The fuzzed logs' bytes; a short repr keeps hypothesis' failure reports readable."""

    def __repr__(self):
        return f'<bags in {self["dir"]}>'


@st.composite
def mutation(draw):
    """Return a list of (kind, position fraction, bytes) edits of a file."""
    edits = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(['flip', 'flip', 'replace', 'truncate', 'insert', 'zero']))
        edits.append((kind, draw(st.floats(0, 1)), draw(st.binary(min_size=1, max_size=16))))
    return edits


def _mutate(data, edits):
    b = bytearray(data)
    for kind, frac, payload in edits:
        i = min(int(frac * len(b)), max(len(b) - 1, 0))
        if kind == 'flip' and b:
            b[i] ^= payload[0] or 1
        elif kind == 'replace':
            b[i:i + len(payload)] = payload
        elif kind == 'truncate':
            del b[i:]
        elif kind == 'insert':
            b[i:i] = payload
        elif kind == 'zero':
            b[i:i + 64 * len(payload)] = bytes(len(b[i:i + 64 * len(payload)]))
    return bytes(b)


def _read_everything(path):
    with time_limit():
        try:
            with open_log(path) as reader:
                reader.info()
                types = reader.topic_types()
                imu = [t for t, ty in types.items() if ty == 'sensor_msgs/msg/Imu']
                temps = [t for t, ty in types.items() if ty == 'sensor_msgs/msg/Temperature'
                         and t not in imu]
                for t in imu[:1]:
                    for chunk in reader.stream(t, temps, 500):
                        assert len(chunk.imu.accel) == len(chunk.imu.stamp_ns)
        except LogError as e:
            assert str(e).strip()


@FUZZ
@given(mutation())
def test_fuzz_mcap_reader(bags, edits):
    path = bags['dir'] / 'fuzz.mcap'
    path.write_bytes(_mutate(bags['mcap'], edits))
    _read_everything(str(path))


@FUZZ
@given(mutation())
def test_fuzz_db3_reader(bags, edits):
    path = bags['dir'] / 'fuzz.db3'
    path.write_bytes(_mutate(bags['db3'], edits))
    for extra in ('fuzz.db3-wal', 'fuzz.db3-shm', 'fuzz.db3-journal'):
        with contextlib.suppress(FileNotFoundError):
            (bags['dir'] / extra).unlink()
    _read_everything(str(path))


# ------------------------------------------------------------------ node callbacks
FLOATS = st.one_of(st.floats(), st.floats(-50, 50), st.sampled_from([0.0, 9.81, 1e30, -1e30]))
STAMPS = st.one_of(st.integers(0, 2 ** 31 - 1), st.integers(1_700_000_000, 1_700_000_100))
EVENTS = st.lists(st.one_of(
    st.tuples(st.just('imu'), STAMPS, st.integers(0, 999_999_999), st.lists(
        FLOATS, min_size=6, max_size=6)),
    st.tuples(st.just('temp'), STAMPS, st.integers(0, 999_999_999), FLOATS),
    st.tuples(st.just('cal'), st.one_of(mutated_text(), st.sampled_from(SEEDS)))),
    min_size=1, max_size=30)


@pytest.fixture(scope='module')
def nodes(tmp_path_factory):
    """A compensator (good calibration active) and a calibrator in their own context."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from thermal_imu_calib.nodes.calibrator import CalibratorNode
    from thermal_imu_calib.nodes.compensator import CompensatorNode
    d = tmp_path_factory.mktemp('fuzznodes')
    (d / 'cal.yaml').write_text(GOOD_TEXT)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ.get('ROS_DOMAIN_ID', '0')))
    comp = CompensatorNode(context=ctx, parameter_overrides=[
        Parameter('calibration_file', value=str(d / 'cal.yaml')),
        Parameter('despike', value=True)])
    calib = CalibratorNode(context=ctx, parameter_overrides=[
        Parameter('collection_file', value=str(d / 'collection.jsonl')),
        Parameter('calibration_file', value=str(d / 'out.yaml'))])
    published = []

    def check(msg):
        a, w = msg.linear_acceleration, msg.angular_velocity
        values = [a.x, a.y, a.z, w.x, w.y, w.z]
        assert all(math.isfinite(v) for v in values), f'published NaN/Inf: {values}'
        published.append(1)
    comp.pub.publish = check
    yield comp, calib, published
    comp.destroy_node()
    calib.destroy_node()
    ctx.try_shutdown()
    shutil.rmtree(d, ignore_errors=True)


@FUZZ
@given(EVENTS)
def test_fuzz_node_callbacks(nodes, events):
    from conftest import imu_msg, temperature_msg
    from std_msgs.msg import String
    comp, calib, _ = nodes
    with time_limit():
        for ev in events:
            if ev[0] == 'imu':
                stamp = ev[1] * 1_000_000_000 + ev[2]
                msg = imu_msg(stamp, ev[3][:3], ev[3][3:])
                comp._on_imu(msg, {'source_timestamp': stamp})
                calib._on_imu(msg, {'source_timestamp': stamp})
            elif ev[0] == 'temp':
                stamp = ev[1] * 1_000_000_000 + ev[2]
                msg = temperature_msg(stamp, ev[3])
                comp._temperature_cb(0)(msg, {'source_timestamp': stamp})
                calib._temperature_cb(0)(msg, {'source_timestamp': stamp})
            else:
                comp._on_calibration(String(data=ev[1]))
        calib._process()
    assert comp.active is not None          # a good calibration stays active throughout
    if comp.counts['calibrations_loaded'] > 1:
        comp._on_calibration(String(data=GOOD_TEXT))


def test_fuzz_targets_cover_the_probe_cases():
    # the seeds include every bad calibration of the probe; each is refused, none hangs
    for text, _ in bad_calibrations().values():
        with time_limit():
            with pytest.raises(CalibrationError):
                Calibration.from_yaml(text, 'seed')
    assert yaml.safe_load(GOOD_TEXT)['format'] == 'thermal_imu_calib/1'


def test_calibrator_survives_stamps_that_imply_no_usable_sample_rate(nodes):
    """Found by the fuzz test: IMU stamps 850 Ms apart derive a detector block of 8.5e9 s.

    The node warns, drops those samples and restarts detection instead of raising out of
    its callback; windows collected before are kept.
    """
    from conftest import imu_msg, temperature_msg
    _, calib, _ = nodes
    before = calib.counts.get('detector_restarts', 0)
    base = 1_700_000_057 * 1_000_000_000
    stamps = [base + k * 850_000_000 * 1_000_000_000 for k in range(4)] + [base]
    for stamp in stamps:                  # 850 million seconds apart, then back: closes it
        calib._temperature_cb(0)(temperature_msg(stamp, 35.0), {'source_timestamp': stamp})
        calib._on_imu(imu_msg(stamp, [0, 0, 9.81], [0, 0, 0]), {'source_timestamp': stamp})
        calib._process()
    assert calib.counts.get('detector_restarts', 0) > before


# ------------------------------------------------------------------ CLI outputs vs inputs
#: every output of every writing subcommand: (argv template, output kind); {X} is the path
#: under test, {B}/{C}/{W}/{R} the command's inputs (log, calibration, windows, registry)
CLI_OUTPUTS = [
    (['calibrate', '{B}', '-o', '{X}'], 'file'),
    (['calibrate', '{B}', '-o', '{T}/c.yaml', '--save-windows', '{X}'], 'file'),
    (['compensate', '{B}', '--calibration', '{C}', '-o', '{X}'], 'log'),
    (['simulate', '{X}'], 'log'),
    (['report', '{C}', '--windows', '{W}', '--html', '{X}'], 'file'),
    (['report', '{C}', '--windows', '{W}', '--png-dir', '{X}'], 'dir'),
    (['noise', '{B}', '-o', '{X}'], 'file'),
    (['noise', '{B}', '--html', '{X}'], 'file'),
    (['noise', '{B}', '-o', '{X}', '--html', '{X}'], 'file'),
    (['export', '{C}', '--format', 'px4', '-o', '{X}'], 'file'),
    (['history', '{R}', '--html', '{X}'], 'file'),
    (['fleet', 'calibrate', '{B}', '-o', '{X}', '--workers', '1'], 'dir'),
    (['fleet', 'compensate', '{B}', '--registry', '{R}', '-o', '{X}'], 'dir'),
]
#: paths no output may take; those naming an input are hostile for the commands reading it
HOSTILE = {'input_log': '{B}', 'input_cal': '{C}', 'fifo': None, 'foreign': None,
           'directory': None, 'registry_index': None, 'in_registry': '{R}',
           'link_to_input': '{B}', 'in_bag': '{B}'}


@pytest.fixture(scope='module')
def cli_world(tmp_path_factory):
    """Inputs every command reads, and hostile paths beside them (digested after each case)."""
    from thermal_imu_calib.cli import main
    from thermal_imu_calib.fleet import registry as reg
    imu, temp = recording(8)
    d = tmp_path_factory.mktemp('cliworld')
    cut = _first(3000)
    paths = {'B': write_bag(str(d / 'bagdir'), imu, temp, cut, storage='mcap'),
             'C': str(d / 'cal.yaml'), 'W': str(d / 'w.jsonl'), 'R': str(d / 'reg'),
             'T': str(d / 'tmp')}
    GOOD.save(paths['C'])
    open(paths['W'], 'w').close()
    reg.add(paths['R'], [('u1', GOOD, 2 * 10 ** 18, 10 ** 18, ['a'])])
    hostile = {'input_log': paths['B'], 'input_cal': paths['C'], 'fifo': str(d / 'fifo'),
               'foreign': str(d / 'notes.txt'), 'directory': str(d / 'adir'),
               'registry_index': os.path.join(paths['R'], 'index.csv'),
               'in_registry': os.path.join(paths['R'], 'new.html'),
               'link_to_input': str(d / 'link'),
               'in_bag': os.path.join(paths['B'], 'out.yaml')}
    os.mkfifo(hostile['fifo'])
    with open(hostile['foreign'], 'w') as f:
        f.write('precious\n')
    os.mkdir(hostile['directory'])
    os.symlink(paths['B'], hostile['link_to_input'])
    assert main(['info', paths['B']]) == 0
    return paths, hostile, d


def _world_digest(d):
    out = {}
    for dp, dn, fn in os.walk(d):
        for n in sorted(dn + fn):
            p = os.path.join(dp, n)
            st = os.lstat(p)
            if os.path.islink(p):
                out[p] = ('link', os.readlink(p))
            elif os.path.isfile(p):
                with open(p, 'rb') as f:
                    out[p] = f.read()
            else:
                out[p] = ('other', st.st_mode)
    return out


@FUZZ
@given(st.sampled_from(CLI_OUTPUTS), st.sampled_from(sorted(HOSTILE)),
       st.sampled_from(['as_is', 'dotdot', 'relative', 'double_slash']),
       st.text(st.characters(blacklist_characters='/\x00', blacklist_categories=('Cs',)),
               min_size=1, max_size=20).filter(lambda n: n not in ('.', '..')))
def test_fuzz_cli_outputs_never_replace_inputs_or_special_files(cli_world, case, hostile,
                                                                spelling, name):
    """Any writing subcommand, any hostile output path: refused in one line, nothing changed.

    ``name`` is the new file's name inside an input directory (a bag, the registry).
    """
    from thermal_imu_calib.cli import main
    paths, hostile_paths, d = cli_world
    template, kind = case
    if hostile == 'directory' and kind == 'dir':
        return                                   # a directory is where those outputs go
    if HOSTILE[hostile] and HOSTILE[hostile] not in template:
        return                                   # not an input of this command
    x = hostile_paths[hostile]
    if hostile in ('in_bag', 'in_registry'):
        x = os.path.join(os.path.dirname(x), name)
    if spelling == 'dotdot':                     # the same path spelt another way
        x = os.path.join(os.path.dirname(x), '..', os.path.basename(os.path.dirname(x)),
                         os.path.basename(x))
    elif spelling == 'relative':
        x = os.path.relpath(x)
    elif spelling == 'double_slash':
        x = x.replace(os.sep, os.sep * 2)
    argv = [a.format(X=x, **paths) for a in template]
    before = _world_digest(d)
    import io
    from contextlib import redirect_stderr, redirect_stdout
    with time_limit():
        err, out = io.StringIO(), io.StringIO()
        with redirect_stderr(err), redirect_stdout(out):
            code = main(argv)
    lines = [ln for ln in err.getvalue().splitlines() if ': error: ' in ln]
    assert code == 2 and len(lines) == 1, (argv, code, out.getvalue(), err.getvalue())
    assert 'Traceback' not in err.getvalue()
    assert _world_digest(d) == before, argv


# ------------------------------------------------------------------ fleet: ids and registries
SENSOR_IDS = st.one_of(
    st.text(min_size=1, max_size=40),
    st.sampled_from(['robot/imu', 'robot_imu', 'imu\N{GRINNING FACE}', 'imu', 'index.csv',
                     '..', '.', '.tmp-x', '%2F', 'a%', ' imu', 'imu\n', 'x' * 300]),
    st.lists(st.sampled_from(['/', '_', '.', '%', 'a', 'Z', '-', ' ', '\u00e9', '\x00']),
             min_size=1, max_size=20).map(''.join))


def _registry_world():
    import tempfile
    return tempfile.mkdtemp(prefix='fuzzreg-')


@FUZZ
@given(st.lists(SENSOR_IDS, min_size=1, max_size=4, unique=True))
def test_fuzz_fleet_sensor_ids_never_merge_or_name_registry_files(ids):
    """Distinct ids get distinct keys and files; none names index.csv; round trip exact."""
    from thermal_imu_calib.fleet import registry as reg
    from thermal_imu_calib.fleet.inputs import GroupBy
    usable = []
    for i in ids:
        try:
            key = reg.key(i)
        except ValueError as e:
            assert len(str(e)) < 400
            with pytest.raises(ValueError):
                GroupBy.parse('frame_id').sensor_id('log.mcap', i)
            continue
        assert reg.unkey(key) == i and '.' not in key and '/' not in key and key
        assert GroupBy.parse('frame_id').sensor_id('log.mcap', i) == i
        usable.append(i)
    assert len({reg.key(i) for i in usable}) == len(usable)
    if not usable:
        return
    d = _registry_world()
    try:
        with time_limit():
            errors = []
            written = reg.add(d, [(i, GOOD, (2 + k) * 10 ** 18, 10 ** 18, ['a'])
                                  for k, i in enumerate(usable)], errors)
            assert not errors and all(written)
            assert os.path.isfile(os.path.join(d, reg.INDEX))
            assert sorted(r['sensor'] for r in reg.read_index(d)) == sorted(usable)
            for i, path in zip(usable, written):
                assert reg.valid_at(d, i) == path
                assert os.path.dirname(path) == os.path.join(d, reg.key(i))
    finally:
        shutil.rmtree(d, ignore_errors=True)


INDEX_CELLS = st.one_of(st.text(max_size=30), st.sampled_from(
    ['../x.yaml', '/etc/passwd', 'u1/20250101T000000Z.yaml', 'u2/20250101T000000Z.yaml',
     'index.csv', 'u1', '20250101T000000Z', 'garbage', '']))


@FUZZ
@given(st.lists(st.tuples(INDEX_CELLS, INDEX_CELLS, INDEX_CELLS, INDEX_CELLS), max_size=5),
       st.booleans(), SENSOR_IDS)
def test_fuzz_fleet_registry_contents(rows, header, sensor):
    """A hand-edited or damaged index: lookups stay inside the sensor's key, errors one line."""
    import csv
    import io
    from thermal_imu_calib.fleet import registry as reg
    d = _registry_world()
    try:
        reg.add(d, [('u1', GOOD, 2 * 10 ** 18, 10 ** 18, ['a'])])
        buf = io.StringIO()
        w = csv.writer(buf)
        if header:
            w.writerow(['sensor', 'time', 'valid_from', 'file'])
        w.writerows(rows)
        with open(os.path.join(d, reg.INDEX), 'w', newline='') as f:
            f.write(buf.getvalue())
        with time_limit():
            for who in ('u1', sensor):
                try:
                    path = reg.valid_at(d, who)
                except (LookupError, ValueError) as e:
                    assert len(str(e)) < 600
                    continue
                assert os.path.dirname(path) in (os.path.join(d, reg.key(who)),
                                                 os.path.join(d, who)), path
                assert os.path.realpath(path).startswith(os.path.realpath(d) + os.sep)
            try:
                reg.assess(reg.read_index(d))
            except ValueError as e:
                assert len(str(e)) < 600
    finally:
        shutil.rmtree(d, ignore_errors=True)
