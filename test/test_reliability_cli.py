"""Issue 21 on the real CLI: no output ever replaces an input, every refusal is one line.

Every subcommand's outputs go through the one output writer (``io.output``): an input of
the same command, a special file (named pipe, device), an existing file of another kind
without --force and two outputs on one path are refused before anything is computed, and
temporary files are unique (never ``OUT.tmp``). Also: compensate on stamps that jump and
on Kelvin temperatures, a .db3 with its -wal, a thermal calibration with no input, and the
messages the probe found misleading.
"""

import os
import shutil
import sqlite3
import stat

import numpy as np
import pytest
import yaml

from _hostile import clean_pair, good_calibration, recording, write_bag
from thermal_imu_calib.calibration import Calibration, CalibrationError
from thermal_imu_calib.cli import main
from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.bag_writer import LogWriter
from thermal_imu_calib.io.cdr import IMU_MSGTYPE

HOUR_NS = 3600 * 10 ** 9


@pytest.fixture(scope='module')
def rec():
    return recording()


@pytest.fixture(scope='module')
def clean(rec, tmp_path_factory):
    d = tmp_path_factory.mktemp('clean')
    return clean_pair(d, rec, '--save-windows', str(d / 'w.jsonl')) + (str(d / 'w.jsonl'),)


def _digest(path):
    if os.path.isdir(path):
        return {n: _digest(os.path.join(path, n)) for n in sorted(os.listdir(path))}
    st = os.lstat(path)
    if not stat.S_ISREG(st.st_mode):
        return ('special', stat.S_IFMT(st.st_mode), st.st_rdev)
    with open(path, 'rb') as f:
        return f.read()


def _refused(argv, capfd, *must):
    """Run the CLI; assert exit 2 with one error line holding ``must``; return that line."""
    code = main([str(a) for a in argv])
    out, err = capfd.readouterr()
    assert 'Traceback' not in out + err
    lines = [ln for ln in err.splitlines() if ': error: ' in ln]
    assert code == 2 and len(lines) == 1, (code, out, err)
    for m in must:
        assert m in lines[0], lines[0]
    return lines[0]


def _special(tmp_path, kind):
    p = tmp_path / f'special_{kind}'
    if kind == 'fifo':
        os.mkfifo(p)
    else:
        try:
            os.mknod(p, 0o666 | stat.S_IFCHR, os.makedev(1, 3))     # a /dev/null twin
        except PermissionError:
            pytest.skip('creating a device node needs privileges')
    return p


# ------------------------------------------------------------------ the probe's data-loss cases
def test_report_html_onto_the_calibration_is_refused(clean, capfd):
    bag, cal, _ = clean
    before = _digest(cal)
    _refused(['report', cal, '--html', cal], capfd, 'one of the inputs')
    assert _digest(cal) == before


def test_html_onto_a_log_is_refused_for_report_and_noise(clean, capfd):
    bag, cal, _ = clean
    before = _digest(bag)
    _refused(['report', cal, '--log', bag, '--html', bag], capfd, 'one of the inputs')
    _refused(['noise', bag, '--html', bag], capfd, 'one of the inputs')
    assert _digest(bag) == before


@pytest.mark.parametrize('kind', ['fifo', 'device'])
def test_special_files_are_never_replaced(kind, clean, tmp_path, capfd):
    bag, cal, _ = clean
    target = _special(tmp_path, kind)
    before = _digest(target)
    for argv in (['report', cal, '--html', target], ['noise', bag, '-o', target],
                 ['calibrate', bag, '-o', target, '--force'],
                 ['export', cal, '--format', 'px4', '-o', target, '--force']):
        line = _refused(argv, capfd, str(target))
        assert 'named pipe' in line or 'device' in line
        assert _digest(target) == before


def test_no_fixed_temporary_name_destroys_a_file(clean, tmp_path, capfd):
    bag, cal, _ = clean
    html, noise_yaml = tmp_path / 'r.html', tmp_path / 'n.yaml'
    for p in (tmp_path / 'r.html.tmp', tmp_path / 'n.yaml.tmp'):
        p.write_text('precious\n')
    assert main(['report', cal, '--windows', clean[2], '--html', str(html)]) == 0
    assert main(['noise', bag, '-o', str(noise_yaml)]) == 0
    capfd.readouterr()
    assert (tmp_path / 'r.html.tmp').read_text() == 'precious\n'
    assert (tmp_path / 'n.yaml.tmp').read_text() == 'precious\n'
    assert sorted(os.listdir(tmp_path)) == ['n.yaml', 'n.yaml.tmp', 'r.html', 'r.html.tmp']


def test_two_outputs_of_one_command_on_one_path_are_refused(clean, tmp_path, capfd):
    bag, cal, _ = clean
    x = tmp_path / 'x'
    _refused(['calibrate', bag, '--save-windows', x, '-o', x], capfd, '--save-windows', '-o')
    _refused(['noise', bag, '-o', x, '--html', x], capfd, '-o', '--html')
    _refused(['calibrate', bag, '--save-windows', tmp_path / 'w', '-o',
              tmp_path / 'w.transitions.npz'], capfd, 'also where')
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------ every subcommand's outputs
def _fleet_registry(tmp_path, cal):
    from thermal_imu_calib.fleet import registry as reg
    reg_dir = tmp_path / 'reg'
    reg.add(str(reg_dir), [('u1', Calibration.load(cal), 2 * 10 ** 18, 10 ** 18, ['a'])])
    return reg_dir


def _sweep(clean, tmp_path):
    """Return {command: (argv with OUT, the inputs it reads)} over every writing subcommand."""
    bag, cal, windows = clean
    reg_dir = _fleet_registry(tmp_path, cal)
    return {
        'calibrate -o': (['calibrate', bag, '-o', '{OUT}'], [bag]),
        'calibrate --save-windows': (['calibrate', bag, '-o', tmp_path / 'c.yaml',
                                      '--save-windows', '{OUT}'], [bag]),
        'compensate -o': (['compensate', bag, '--calibration', cal, '-o', '{OUT}'],
                          [bag, cal]),
        'simulate OUTPUT': (['simulate', '{OUT}'], []),
        'report --html': (['report', cal, '--windows', windows, '--html', '{OUT}'],
                          [cal, windows]),
        'report --png-dir': (['report', cal, '--windows', windows, '--png-dir', '{OUT}'],
                             [cal, windows]),
        'noise -o': (['noise', bag, '-o', '{OUT}'], [bag]),
        'noise --html': (['noise', bag, '--html', '{OUT}'], [bag]),
        'noise --png-dir': (['noise', bag, '--png-dir', '{OUT}'], [bag]),
        'export -o': (['export', cal, '--format', 'px4', '-o', '{OUT}'], [cal]),
        'history --html': (['history', reg_dir, '--html', '{OUT}'],
                           [reg_dir / 'index.csv']),
        'fleet calibrate -o': (['fleet', 'calibrate', bag, '-o', '{OUT}', '--workers', '1'],
                               [bag]),
        'fleet compensate -o': (['fleet', 'compensate', bag, '--registry', reg_dir, '-o',
                                 '{OUT}', '--workers', '1'], [bag]),
        'simulate-fleet DIR': (['simulate-fleet', '{OUT}', '--units', '1'], []),
    }


def test_every_subcommand_refuses_inputs_special_files_and_foreign_files(clean, tmp_path,
                                                                         capfd):
    fifo = _special(tmp_path, 'fifo')
    foreign = tmp_path / 'notes.txt'
    foreign.write_text('my precious notes\n')
    sweep = _sweep(clean, tmp_path)
    for name, (argv, inputs) in sweep.items():
        def run(out):
            return [str(out) if a == '{OUT}' else a for a in argv]
        for src in inputs:                     # an input of the same command
            before = _digest(src)
            _refused(run(src), capfd, 'input')
            assert _digest(src) == before, name
        line = _refused(run(fifo), capfd, str(fifo))          # a special file
        assert 'named pipe' in line or 'not a directory' in line, (name, line)
        line = _refused(run(foreign), capfd, str(foreign))   # a file of another kind
        assert foreign.read_text() == 'my precious notes\n', name
        if '--force' in line:
            assert 'not a' in line, (name, line)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_outputs_of_their_own_kind_are_replaced_and_others_need_force(clean, tmp_path, capfd):
    bag, cal, windows = clean
    page = tmp_path / 'page.html'
    assert main(['report', cal, '--windows', windows, '--html', str(page)]) == 0
    assert main(['report', cal, '--windows', windows, '--html', str(page)]) == 0   # replaced
    other = tmp_path / 'other.html'
    other.write_text('not html at all\n')
    _refused(['report', cal, '--windows', windows, '--html', other], capfd, '--force')
    assert main(['report', cal, '--windows', windows, '--html', str(other), '--force']) == 0
    assert other.read_text().lstrip().lower().startswith('<!doctype html')
    capfd.readouterr()


def test_history_refuses_the_registry_index(clean, tmp_path, capfd):
    reg_dir = _fleet_registry(tmp_path, clean[1])
    before = _digest(reg_dir)
    _refused(['history', reg_dir, '--html', reg_dir / 'index.csv'], capfd, 'inside')
    assert _digest(reg_dir) == before
    assert main(['history', str(reg_dir)]) == 0
    capfd.readouterr()


def test_history_takes_the_fleet_false_alarm_rate(clean, tmp_path, capfd):
    # --family-rate sets the threshold every test must pass (Sidak over the fleet's tests);
    # a value that is no probability is refused, saying what it must be
    from thermal_imu_calib.fleet.alarms import family_threshold
    reg_dir = _fleet_registry(tmp_path, clean[1])
    shown = {}
    for rate in (0.01, 0.2):
        assert main(['history', str(reg_dir), '--family-rate', str(rate)]) == 0
        out = capfd.readouterr().out
        rule = next(ln for ln in out.splitlines() if 'family-wise' in ln)
        n = int(rule.split(' tests over the fleet')[0].rsplit(' ', 1)[1])
        assert f'flagged when |z| > {family_threshold(n, rate):.2f} (Sidak: {100 * rate:g} % ' \
            'family-wise' in rule, rule
        shown[rate] = family_threshold(n, rate)
    assert shown[0.2] < shown[0.01]
    for bad in ('0', '1', '-0.1', 'nan'):
        _refused(['history', reg_dir, '--family-rate', bad], capfd,
                 f'--family-rate {float(bad):g} must lie between 0 and 1')


# ------------------------------------------------------------------ time and inputs
def _jump_back(start, length):
    def edit(a):
        a['stamp_ns'][start:start + length] -= HOUR_NS
    return edit


def test_compensate_passes_a_span_of_stamps_jumped_back_through_and_counts_it(
        rec, clean, tmp_path, capfd):
    imu, temp = rec
    n = len(imu.stamp_ns)
    bag = write_bag(str(tmp_path / 'jump.mcap'), imu, temp, _jump_back(n // 2, n // 50))
    out = tmp_path / 'out.mcap'
    assert main(['compensate', bag, '--calibration', clean[1], '-o', str(out)]) == 0
    text = capfd.readouterr().out
    assert f'{n // 50} after IMU stamps jumped back by more than 10 s passed through' in text, text
    raw = {}
    comp = {}
    with open_log(str(out)) as r:
        for topic, _, _, data in r.iter_raw(['/imu/data_raw', '/imu/data_compensated']):
            m = cdr.decode_imu([data])
            (raw if topic == '/imu/data_raw' else comp).setdefault(
                int(m.stamp_ns[0]), []).append(m.accel[0])
    jumped = imu.stamp_ns[n // 2:n // 2 + n // 50] - HOUR_NS
    for s in jumped[:50]:                      # passed through: equal to the raw sample
        np.testing.assert_array_equal(comp[int(s)][0], raw[int(s)][0])
    other = imu.stamp_ns[10]
    assert not np.array_equal(comp[int(other)][0], raw[int(other)][0])


def test_compensate_refuses_stamps_that_jump_back_like_calibrate(rec, clean, tmp_path, capfd):
    imu, temp = rec
    n = len(imu.stamp_ns)
    bag = write_bag(str(tmp_path / 'jump.mcap'), imu, temp, _jump_back(n // 3, n // 3))
    _refused(['calibrate', bag, '-o', tmp_path / 'c.yaml'], capfd, 'do not increase')
    _refused(['compensate', bag, '--calibration', clean[1], '-o', tmp_path / 'o.mcap'], capfd,
             'do not increase')
    assert sorted(os.listdir(tmp_path)) == ['jump.mcap']


def test_compensate_refuses_kelvin_temperatures_with_a_unit_hint(rec, clean, tmp_path, capfd):
    imu, temp = rec
    bag = write_bag(str(tmp_path / 'kelvin.mcap'), imu, temp,
                    lambda a: a['temperature'].__iadd__(273.15))
    line = _refused(['compensate', bag, '--calibration', clean[1], '-o', tmp_path / 'o.mcap'],
                    capfd, 'outside the calibrated range', 'Kelvin')
    assert 'publish degC' in line
    assert sorted(os.listdir(tmp_path)) == ['kelvin.mcap']


def _bag_in_wal(tmp_path, rec):
    """Return (bag, total messages): a sqlite3 bag whose second half is only in its -wal."""
    bag = write_bag(str(tmp_path / 'walbag'), *rec, storage='sqlite3')
    db = next(str(p) for p in (tmp_path / 'walbag').iterdir() if p.suffix == '.db3')
    con = sqlite3.connect(db)
    con.execute('PRAGMA journal_mode=WAL')
    con.execute('PRAGMA wal_autocheckpoint=0')
    total = con.execute('select count(*) from messages').fetchone()[0]
    rows = con.execute('select id, topic_id, timestamp, data from messages order by id desc '
                       'limit ?', (total // 2,)).fetchall()
    con.execute('delete from messages where id >= ?', (min(r[0] for r in rows),))
    con.commit()
    con.execute('PRAGMA wal_checkpoint(TRUNCATE)')
    con.executemany('insert into messages(id, topic_id, timestamp, data) values (?,?,?,?)',
                    rows)
    con.commit()
    # the recorder "dies": copy the files as they are, without the checkpoint of a close
    snap = tmp_path / 'snapshot'
    shutil.copytree(tmp_path / 'walbag', snap)
    con.close()
    shutil.rmtree(tmp_path / 'walbag')
    snap.rename(tmp_path / 'walbag')
    assert os.path.getsize(db + '-wal') > 0
    return bag, total


def test_db3_with_its_wal_is_read_whole(rec, tmp_path, capfd):
    bag, total = _bag_in_wal(tmp_path, rec)
    before = _digest(bag)
    assert main(['info', bag]) == 0
    out = capfd.readouterr().out
    assert f'messages: {total}' in out and 'write-ahead log' in out, out
    imu_count = len(rec[0].stamp_ns)
    assert f'sensor_msgs/msg/Imu {imu_count:>16}' in ' '.join(out.split(' ' * 3)) or \
        str(imu_count) in out
    assert main(['calibrate', bag, '-o', str(tmp_path / 'c.yaml')]) == 0
    err = capfd.readouterr().err
    assert f'{imu_count} Imu messages' in err, err
    assert _digest(bag) == before                # the log itself is never written


def test_info_counts_the_messages_not_the_stale_index(rec, tmp_path, capfd):
    bag = write_bag(str(tmp_path / 'bag'), *rec, storage='mcap')
    meta = tmp_path / 'bag' / 'metadata.yaml'
    d = yaml.safe_load(meta.read_text())
    d['rosbag2_bagfile_information']['message_count'] = 999999
    meta.write_text(yaml.safe_dump(d))
    assert main(['info', bag]) == 0
    out = capfd.readouterr().out
    total = len(rec[0].stamp_ns) + len(rec[1].stamp_ns)
    assert f'messages: {total}' in out and 'the index says 999999' in out, out


def test_thermal_calibration_without_inputs_is_refused_at_load(clean, tmp_path, capfd):
    d = good_calibration().to_dict()
    d['temperature']['inputs'] = []
    d['temperature'].pop('valid_range', None)
    bad = tmp_path / 'no_inputs.yaml'
    bad.write_text(yaml.safe_dump(d))
    with pytest.raises(CalibrationError, match='thermal terms but there is no temperature'):
        Calibration.load(bad)
    _refused(['compensate', clean[0], '--calibration', bad, '-o', tmp_path / 'o.mcap'],
             capfd, 'thermal terms')
    _refused(['report', bad], capfd, 'thermal terms')


# ------------------------------------------------------------------ messages
def test_non_utf8_file_name_is_not_blamed_on_the_data(clean, tmp_path, capfd):
    name = os.fsdecode(os.path.join(os.fsencode(str(tmp_path)), b'log\xff.mcap'))
    shutil.copy(clean[0], name)
    line = _refused(['info', name], capfd, 'not UTF-8', 'rename')
    assert 'damaged' not in line and 'codec' not in line


def test_imu_topic_of_another_schema_name_is_named(rec, tmp_path, capfd):
    imu, _ = rec
    path = str(tmp_path / 'ros1.mcap')
    with LogWriter(path, 'mcap') as w:
        w.add_topic('/imu', 'sensor_msgs/Imu', msgdef='float64 x', type_hash='RIHS01_' + '0' * 64)
        w.write('/imu', 1, cdr.encode_imu(imu.slice(slice(0, 1)))[0])
    line = _refused(['calibrate', path, '-o', tmp_path / 'c.yaml'], capfd, '/imu',
                    'sensor_msgs/Imu', 'another schema name')
    assert 'present: none' not in line


def test_prior_directory_and_deep_nesting_are_one_line(clean, tmp_path, capfd):
    (tmp_path / 'prior').mkdir()
    _refused(['calibrate', clean[0], '-o', tmp_path / 'c.yaml', '--prior', tmp_path / 'prior'],
             capfd, 'is a directory')
    deep = tmp_path / 'deep.json'
    deep.write_text('[' * 100000 + ']' * 100000)
    _refused(['calibrate', clean[0], '-o', tmp_path / 'c.yaml', '--prior', deep], capfd,
             'nested too deeply')


def test_decoding_errors_name_the_file(rec, tmp_path, capfd):
    imu, _ = rec
    raws = cdr.encode_imu(imu.slice(slice(0, 2000)))
    for storage, name in (('mcap', 'short.mcap'), ('sqlite3', 'shortbag')):
        path = str(tmp_path / name)
        with LogWriter(path, storage) as w:
            w.add_topic('/imu/data_raw', IMU_MSGTYPE)
            for i, r in enumerate(raws):
                w.write('/imu/data_raw', int(imu.stamp_ns[i]), r if i != 1000 else r[:20])
        _refused(['calibrate', path, '-o', tmp_path / 'c.yaml'], capfd, path, 'too short')
