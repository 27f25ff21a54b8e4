"""The live bench's two guards against a stray calibrator_node (``bench/live_replay.py``).

* The domain guard: before a live run, a probe node lists the other nodes on the ROS
  domain (``foreign_nodes``); ``bench/scoreboard.py`` refuses to start, naming them, when
  there are any (a node left by a killed run shares the topics and spoils every row).
* The domain's participants (``bench/dds_domain.py``, read from the UDP ports they
  listen on): a domain whose participant ids 0..31 are all taken cannot host a live run
  (Fast DDS's localhost discovery reaches only those), so the guard refuses it and a live
  run ends at once, saying so, instead of waiting 180 s for a match that never comes
  (``run_live`` moves to a free spare domain when it is given some); the tests' own
  domains are chosen free of participants (``conftest``).
* The cleanup: a bench process that ends (normal exit, SIGTERM, SIGHUP, SIGINT) stops
  every node it launched. A helper process imports ``bench/live_replay``, starts a
  ``LiveCalibrator`` (the real calibrator_node, or a cheap shell stand-in with a child of
  its own that ignores SIGINT), is ended, and the node's process group must be empty.

Waits are on conditions with deadlines (the node on the graph, a line from the helper,
the helper's exit, the group emptied).
"""

import os
import re
import signal
import subprocess
import sys
import textwrap

from conftest import DOMAIN_ID, participant, SPARE_DOMAINS, venv_env, wait_for
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BENCH = os.path.join(ROOT, 'bench')
sys.path.insert(0, BENCH)

import dds_domain  # noqa: E402
import live_replay  # noqa: E402

CALIBRATOR = 'thermal_imu_calibrator'

#: the helper: launch one node the way run_live_once does (a player node in the process
#: too, for the real one), print its pid, then wait like the bench until it is ended
HELPER = textwrap.dedent('''
    import os
    import sys

    sys.path.insert(0, {bench!r})
    import live_replay as lr

    kind, how, domain, work = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    if kind == 'stand_in':
        # sh, a foreground child, and a background child that ignores SIGINT: only the
        # group's SIGKILL ends the last one
        lr.launch_nodes.command = lambda node, workdir, extra=None: [
            'sh', '-c', 'sleep 600 & sleep 600']
    node = lr.LiveCalibrator(work, {{'calibration_file': os.path.join(work, 'c.yaml')}},
                             {{'gravity': 9.81}}, domain)
    driver = lr._Driver(domain, None) if kind == 'calibrator' else None
    try:
        print('READY', node.proc.pid, flush=True)
        if how == 'exit':
            sys.stdin.readline()        # returns when the test closes stdin
        else:
            lr._wait(lambda: False, 'the signal', node, stall=1e9)
    finally:
        # as run_live_once's finally, without node.stop(): that is the cleanup's job
        print('REGISTERED', len(lr.live_nodes()), flush=True)
        if driver is not None:
            driver.close()
''').format(bench=BENCH)


def _group_running(pgid, names=False):
    """Return the pids (or names) of group ``pgid``'s processes still running (not zombies).

    Read from /proc: an orphan killed in the group stays a zombie where nothing reaps
    orphans (a container's init), and a zombie runs nothing.
    """
    out = []
    for pid in os.listdir('/proc'):
        if not pid.isdigit():
            continue
        try:
            with open(f'/proc/{pid}/stat') as f:
                comm, rest = f.read().rsplit(')', 1)
            fields = rest.split()
            group = int(fields[2])
        except (OSError, ValueError, IndexError):     # the process has just ended
            continue
        if group == pgid and fields[0] not in 'ZX':
            out.append(comm.split('(', 1)[1] if names else int(pid))
    return out


def _children(pid):
    """Return the pids of the processes whose parent is ``pid``."""
    out = []
    for child in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{child}/stat') as f:
                if int(f.read().rsplit(')', 1)[1].split()[1]) == pid:
                    out.append(int(child))
        except (OSError, ValueError, IndexError):
            continue
    return out


def _kill_group(pgid):
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _sigint_default():
    """Give the helper the default of every signal it is ended by: a job a shell starts in
    the background (make test run with ``&``, some CI runners) inherits SIGINT ignored, one
    run under ``nohup`` SIGHUP, and an ignored signal stays ignored by design
    (``install_cleanup``), so that case would never end."""
    for sig in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def _run_helper(tmp_path, kind, how, before_end=None):
    """Start the helper, end it by ``how``; return (returncode, output, node pgid)."""
    script = tmp_path / 'helper.py'
    script.write_text(HELPER)
    work = tmp_path / 'work'
    log_path = tmp_path / 'helper.log'
    with open(log_path, 'w') as log:
        helper = subprocess.Popen([sys.executable, str(script), kind, how, str(DOMAIN_ID),
                                   str(work)], stdin=subprocess.PIPE, stdout=log,
                                  stderr=subprocess.STDOUT, text=True,
                                  env=venv_env(ROS_DOMAIN_ID=DOMAIN_ID),
                                  preexec_fn=_sigint_default)
    pgid = None

    def output():
        return log_path.read_text()     # its own offset, not the one the helper writes at
    try:
        # a whole line only: read while the helper writes it, 'READY' may come without its pid
        line = wait_for(lambda: [x for x in output().splitlines()
                                 if re.fullmatch(r'READY \d+', x)]
                        or helper.poll() is not None, 60,
                        lambda: f'the helper to launch the node: {output()[-800:]}')
        assert helper.poll() is None, f'helper exited: {output()[-800:]}'
        pgid = int(line[0].split()[1])       # start_new_session: the group is the node's pid
        assert _group_running(pgid), 'the launched node is not running'
        if kind == 'stand_in':
            # a signal before the shell has started its children would be lost in the exec
            wait_for(lambda: sorted(_group_running(pgid, True)) == ['sh', 'sleep', 'sleep'],
                     60, lambda: f'the stand-in running ({_group_running(pgid, True)})')
        if before_end is not None:
            before_end()
        if how == 'exit':
            helper.stdin.close()
        else:
            helper.send_signal(getattr(signal, how))
        try:
            rc = helper.wait(60)
        except subprocess.TimeoutExpired:
            pytest.fail(f'the helper did not end within 60 s of {how}: {output()[-800:]}')
        wait_for(lambda: not _group_running(pgid), 30,
                 lambda: f'the node group {pgid} to end: {_group_running(pgid)} still run')
        return rc, output(), pgid
    finally:
        # a failed test leaves nothing running: the helper, and the group it launched
        # (found by its parent when the test failed before reading it)
        groups = {pgid} if pgid is not None else set(_children(helper.pid))
        if helper.poll() is None:
            helper.kill()
            helper.wait(10)
        for g in groups:
            _kill_group(g)


#: the guard's wait where the domain should be free: shorter than the bench's (absence is
#: only known at the deadline; a shorter one checks the same thing, less thoroughly)
FREE_S = 3.0


def test_guard_reports_no_node_on_a_free_domain():
    assert live_replay.foreign_nodes(DOMAIN_ID, wait_s=FREE_S) == []


def test_guard_names_a_foreign_node():
    with participant('stray_calibrator'):
        found = live_replay.foreign_nodes(DOMAIN_ID, wait_s=30.0)
        with pytest.raises(live_replay.DomainBusy) as e:
            live_replay.check_domain(DOMAIN_ID, wait_s=30.0)
    assert '/stray_calibrator' in found
    assert not any('bench_domain_guard' in n for n in found), found
    assert '/stray_calibrator' in str(e.value) and f'ROS domain {DOMAIN_ID}' in str(e.value)


def test_scoreboard_refuses_a_busy_domain(tmp_path):
    with participant('stray_calibrator'):
        r = subprocess.run([sys.executable, os.path.join(BENCH, 'scoreboard.py'),
                            '--work', str(tmp_path / 'work'), '--out', str(tmp_path / 'board'),
                            '--only', 'no_such_recording'], capture_output=True, text=True,
                           timeout=120, env=venv_env(ROS_DOMAIN_ID=DOMAIN_ID), cwd=ROOT)
    out = r.stdout + r.stderr
    assert r.returncode != 0, out
    assert '/stray_calibrator' in r.stderr and f'ROS domain {DOMAIN_ID}' in r.stderr, out
    assert 'pgrep -a calibrator_node' in r.stderr and 'ROS_DOMAIN_ID' in r.stderr, out
    assert 'Traceback' not in out, out
    assert not os.path.exists(tmp_path / 'board.json')


def test_participants_are_read_from_their_ports():
    # conftest chose a free domain; a module fixture of another test may still hold one
    before = dds_domain.participants(DOMAIN_ID)
    with participant('port_probe'):
        ids = dds_domain.participants(DOMAIN_ID)
        new = sorted(set(ids) - set(before))
        assert len(ids) == len(before) + 1 and 0 <= new[0] < dds_domain.LOCALHOST_PEERS, ids
        assert not dds_domain.saturated(ids)
        # the first free one after it (domains past 101 are not used: their ports fall in
        # the ephemeral range, where any UDP socket can look like a participant; a clean
        # clone once found domain 200 taken so)
        spare = dds_domain.free_domain(d for d in dds_domain.DOMAINS if d != DOMAIN_ID)
        assert spare is not None and dds_domain.free_domain([DOMAIN_ID, spare]) == spare
        assert f'{len(ids)} DDS participant(s) bound' in dds_domain.describe(DOMAIN_ID)
    assert dds_domain.participants(DOMAIN_ID) == before     # destroyed with its node
    # two workers never share a candidate; each starts at base + its index
    a, b = (dds_domain.worker_domains(100, k, 2) for k in (0, 1))
    assert a[:3] == [100, 1, 3] and b[:3] == [101, 2, 4] and not set(a) & set(b)
    assert set(a) | set(b) <= set(dds_domain.DOMAINS)


def test_a_domain_with_ids_0_to_31_taken_is_refused_at_once(tmp_path):
    """32 idle participants on the domain: the guard refuses and a live run does not start.

    With them there, a node and a player on the domain never matched (the CI failure of
    2026-12-03, reproduced: 180 s without a match); now the run ends at once, saying why.
    """
    import rclpy
    from rclpy.context import Context
    before = dds_domain.participants(DOMAIN_ID)
    held = []
    try:
        for i in range(dds_domain.LOCALHOST_PEERS):
            context = Context()
            rclpy.init(context=context, domain_id=DOMAIN_ID)
            held.append((context, rclpy.create_node(f'holder_{i}', context=context)))
        ids = dds_domain.participants(DOMAIN_ID)
        assert dds_domain.saturated(ids), ids
        with pytest.raises(live_replay.DomainBusy) as e:
            live_replay.check_domain(DOMAIN_ID, wait_s=FREE_S)
        assert 'ids 0..31 all taken' in str(e.value) and 'ROS_DOMAIN_ID' in str(e.value)
        # no recording: the run must end before the node starts, so none is read
        out = live_replay.run_live_once(None, None, 9.81, DOMAIN_ID,
                                        workdir=str(tmp_path / 'live'))
        assert out.error.startswith('not started: ') and 'ids 0..31 all taken' in out.error
        assert out.imu_sent == 0 and not live_replay.live_nodes()
        # run_live moves to a free spare domain (the worker's), else stays
        spare = dds_domain.free_domain(SPARE_DOMAINS)
        assert live_replay.usable_domain(DOMAIN_ID, SPARE_DOMAINS) == spare != DOMAIN_ID
        assert live_replay.usable_domain(DOMAIN_ID, []) == DOMAIN_ID
    finally:
        for context, node in held:
            node.destroy_node()
            context.try_shutdown()
    assert dds_domain.participants(DOMAIN_ID) == before


def test_sigterm_stops_the_launched_calibrator_node(tmp_path):
    def on_graph():
        with participant('cleanup_probe') as probe:
            def names():
                return [n for n, _ in probe.get_node_names_and_namespaces()]
            wait_for(lambda: CALIBRATOR in names(), 60,
                     lambda: f'{CALIBRATOR} on the graph (have {names()})')
    rc, out, _ = _run_helper(tmp_path, 'calibrator', 'SIGTERM', before_end=on_graph)
    # the process ended by the signal, as without the handler (a shell shows 143), and
    # its node with it: no finally ran, so the handler stopped it
    assert rc == -signal.SIGTERM and 'REGISTERED' not in out, out
    # the next run's guard finds the domain free (a probe that knew the node may still
    # list it until its lease ends when the node's goodbye is lost; a new one does not)
    assert live_replay.foreign_nodes(DOMAIN_ID, wait_s=FREE_S) == []


@pytest.mark.parametrize('how', ['SIGINT', 'SIGHUP', 'exit'])
def test_bench_end_stops_the_launched_group(tmp_path, how):
    rc, out, _ = _run_helper(tmp_path, 'stand_in', how)
    if how == 'SIGINT':
        # KeyboardInterrupt raised after the stop (the finally sees no node left); Python
        # ends by SIGINT, as without the handler
        assert rc == -signal.SIGINT and 'KeyboardInterrupt' in out, out
        assert 'REGISTERED 0' in out, out
    elif how == 'SIGHUP':
        assert rc == -signal.SIGHUP and 'REGISTERED' not in out, out
    else:
        # a normal end: the node was still registered after main; atexit stopped it
        assert rc == 0 and 'REGISTERED 1' in out, out


def test_a_run_whose_node_never_matched_is_tried_once_on_a_spare_domain(monkeypatch, tmp_path):
    # the CI failure of 2026-12-03 (node and player never matched, cause unseen by the port
    # scan): run_live tries a free spare domain once, and keeps the first error
    calls = []

    def once(imu, temps, gravity, domain, *args):
        calls.append(domain)
        if len(calls) == 1:
            return live_replay.Replay(error='no progress for 180 s waiting for '
                                      + live_replay.NO_MATCH + ' (the IMU on imu/data_raw)')
        return live_replay.Replay(imu_sent=5, imu_received=5, success=True)
    monkeypatch.setattr(live_replay, 'run_live_once', once)
    spare = dds_domain.free_domain(SPARE_DOMAINS)
    out = live_replay.run_live(None, None, 9.81, DOMAIN_ID, workdir=str(tmp_path),
                               spare_domains=SPARE_DOMAINS)
    assert calls == [DOMAIN_ID, spare] and out.domain == spare and out.success
    assert len(out.earlier) == 1 and out.earlier[0].startswith(f'domain {DOMAIN_ID}: ')
    # without spares the first error is the answer
    calls.clear()
    out = live_replay.run_live(None, None, 9.81, DOMAIN_ID, workdir=str(tmp_path))
    assert calls == [DOMAIN_ID] and live_replay.NO_MATCH in out.error and not out.earlier
