"""Replay a log into calibrator_node over DDS and call ~/calibrate, counting every message.

The node is started as its own process the way the launch file describes it
(``launch_nodes``: the shipped ``config/calibrator.yaml`` and the launch arguments a user
gives, ``gravity:=G`` among them; before 2026-11-29 gravity was added as a parameters dict,
as no launch argument took it), with ``HOME`` pointed at a fresh directory so
the shipped ``~/.ros/thermal_imu_calib/...`` collection never carries over between runs.

The node's inputs are best effort (``common.sensor_qos``), which promises no delivery, so
the replay is flow-controlled: IMU messages go out in chunks, and a chunk is published only
when the node's ``~/progress`` count (``imu_received``) shows that all but one chunk have
arrived; the window in flight stays below the node's input depth (1000). At the end both
counts (IMU and temperature) must equal what was published; ``Replay.complete`` says so.
The one parameter the harness sets beyond the launch arguments is ``progress_period``
(``HARNESS_PARAMS``, 0.1 s instead of 1 s): how often the node reports its counts, which
the flow control reads. It changes nothing collected or estimated; with the shipped 1 s
a chunk waited up to a second for the count, and a 10,245-message replay took 18 s
instead of 5 s (2026-11-29).
Every wait is on a condition, bounded by a stall time (no progress at all), and fails at
once when the node process has exited.

A launched node never outlives the bench: every ``LiveCalibrator`` is registered until it
is stopped, and the registered ones are stopped at interpreter exit (``atexit``) and on
SIGTERM, SIGHUP and SIGINT (``install_cleanup``; the process then ends by the signal,
exit status 128 + its number, or raises KeyboardInterrupt for SIGINT). SIGKILL cannot be
caught: a node left running that way is what ``foreign_nodes`` / ``check_domain`` find on
the domain before a run (a stray node shares the topics and spoils every live row).
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np

import dds_domain
import launch_nodes

#: IMU messages published before the node must have caught up (half the window in flight)
CHUNK = 300
#: messages per second inside a chunk (bursts beyond the socket buffers are lost)
RATE = 2000.0
#: node parameters of every live run beyond the launch arguments (see the module text)
HARNESS_PARAMS = {'progress_period': 0.1}
#: the message type readings are published as by default (header-stamped)
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
#: the topic readings are published on by default (the shipped config's)
TEMPERATURE_TOPIC = '/imu/temperature'
#: a wait fails when its condition has made no progress for this long (a busy 2-core
#: machine can starve a process for tens of seconds; a broken path does not move at all)
STALL_S = 180.0
#: what a start-up stall's error says (``run_live`` tries a spare domain once after it)
NO_MATCH = 'the node to match the player'
#: bound on one ~/calibrate call (the estimation itself; ends as soon as the answer comes)
CALL_S = 1800.0


class NodeFailed(RuntimeError):
    """The node process exited or a wait made no progress; the message says which."""


class DomainBusy(RuntimeError):
    """Other nodes are on the ROS domain of a live run; the message names them."""


# ------------------------------------------------------------------ launched nodes' cleanup
#: the signals after which no launched node may be left running
CLEANUP_SIGNALS = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)
#: launched nodes not stopped yet (registered at launch, removed by ``stop``)
_LIVE = []
#: reentrant: a handler may run in the main thread while it holds the lock
_LIVE_LOCK = threading.RLock()
_INSTALLED = {'atexit': False, 'signals': False}
#: the handlers replaced by ``install_cleanup`` (called after the nodes are stopped)
_PREVIOUS = {}


def live_nodes():
    """Return the launched nodes not stopped yet."""
    with _LIVE_LOCK:
        return list(_LIVE)


def stop_all():
    """Stop every registered node (``LiveCalibrator.stop``); errors do not stop the rest."""
    for node in live_nodes():
        try:
            node.stop()
        except Exception as e:  # noqa: B902 - the next node must be stopped all the same
            print(f'live_replay: stopping calibrator_node {node.proc.pid}: {e!r}',
                  file=sys.stderr)


def _on_signal(signum, frame):
    """Stop the nodes, then do what the signal did before.

    A Python handler that was there is called; SIGINT raises KeyboardInterrupt; otherwise
    the signal is raised again with its default action, so the process ends by it as it
    would have (a shell reports 128 + the signal number, a parent sees the signal) and no
    ``except``/``finally`` can hold it up (pytest would take a SystemExit for one test's
    failure and carry on).
    """
    stop_all()
    previous = _PREVIOUS.get(signum)
    if callable(previous) and previous is not signal.default_int_handler:
        return previous(signum, frame)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)
    sys.exit(128 + signum)          # not reached: the default action ends the process


def install_cleanup():
    """Stop every launched node at exit and on SIGTERM/SIGHUP/SIGINT; idempotent.

    The atexit hook is installed from any thread; the signal handlers only from the main
    thread (Python runs handlers there), at the first call made from it. An ignored signal
    stays ignored (``nohup``, a background job's SIGINT); a Python handler already there
    is called after the nodes are stopped.
    """
    import atexit
    with _LIVE_LOCK:
        if not _INSTALLED['atexit']:
            atexit.register(stop_all)
            _INSTALLED['atexit'] = True
        if not _INSTALLED['signals'] and threading.current_thread() is threading.main_thread():
            for s in CLEANUP_SIGNALS:
                previous = signal.getsignal(s)
                if previous is signal.SIG_IGN:
                    continue
                _PREVIOUS[s] = previous
                signal.signal(s, _on_signal)
            _INSTALLED['signals'] = True


# ------------------------------------------------------------------ the domain guard
#: how long the guard waits for discovery to show another node on the domain: a node
#: already there often answers a new participant only with its next periodic announcement
#: (every 3 s with Fast DDS's defaults; seen at 2-3.4 s on a loaded 2-core machine, so
#: a 3-s wait missed it), hence three periods. A busy domain ends the wait at once.
GUARD_S = 10.0


def foreign_nodes(domain_id, wait_s=GUARD_S):
    """Return the full names of the nodes on ``domain_id`` other than this probe.

    A probe node in a context of its own joins the domain and polls the graph until another
    node shows up or ``wait_s`` has passed (discovery takes a moment; an empty domain is
    only known as such at the deadline). Discovery follows the environment
    (``ROS_AUTOMATIC_DISCOVERY_RANGE``), as for the launched node.
    """
    import rclpy
    from rclpy.context import Context
    probe = f'bench_domain_guard_{os.getpid()}'
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = None
    try:
        node = rclpy.create_node(probe, context=context)
        me = (probe, node.get_namespace())
        deadline = time.monotonic() + wait_s
        while True:
            others = sorted({(ns.rstrip('/') + '/' + name) for name, ns in
                             node.get_node_names_and_namespaces() if (name, ns) != me})
            if others or time.monotonic() >= deadline:
                return others
            time.sleep(0.05)
    finally:
        if node is not None:
            node.destroy_node()
        context.try_shutdown()


def domain_busy_message(nodes, domain_id):
    """Return the refusal for a live run on a domain where ``nodes`` already are."""
    return (f'ROS domain {domain_id} is not free: {len(nodes)} other node(s) on it: '
            f'{", ".join(nodes)}. A live run shares the topics with them (a calibrator_node '
            f'left by a killed run spoils every live row). Stop them (pgrep -a calibrator_node,'
            f' then kill PID) or choose another domain (ROS_DOMAIN_ID=N).')


def check_domain(domain_id, wait_s=GUARD_S):
    """Raise DomainBusy when another node is on ``domain_id`` or its ids 0..31 are taken.

    The second: a new node and player would never match there (``dds_domain``), and the
    probe could not see the nodes either.
    """
    if dds_domain.saturated(dds_domain.participants(domain_id)):
        raise DomainBusy(f'ROS domain {domain_id} is not free: '
                         f'{dds_domain.describe(domain_id)}.')
    nodes = foreign_nodes(domain_id, wait_s)
    if nodes:
        raise DomainBusy(domain_busy_message(nodes, domain_id))


@dataclass
class Replay:
    """What one live run did: counts, the service answer and the written calibration."""

    imu_sent: int = 0
    temp_sent: int = 0
    imu_received: int = 0
    temp_received: int = 0
    success: bool = False
    message: str = ''
    calibration_text: str = ''
    seconds: dict = field(default_factory=dict)
    error: str = ''
    command: list = field(default_factory=list)
    attempts: int = 1
    domain: int = -1
    earlier: list = field(default_factory=list)

    @property
    def complete(self):
        """True when every published message was counted by the node."""
        return (self.imu_received == self.imu_sent and self.temp_received == self.temp_sent
                and self.imu_sent > 0)


class _Driver:
    """The rclpy side: publishers, the progress subscription and a spinning thread."""

    def __init__(self, domain_id, temperature_topic, temperature_type=TEMPERATURE_TYPE):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu
        from std_msgs.msg import String
        from thermal_imu_calib.nodes.common import headerless, THERMAL_TYPES
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('scoreboard_player', context=self.context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.imu_pub = self.node.create_publisher(Imu, 'imu/data_raw', qos)
        self.temp_cls = THERMAL_TYPES[temperature_type][0]
        self.temp_headerless = headerless(self.temp_cls)
        self._qos = qos
        self.temp_pub = (self.node.create_publisher(self.temp_cls, temperature_topic, qos)
                         if temperature_topic else None)
        self.progress = None
        self._lock = threading.Lock()
        self.node.create_subscription(String, '/thermal_imu_calibrator/progress',
                                      self._on_progress, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def start_temperature(self, topic):
        """Create the temperature publisher now (a driver started after the IMU's)."""
        self.temp_pub = self.node.create_publisher(self.temp_cls, topic, self._qos)

    def _on_progress(self, msg):
        with self._lock:
            self.progress = json.loads(msg.data)

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        while self.context.ok() and not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                break
            except Exception:  # noqa: B902 - shutting down
                if not self.context.ok():
                    break
                raise

    def reported(self, key, default=0):
        with self._lock:
            return self.progress.get(key, default) if self.progress else default

    def close(self):
        """Stop spinning, destroy the node (its participant leaves the graph), shut down.

        Shutting the context down alone left the participant and its publishers on the
        graph until the garbage collector ran: the next live run in the same process (a
        test file's next case) then saw the last one's temperature publisher on
        /imu/temperature (its node switched type, or did not follow a renamed topic) and
        never matched its player.
        """
        self._stop.set()
        self._thread.join(5.0)
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        self.context.try_shutdown()


class LiveCalibrator:
    """calibrator_node in its own process (new session), as the launch file starts it."""

    def __init__(self, workdir, launch_args, extra_params, domain_id):
        self.workdir = workdir
        os.makedirs(os.path.join(workdir, 'home'), exist_ok=True)
        node, = launch_nodes.resolve(nodes='calibrator', **launch_args)
        self.argv = launch_nodes.command(node, workdir, extra_params)
        env = dict(os.environ, HOME=os.path.join(workdir, 'home'),
                   ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   PYTHONUNBUFFERED='1')
        self.log_path = os.path.join(workdir, 'node.log')
        self._log = open(self.log_path, 'wb')
        install_cleanup()
        self._stopping = self._stopped = False
        self.proc = subprocess.Popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     env=env, start_new_session=True)
        with _LIVE_LOCK:
            _LIVE.append(self)

    def dead(self):
        """Return the exit code when the process has exited, else None."""
        return self.proc.poll()

    def log_tail(self, n=1):
        """Return the last ``n`` lines of the node's output (its exception, when it died)."""
        with open(self.log_path, 'rb') as f:
            lines = f.read().decode('utf-8', 'replace').strip().splitlines()
        return ' | '.join(x.strip() for x in lines[-n:])

    def stop(self):
        """SIGINT the node's process group; SIGKILL it if it has not ended in 20 s.

        Called again while it runs (a signal handler interrupting it in the main thread),
        it kills the group at once rather than wait a second time for the same process.
        """
        if self._stopped:
            return
        if self._stopping:
            self._kill_group()
            return
        self._stopping = True
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._kill_group()          # the report child (nice 10) may outlive the node
        self._log.close()
        self._stopped = True
        with _LIVE_LOCK:
            if self in _LIVE:
                _LIVE.remove(self)

    def _kill_group(self):
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _wait(cond, what, node, stall=STALL_S, progress=None):
    """Wait until ``cond()``; fail when ``progress()`` has not changed for ``stall`` s."""
    last, moved = (progress() if progress else None), time.monotonic()
    while not cond():
        code = node.dead()
        if code is not None:
            raise NodeFailed(f'calibrator_node exited (code {code}) while waiting for {what}: '
                             f'{node.log_tail()}')
        now = progress() if progress else None
        if now != last:
            last, moved = now, time.monotonic()
        elif time.monotonic() - moved > stall:
            raise NodeFailed(f'no progress for {stall:.0f} s waiting for {what}')
        time.sleep(0.02)


def _match_state(driver, with_temperature, domain_id):
    """Return what the start-up wait saw: the node's counts, the player's matches, DDS."""
    p = driver.progress
    seen = ('no progress message from the node' if p is None else
            f'the node sees {p["imu_publishers"]} IMU publisher(s)'
            + (f', {p["temperature_publishers"]} temperature publisher(s)'
               if with_temperature else ''))
    subs = f'the player\'s IMU publisher has {driver.imu_pub.get_subscription_count()} match(es)'
    if with_temperature:
        subs += f', its temperature publisher {driver.temp_pub.get_subscription_count()}'
    return f'{seen}; {subs}; {dds_domain.describe(domain_id)}'


def _start_late(driver, node, received, topic):
    """Wait for the node to decide without a temperature, then start its publisher."""
    _wait(lambda: (driver.reported('imu_received') >= received
                   and driver.reported('temperature_publishers', None) == []
                   and driver.reported('samples') > 0),
          'the node to decide without a temperature', node,
          progress=lambda: driver.reported('imu_received'))
    driver.start_temperature(topic)
    _wait(lambda: driver.temp_pub.get_subscription_count() >= 1,
          f'the node to match the late temperature on {topic}', node)


def _publish(driver, imu, temps, i0, i1, t_lo, t_hi, pace, header_ns=None):
    """Publish IMU rows i0..i1 and the temperatures stamped in [t_lo, t_hi), in stamp order.

    ``header_ns``: the temperatures' header stamps when not their stamps (a driver on
    another clock; the stamps still give the publish order, as a log's times do).
    """
    from thermal_imu_calib.nodes.player import imu_msg, temperature_msg
    events = [(int(imu.stamp_ns[i]), 0, i) for i in range(i0, i1)]
    n_t = 0
    if temps is not None:
        m = np.flatnonzero((temps.stamp_ns >= t_lo) & (temps.stamp_ns < t_hi))
        events += [(int(temps.stamp_ns[j]), 1, j) for j in m]
        n_t = len(m)
    events.sort()
    frame = imu.frame_id or 'imu_link'
    for k, (stamp, kind, i) in enumerate(events):
        pace.wait(k)
        if kind == 0:
            driver.imu_pub.publish(imu_msg(stamp, imu.accel[i], imu.gyro[i], frame))
        elif driver.temp_headerless:     # the value alone
            driver.temp_pub.publish(driver.temp_cls(data=float(temps.temperature[i])))
        else:
            driver.temp_pub.publish(temperature_msg(
                stamp if header_ns is None else int(header_ns[i]), temps.temperature[i], frame))
    return i1 - i0, n_t


def run_live(imu, temps, gravity, domain_id, temperature_topics=None, workdir=None,
             calibration_name='live.yaml', extra_params=None, attempts=3,
             temperature_type=TEMPERATURE_TYPE, temperature_header_ns=None,
             set_temperature_type=True, published_on=TEMPERATURE_TOPIC, late_from=None,
             spare_domains=()):
    """Run ``run_live_once`` until every message arrives, at most ``attempts`` times.

    Best effort may lose messages on a loaded machine (counted, never hidden): a run that
    lost some is repeated with a fresh node; the last run is returned with ``attempts``.
    ``spare_domains``: where to run instead when ``domain_id``'s participant ids 0..31 are
    all taken (``usable_domain``), and where a run whose node and player never matched is
    tried once more (a cause the port scan cannot see; its error is kept in
    ``Replay.earlier``); ``Replay.domain`` says where the returned run ran.
    """
    workdir = workdir or tempfile.mkdtemp(prefix='live-')
    domain_id = usable_domain(domain_id, spare_domains)
    earlier = []
    for i in range(1, attempts + 1):
        out = run_live_once(imu, temps, gravity, domain_id, temperature_topics,
                            os.path.join(workdir, f'attempt{i}'), calibration_name,
                            extra_params, temperature_type, temperature_header_ns,
                            set_temperature_type, published_on, late_from)
        out.attempts, out.domain, out.earlier = i, domain_id, list(earlier)
        if out.error and NO_MATCH in out.error and not earlier:
            spare = dds_domain.free_domain([d for d in spare_domains if d != domain_id])
            if spare is not None:
                earlier.append(f'domain {domain_id}: {out.error}')
                domain_id = spare
                continue
        if out.complete or (out.error and not out.error.startswith('not every message')):
            return out
    return out


def usable_domain(domain_id, spare_domains=()):
    """Return ``domain_id``, or the first free of ``spare_domains`` when it is saturated.

    Saturated: its participant ids 0..31 are all taken on this host, so a new node and
    player would never match there (``dds_domain``). Without a free spare the domain is
    returned as it is (the run then ends at once, saying why).
    """
    if dds_domain.saturated(dds_domain.participants(domain_id)) and spare_domains:
        return dds_domain.free_domain(spare_domains) or domain_id
    return domain_id


def run_live_once(imu, temps, gravity, domain_id, temperature_topics=None, workdir=None,
                  calibration_name='live.yaml', extra_params=None,
                  temperature_type=TEMPERATURE_TYPE, temperature_header_ns=None,
                  set_temperature_type=True, published_on=TEMPERATURE_TOPIC, late_from=None):
    """Replay ``imu`` (+ ``temps`` on ``published_on``) into a launched calibrator_node.

    ``temperature_topics``: the launch argument (None: the shipped config's
    [imu/temperature]; '[]': none); ``gravity`` is given as the launch argument
    ``gravity:=G``; ``HARNESS_PARAMS`` and ``extra_params`` (for experiments; by
    default none) are added as one more parameters dict. ``temperature_header_ns``: the
    header stamps of ``temps`` when not their stamps (``_publish``). ``set_temperature_type``
    False: the node is not given ``temperature_types`` for a ``temperature_type`` other than
    sensor_msgs/Temperature, and must follow the type it sees on the graph
    (``nodes/thermal_types``). ``published_on``: the readings' topic (another than the
    node's /imu/temperature: the node must follow it, ``nodes/topic_follower``).
    ``late_from``: the IMU row at which the temperature's publisher starts (a driver started
    later than the IMU's, ``nodes/late_inputs``; ``temps`` then has no earlier reading):
    the rows before it are replayed first, the node must decide to collect without a
    temperature, and then the publisher is created and matched. Returns a
    Replay; never raises
    for node failures (they are in ``Replay.error``).
    """
    from thermal_imu_calib.nodes.player import Pacer
    from std_srvs.srv import Trigger
    workdir = workdir or tempfile.mkdtemp(prefix='live-')
    # a fresh node: the calibrator resumes its collection from $HOME/.ros (inside workdir),
    # so a workdir left by an earlier run would add its holds to this one's
    shutil.rmtree(workdir, ignore_errors=True)
    os.makedirs(workdir)
    cal_path = os.path.join(workdir, calibration_name)
    args = {'calibration_file': cal_path, 'gravity': repr(float(gravity))}  # gravity:=G
    if temperature_topics is not None:
        args['temperature_topics'] = temperature_topics
    out = Replay()
    t_start = time.monotonic()
    typed = ({} if temperature_type == TEMPERATURE_TYPE or not set_temperature_type
             else {'temperature_types': [temperature_type]})
    if dds_domain.saturated(dds_domain.participants(domain_id)):
        out.error = f'not started: {dds_domain.describe(domain_id)}'
        return out
    node = LiveCalibrator(workdir, args, {**HARNESS_PARAMS, **typed, **(extra_params or {})},
                          domain_id)
    out.command = node.argv
    driver = None
    try:
        # inside the try: an exit while the player starts still stops the launched node
        now = temps is not None and late_from is None     # the temperature from the start
        driver = _Driver(domain_id, published_on if now else None, temperature_type)

        def connected():
            p = driver.progress
            # without a temperature the node's inputs have no publisher: with the shipped
            # config it decides to collect without them after the first IMU messages
            return (p is not None and p['imu_publishers'] >= 1
                    and (not now or all(n >= 1 for n in p['temperature_publishers']))
                    and driver.imu_pub.get_subscription_count() >= 1
                    and (not now or driver.temp_pub.get_subscription_count() >= 1))
        try:
            _wait(connected, NO_MATCH + ' (the IMU on imu/data_raw'
                  + (f', the temperature on {published_on})' if now else ')'), node)
        except NodeFailed as e:
            raise NodeFailed(f'{e}; {_match_state(driver, now, domain_id)}; '
                             f'the node said: {node.log_tail(3) or "nothing"}') from None
        out.seconds['start'] = time.monotonic() - t_start
        t0 = time.monotonic()
        n = len(imu)
        base = driver.reported('imu_received')
        starts = sorted(set(range(0, n, CHUNK)) | ({late_from} if late_from else set()))
        for i0, i1 in zip(starts, starts[1:] + [n]):
            if late_from and i0 == late_from:
                _start_late(driver, node, out.imu_sent + base, published_on)
            if out.imu_sent:
                need = out.imu_sent - CHUNK
                _wait(lambda: driver.reported('imu_received') - base >= need,
                      f'{need} IMU messages at the node', node,
                      progress=lambda: driver.reported('imu_received'))
            lo = -2 ** 62 if i0 == 0 else int(imu.stamp_ns[i0])
            hi = 2 ** 62 if i1 == n else int(imu.stamp_ns[i1])
            a, b = _publish(driver, imu, None if late_from and i0 < late_from else temps,
                            i0, i1, lo, hi, Pacer(RATE), temperature_header_ns)
            out.imu_sent += a
            out.temp_sent += b

        def temps_in():           # a reading the node drops as invalid has arrived too
            return (driver.reported('temperature_readings')
                    + driver.reported('temperature_invalid', 0))

        def all_in():
            return (driver.reported('imu_received') - base >= out.imu_sent
                    and temps_in() >= out.temp_sent)
        try:
            _wait(all_in, 'every message at the node', node, stall=30.0,
                  progress=lambda: (driver.reported('imu_received'), temps_in()))
        except NodeFailed as e:
            if node.dead() is not None:
                raise
            out.error = f'not every message arrived: {e}'
        out.imu_received = driver.reported('imu_received') - base
        out.temp_received = temps_in()
        out.seconds['replay'] = time.monotonic() - t0
        t0 = time.monotonic()
        client = driver.node.create_client(Trigger, '/thermal_imu_calibrator/calibrate')
        _wait(client.service_is_ready, 'the ~/calibrate service', node)
        fut = client.call_async(Trigger.Request())
        deadline = time.monotonic() + CALL_S
        while not fut.done():
            if node.dead() is not None:
                raise NodeFailed(f'calibrator_node exited during ~/calibrate: {node.log_tail()}')
            if time.monotonic() > deadline:
                raise NodeFailed(f'~/calibrate gave no answer in {CALL_S:.0f} s')
            time.sleep(0.05)
        r = fut.result()
        out.success, out.message = bool(r.success), r.message
        out.seconds['calibrate'] = time.monotonic() - t0
        if out.success and os.path.exists(cal_path):
            with open(cal_path) as f:
                out.calibration_text = f.read()
    except NodeFailed as e:
        out.error = str(e)
    finally:
        if driver is not None:
            driver.close()
        node.stop()
    return out
