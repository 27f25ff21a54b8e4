"""Lifelong mode of the calibrator node: collect from everyday stops, swap when proven.

``declare(node, params)`` declares the parameters (always, so the shipped config lists
them); with ``lifelong: true`` it returns a ``LifelongMode`` the calibrator calls from a
small hook: ``on_windows`` with every closed hold's windows, ``statuses`` for
/diagnostics. Everything else is the pure core ``lifelong.manager.Lifelong``.

Motion hints (optional; without any, the detector alone decides): ``cmd_vel_topic``
(geometry_msgs/Twist, still when every component is below 1e-3; silent for longer than
``hint_timeout`` counts as still, as a base controller stops on a command timeout),
``odom_topic`` (nav_msgs/Odometry, its twist; header stamps) and ``still_topic``
(std_msgs/Bool, true = commanded still). Twist and Bool have no header: they are stamped
with the newest IMU header stamp received, so a replay at many times real time keeps the
IMU's time base. A hold counts only when every configured hint said still over it.

Re-estimation runs on a worker thread at nice +10 (Linux threads have their own nice
value), never more than one at a time; the holds arriving meanwhile are queued and added
after it. A swap publishes the new calibration latched on ``imu/calibration`` and writes
``calibration_file`` (as ~/calibrate does); with ``gyro_follow`` the calibration published
carries the gyro follower's offset, published again after every hold that moves it.
/diagnostics gets one more status: the active model's age, the present temperature against
its valid range (WARN outside it), its error on the newest holds, the number of holds and
the temperature coverage. The node's own collection (what ~/calibrate uses) is cut to its
newest ``NODE_HOLDS`` holds, so memory and collection_file stay bounded over weeks.
``~/reset`` starts the lifelong collection afresh too (``reset``): the store is archived,
never deleted, and the active calibration stays active.
"""

from concurrent.futures import ThreadPoolExecutor
import os
import threading

from geometry_msgs.msg import Twist
import numpy as np
from nav_msgs.msg import Odometry
from std_msgs.msg import Bool, String

from . import common
from ..lifelong.hints import HintGate, HintSource, twist_still
from ..io.output import OutputError, write_atomic
from ..lifelong.manager import archive_collection, ArchiveFull, Lifelong, LifelongConfig

#: nice increment of the re-estimation thread
NICE = 10
#: most holds the node's own collection keeps in lifelong mode (the store has the rest)
NODE_HOLDS = 400


def declare(node, p):
    """Declare the lifelong parameters on ``node``; return a LifelongMode or None."""
    ro = {'read_only': True}
    c = LifelongConfig()
    on = p.declare('lifelong', False, 'Lifelong mode: collect holds from everyday stops '
                   'without a service call, across restarts, re-estimate when due and swap '
                   'in a new calibration only when it predicts the newest holds better '
                   '(docs/lifelong.md).', **ro)
    values = {
        'lifelong_dir': p.declare('lifelong_dir', '~/.ros/thermal_imu_calib/lifelong',
                                  'Directory of the lifelong state (holds, active and '
                                  'candidate calibrations, decisions).', **ro),
        'registry_dir': p.declare('registry_dir', '', 'Registry (fleet format) every '
                                  'activated calibration is added to; empty: '
                                  '<lifelong_dir>/registry.', **ro),
        'sensor_id': p.declare('sensor_id', '', 'Unit id in the registry; empty: the IMU '
                               'frame_id.', **ro),
        'cmd_vel_topic': p.declare('cmd_vel_topic', '', 'geometry_msgs/Twist velocity '
                                   'command hint; empty: none.', **ro),
        'odom_topic': p.declare('odom_topic', '', 'nav_msgs/Odometry hint; empty: none.',
                                **ro),
        'still_topic': p.declare('still_topic', '', 'std_msgs/Bool hint (true: commanded '
                                 'still); empty: none.', **ro),
        'hint_timeout': p.declare('hint_timeout', 1.0, 'Seconds a hint holds after its last '
                                  'message.', lo=0.01, hi=600.0, **ro),
        'range_extension_degc': p.declare(
            'range_extension_degc', c.range_extension_degc, 'Re-estimate when the collected '
            'temperatures extend the active valid range by this (degC).', lo=0.1, hi=100.0,
            **ro),
        'new_holds': p.declare('new_holds', c.new_holds, 'Re-estimate after this many new '
                               'holds.', lo=1, hi=100000, **ro),
        'misfit_holds': p.declare('misfit_holds', c.misfit_holds, 'Re-estimate when this '
                                  'many new holds are missed by the active calibration '
                                  '(past the change alarm\'s limit, any temperature).',
                                  lo=1, hi=100000, **ro),
        'holdout_holds': p.declare('holdout_holds', c.holdout_holds, 'Newest holds left out '
                                   'of a re-estimate to judge the swap.', lo=2, hi=1000,
                                   **ro),
        'per_sensor_swap': p.declare('per_sensor_swap', c.per_sensor, 'A new estimate better '
                                     'for one sensor only replaces that sensor\'s model alone; '
                                     'false: the whole calibration or nothing.', **ro),
        'gyro_follow': p.declare('gyro_follow', c.gyro_follow, 'The published calibration '
                                 'takes off the gyro what the newest holds say the active '
                                 'model misses now (needs use_latitude, or '
                                 'follow_without_latitude; docs/lifelong.md).', **ro),
        'follow_without_latitude': p.declare(
            'follow_without_latitude', c.follow_without_latitude, 'Without use_latitude the '
            'gyro follower follows in the model\'s own convention (the vertical earth rate '
            'is in its bias; the output at rest reads no vertical earth rate).', **ro),
    }
    if not on:
        return None
    return LifelongMode(node, values)


class LifelongMode:
    """The node side of lifelong mode (subscriptions, worker, diagnostics)."""

    def __init__(self, node, values):
        self.node = node
        self.values = values
        d = os.path.expanduser(values['lifelong_dir'])
        self.dir = d
        self.registry_dir = os.path.expanduser(values['registry_dir']) or \
            os.path.join(d, 'registry')
        config = LifelongConfig(range_extension_degc=values['range_extension_degc'],
                                new_holds=values['new_holds'],
                                misfit_holds=values['misfit_holds'],
                                holdout_holds=values['holdout_holds'],
                                per_sensor=values['per_sensor_swap'],
                                gyro_follow=values['gyro_follow'],
                                follow_without_latitude=values['follow_without_latitude'])
        self.config = config
        sources = []
        qos = common.sensor_qos(100)
        timeout = values['hint_timeout']
        if values['cmd_vel_topic']:
            sources.append(HintSource('cmd_vel', True, timeout))
            node.create_subscription(Twist, values['cmd_vel_topic'], self._on_twist, qos)
        if values['odom_topic']:
            sources.append(HintSource('odom', False, timeout))
            node.create_subscription(Odometry, values['odom_topic'], self._on_odom, qos)
        if values['still_topic']:
            sources.append(HintSource('still', False, timeout))
            node.create_subscription(Bool, values['still_topic'], self._on_bool, qos)
        self.gate = HintGate(sources)
        self._lock = threading.Lock()        # the Lifelong state
        self._pending = []                   # windows waiting while an estimate runs
        self._busy = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='lifelong')
        self._worker.submit(_lower_priority)
        self.life = None
        self._published = None               # id of the calibration published last
        self.counts = {'hint_messages': 0, 'holds_refused_by_hints': 0}
        self.last_temperature = None

    # ------------------------------------------------------------------ state
    def _manager(self):
        """Create the Lifelong core on first use (the frame_id is known by then)."""
        if self.life is None:
            n = self.node
            frame = n.frame_id or n._seen_frame or 'imu'
            self.life = Lifelong(self.dir, n.settings(), n.k, list(n.temperature_topics),
                                 frame, self.values['sensor_id'] or frame,
                                 self.registry_dir, self.config, log=self._log)
            self._publish_output()
            st = self.life.store.summary()
            n.get_logger().info(
                f'lifelong: {st["holds_total"]} holds so far ({st["raw_holds"]} raw, '
                f'{st["compacted_bins"]} compacted bins) in {self.dir}; active calibration '
                f'{self.life.active.id if self.life.active is not None else "none yet"}'
                + ('; gyro follower idle: the vertical earth rate is not known (set '
                   'use_latitude and latitude, or follow_without_latitude)'
                   if self.config.gyro_follow and self.life.latitude is None
                   and not self.config.follow_without_latitude else ''))
        return self.life

    def _publish_output(self):
        """Publish the lifelong output unless it is the one published last.

        The output: the active calibration, with the gyro follower's offset when
        ``gyro_follow`` is on.
        """
        cal = self.life.output
        if cal is not None and cal.id != self._published:
            self.node.cal_pub.publish(String(data=cal.to_yaml()))
            self._published = cal.id

    def start(self):
        """Load the state now when the frame is configured (publishes the active model)."""
        if self.node.frame_id:
            with self._lock:
                self._manager()

    def inputs_decided(self):
        """Name the node's inputs in the store's calibrations once they are decided.

        The node may have followed its temperature under another name
        (``topic_follower``) after the state was loaded with the configured one.
        """
        with self._lock:
            if self.life is not None:
                self.life.topics = list(self.node.temperature_topics)

    def _log(self, level, text):
        logger = self.node.get_logger()
        if level == 'error':
            logger.error(text)
        elif level == 'warn':
            logger.warning(text)
        else:
            logger.info(text)

    # ------------------------------------------------------------------ hints
    def _now_s(self):
        ns = self.node._newest_ns
        return ns * 1e-9 if ns else None

    def _on_twist(self, msg):
        t = self._now_s()
        self.counts['hint_messages'] += 1
        if t is not None:
            self.gate.add('cmd_vel', t, twist_still(
                [msg.linear.x, msg.linear.y, msg.linear.z],
                [msg.angular.x, msg.angular.y, msg.angular.z]))

    def _on_odom(self, msg):
        self.counts['hint_messages'] += 1
        tw = msg.twist.twist
        self.gate.add('odom', common.stamp_to_ns(msg.header.stamp) * 1e-9, twist_still(
            [tw.linear.x, tw.linear.y, tw.linear.z], [tw.angular.x, tw.angular.y,
                                                      tw.angular.z], threshold=1e-2))

    def _on_bool(self, msg):
        t = self._now_s()
        self.counts['hint_messages'] += 1
        if t is not None:
            self.gate.add('still', t, bool(msg.data))

    # ------------------------------------------------------------------ holds
    def on_windows(self, win):
        """Take the windows of closed holds (called under the node's lock: quick)."""
        if not len(win):
            return
        self._bound_node_collection()
        n0 = len(win.hold_ids)
        kept = self.gate.filter(win)
        self.counts['holds_refused_by_hints'] += n0 - (len(kept.hold_ids) if len(kept) else 0)
        if len(kept) and kept.n_inputs:
            self.last_temperature = float(kept.temp[-1, 0])
        if not len(kept):
            return
        self._pending.append(kept)
        self._flush()

    def _bound_node_collection(self):
        """Keep the node's own collection (for ~/calibrate) to the newest holds.

        In lifelong mode the node runs for weeks: its collection and collection_file are cut
        to the newest ``NODE_HOLDS`` x 3/4 holds when they pass ``NODE_HOLDS`` (the
        lifelong store keeps the rest, compacted). Called under the node's lock.
        """
        node = self.node
        ids = node.windows.hold_ids if len(node.windows) else []
        if len(ids) <= NODE_HOLDS:
            return
        keep = ids[-(NODE_HOLDS * 3 // 4):]
        node.windows = node.windows.select(np.isin(node.windows.hold, keep))
        node.transitions = [t for t in node.transitions if t.hold_from in set(keep.tolist())]
        path = node._collection_path()
        if path:
            try:
                write_atomic(path, node.windows.to_jsonl())
            except (OSError, OutputError) as e:
                node._degrade(e)

    def _flush(self):
        if not self._lock.acquire(blocking=False):
            return                           # an estimate runs: added after it
        try:
            life = self._manager()
            while self._pending:
                life.add(self._pending.pop(0))
            self._publish_output()
            why = '' if self._busy else life.due()
            if why:
                self._busy = True
                self._worker.submit(self._estimate, why)
        finally:
            self._lock.release()

    def _estimate(self, why):
        try:
            with self._lock:
                decision = self.life.estimate(why)
                cal = self.life.output
                if decision['action'] == 'swap':
                    self._publish_output()
            if decision['action'] == 'swap':
                self.node._result = _Result(cal)
                ok, where = self.node._write(cal)
                self.node.get_logger().info(f'lifelong: published {cal.id}; {where}')
        except Exception as e:  # noqa: B902 - report, never kill the worker
            self.node.get_logger().error(f'lifelong estimation failed: {e!r}')
        finally:
            self._busy = False
        self._flush()

    def reset(self):
        """Start the lifelong collection afresh (``~/reset``); return (ok, message).

        The store moves into ``<lifelong_dir>/archive/<UTC time>/`` (``Lifelong.reset``:
        nothing is deleted); the active calibration stays active and published. Refused,
        with nothing changed, while a re-estimate runs or when the archives are full.
        Windows queued during an estimate are stored (and archived) first.
        """
        if not self._lock.acquire(timeout=1.0):
            return False, ('refused: a lifelong re-estimate is running; call ~/reset again '
                           'when it has finished (its decision is logged)')
        try:
            if self.life is not None:
                while self._pending:
                    self.life.add(self._pending.pop(0))
                return True, 'lifelong ' + self.life.reset()['text']
            dest = archive_collection(self.dir)   # not loaded yet: no hold since the start
            return True, ('lifelong collection restarted: ' + (
                f'moved the holds of earlier runs to {dest}/ (kept there, not deleted)'
                if dest else 'nothing collected yet') + '; the active calibration (if any) '
                'stays active')
        except ArchiveFull as e:
            return False, f'refused: {e}'
        except OSError as e:
            return False, (f'failed: the lifelong store in {self.dir} could not be moved aside '
                           f'({e}); fix the directory, then call ~/reset again')
        finally:
            self._lock.release()

    def holds(self):
        """Return the number of holds stored (0 before the first)."""
        return self.life.store.total_holds if self.life is not None else 0

    # ------------------------------------------------------------------ diagnostics
    def statuses(self):
        """Return the /diagnostics status of lifelong mode."""
        node = self.node
        name = f'{node.get_name()}: lifelong calibration'
        if self.life is None:
            return [common.diagnostic_status(name, node.get_fully_qualified_name(),
                                             common.OK, 'waiting for the first hold',
                                             dict(self.counts, **self.gate.counts))]
        now = self._now_s()
        present = self._present_temperature()
        if present is not None:
            self.last_temperature = present
        with_lock = self._lock.acquire(timeout=0.05)
        try:
            st = self.life.status(self.last_temperature, now)
        finally:
            if with_lock:
                self._lock.release()
        values = {k: v for k, v in st.items() if not isinstance(v, (list, tuple, dict))}
        span = st.get('temperature_span')
        if span:
            values['temperature_coverage_degC'] = f'{span[0]:.1f}..{span[1]:.1f}'
        if st.get('valid_range'):
            values['valid_range_degC'] = '{:.1f}..{:.1f}'.format(*st['valid_range'])
        if self.last_temperature is not None:
            values['temperature_degC'] = self.last_temperature
        values.update(self.counts)
        values.update(self.gate.counts)
        level, msg = common.OK, ''
        if not st['active']:
            msg = f'no active calibration yet ({st["holds_total"]} holds)'
        else:
            age = st.get('active_age_s')
            msg = f'active {st["active"]}' + (f', {age / 3600:.1f} h old' if age else '')
            if st.get('in_range') is False:
                level = common.WARN
                msg += (f'; temperature {self.last_temperature:.1f} degC outside its valid '
                        f'range {values.get("valid_range_degC")}')
        if st.get('alarm'):
            level = common.WARN
            msg += '; change alarm: ' + st['alarm']
        return [common.diagnostic_status(name, node.get_fully_qualified_name(), level, msg,
                                         values)]

    def _present_temperature(self):
        """Return the newest reading of the first thermal input the aligner holds, or None."""
        try:
            v = self.node.aligner.tracks[0]._v
            return float(v[-1]) if len(v) else None
        except (AttributeError, IndexError):
            return None

    def shutdown(self):
        """Stop the worker (an estimate in progress finishes in the background)."""
        self._worker.shutdown(wait=False, cancel_futures=True)


class _Result:
    """What ``~/save`` needs of an activated calibration (a CalibrationResult's shape)."""

    def __init__(self, cal):
        self.calibration = cal
        self.summary = 'lifelong calibration'


def _lower_priority():
    """Lower this worker thread's priority (Linux: per thread; elsewhere a no-op)."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)
    except (AttributeError, OSError):
        pass
