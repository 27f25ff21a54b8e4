"""Issue 21, fleet: units never merge, no frame_id names the registry's files, one bad log
never aborts the others, and the cluster options are checked up front in one line.

Real logs, a real dask.distributed LocalCluster (one worker), real subprocesses for
Ctrl-C; the scheduler probes talk to real sockets.
"""

import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from _hostile import recording
from thermal_imu_calib.cli import main
from thermal_imu_calib.fleet import registry as reg
from thermal_imu_calib.io import cdr
from thermal_imu_calib.io.bag_writer import LogWriter
from thermal_imu_calib.io.cdr import IMU_MSGTYPE, TEMPERATURE_MSGTYPE
from thermal_imu_calib.io.columns import ImuColumns, TemperatureColumns

CLI = [os.path.join(os.path.dirname(sys.executable), 'thermal-imu-calib')]
FRAMES = ['robot/imu', 'robot_imu', 'imu\N{GRINNING FACE}', 'imu', 'index.csv']


def write_log(path, imu, temp, frame_id):
    """Write a log of ``imu``/``temp`` whose IMU header frame_id is ``frame_id``."""
    imu_raw = cdr.encode_imu(ImuColumns(imu.stamp_ns, imu.accel, imu.gyro, frame_id))
    temp_raw = cdr.encode_temperature(TemperatureColumns(temp.stamp_ns, temp.temperature))
    msgs = sorted([(int(t), 0, i) for i, t in enumerate(imu.stamp_ns)]
                  + [(int(t), 1, i) for i, t in enumerate(temp.stamp_ns)])
    with LogWriter(str(path), 'mcap') as w:
        w.add_topic('/imu/data_raw', IMU_MSGTYPE)
        w.add_topic('/imu/temperature', TEMPERATURE_MSGTYPE)
        for t, kind, i in msgs:
            w.write(*(('/imu/data_raw', t, imu_raw[i]) if kind == 0 else
                      ('/imu/temperature', t, temp_raw[i])))
    return str(path)


@pytest.fixture(scope='module')
def fleet_logs(tmp_path_factory):
    imu, temp = recording()
    d = tmp_path_factory.mktemp('fleet')
    for i, f in enumerate(FRAMES):
        write_log(d / f'log{i}.mcap', imu, temp, f)
    write_log(d / 'huge.mcap', imu, temp, 'x' * 10240)
    return d


def test_frame_ids_are_units_exactly_and_never_name_registry_files(fleet_logs, tmp_path, capfd):
    registry = tmp_path / 'reg'
    code = main(['fleet', 'calibrate', str(fleet_logs), '-o', str(registry), '--workers', '1'])
    out, err = capfd.readouterr()
    assert code == 1, (out, err)                 # the 10 kB frame_id log failed, alone
    assert 'Traceback' not in out + err
    failed = [ln for ln in out.splitlines() if ln.startswith('FAILED')]
    assert len(failed) == 1 and 'huge.mcap' in failed[0] and len(failed[0]) < 600, failed
    rows = reg.read_index(str(registry))
    assert sorted(r['sensor'] for r in rows) == sorted(FRAMES)    # five units, none merged
    assert os.path.isfile(registry / 'index.csv')
    for r in rows:
        assert r['file'].split('/')[0] == reg.key(r['sensor'])
        assert reg.unkey(reg.key(r['sensor'])) == r['sensor']
        assert reg.valid_at(str(registry), r['sensor']) == str(registry / r['file'])
    assert len({r['file'].split('/')[0] for r in rows}) == len(FRAMES)
    # the registry still works: history and another fleet calibrate
    assert main(['history', str(registry)]) == 0
    assert main(['fleet', 'calibrate', str(fleet_logs / 'log4.mcap'), '-o', str(registry),
                 '--workers', '1']) == 0
    capfd.readouterr()
    assert main(['history', str(registry), '--sensor', 'index.csv']) == 0
    assert 'index.csv: 1 calibrations' in capfd.readouterr().out


def test_registry_keys_are_reversible_and_distinct():
    ids = FRAMES + ['a.b', 'a%2Eb', '..', '.tmp-x', ' imu', 'imu ', 'a\nb', 'IMU']
    keys = [reg.key(i) for i in ids]
    assert len(set(keys)) == len(ids)
    assert all(reg.unkey(k) == i for k, i in zip(keys, ids))
    assert all('.' not in k and '/' not in k for k in keys)
    with pytest.raises(ValueError, match='too long'):
        reg.key('x' * 10240)


def test_worker_count_is_checked_up_front(fleet_logs, tmp_path, capfd):
    for n in ('-1', '0', '100000'):
        code = main(['fleet', 'calibrate', str(fleet_logs), '-o', str(tmp_path / 'r'),
                     f'--workers={n}'])
        err = capfd.readouterr().err
        assert code == 2 and f'--workers {n}' in err and 'Traceback' not in err, err
    assert not (tmp_path / 'r').exists()


class _Server:
    """A TCP server on a free port: ``reply`` bytes are sent on connect (None: silent)."""

    def __init__(self, reply):
        self.sock = socket.socket()
        self.sock.bind(('127.0.0.1', 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.reply = reply
        self.conns = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(c)
            if self.reply:
                c.sendall(self.reply)

    def close(self):
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.mark.parametrize('reply', [None, b'HTTP/1.1 400 Bad Request\r\n\r\n' + b'\xff' * 64])
def test_scheduler_that_is_not_dask_is_one_line_in_bounded_time(reply, fleet_logs, tmp_path):
    server = _Server(reply)
    try:
        t = time.monotonic()
        proc = subprocess.run(CLI + ['fleet', 'calibrate', str(fleet_logs / 'log0.mcap'), '-o',
                                     str(tmp_path / 'r'), '--scheduler',
                                     f'tcp://127.0.0.1:{server.port}'],
                              capture_output=True, text=True, timeout=120)
        took = time.monotonic() - t
    finally:
        server.close()
    lines = [ln for ln in proc.stderr.splitlines() if 'error' in ln]
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr, proc.stderr
    assert len(lines) == 1 and '--scheduler' in lines[0], proc.stderr
    assert took < 60, took          # bounded by the 10 s probe, not the OS or the server
    assert not (tmp_path / 'r').exists()


def test_ctrl_c_of_fleet_calibrate_is_one_line_and_exit_130(fleet_logs, tmp_path):
    proc = subprocess.Popen(CLI + ['fleet', 'calibrate', str(fleet_logs), '-o',
                                   str(tmp_path / 'r'), '--workers', '2'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = ''
    while 'dask:' not in seen:                  # the cluster is up and the job runs
        line = proc.stderr.readline()
        assert line, (seen, proc.communicate())
        seen += line
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)          # Ctrl-C: the whole foreground group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ['interrupted'], err
