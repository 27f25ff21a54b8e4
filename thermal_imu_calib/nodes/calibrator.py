"""Live field calibration: collect stationary segments, estimate on request, publish.

Subscribes ``imu/data_raw`` and ``temperature_topics`` (each in its ``temperature_units``
entry, degC or a thermal proxy's unit such as Hz, written into the calibration; the gyro
follows the one non-degC input by default). The node is split by concern:

* ``nodes/calibrator_params.py``: the parameters, declared from the shared
  ``app.calibrate.CalibrateSettings`` and read back into one (``settings``);
* ``nodes/calibrator_collection.py``: the live collection (``LiveCollection``: aligned
  samples, stationary holds and pose changes, persisted to ``collection_file`` and resumed
  after a restart);
* here: the services, the publishers and the reports.

Services (std_srvs/Trigger): ``~/calibrate`` runs the calibrate use case of the command
line and the fleet (``app.calibrate.calibrate_collected``) on a snapshot of the collection,
on a worker thread, writes ``calibration_file`` atomically (previous kept as ``.bak``,
``app.calibrate.write_calibration``) and publishes it latched on ``imu/calibration``;
``~/reset`` clears the collection (in lifelong mode it also moves the lifelong store into
an archive and keeps the active calibration, ``nodes.lifelong``); ``~/save`` writes the
current model. ``~/progress`` (JSON) and ``/diagnostics`` report coverage and what to hold
next.
"""

from concurrent.futures import ThreadPoolExecutor
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger

from . import (absent_inputs, calibrator_params as params, common, input_hints, late_inputs,
               process, thermal_types, topic_follower)
from .calibrator_collection import LiveCollection
from ..app import calibrate as app
from ..calibration import CalibrationError
from ..collection.segments import FACE_NAMES, Windows
from ..estimation.calibrate import CalibrationRefused
from ..io.gate import gyro_unit_problem, unit_refusal
from ..io.headerless import LiveClocks

NODE_NAME = 'thermal_imu_calibrator'
#: what ``_write`` says when calibration_file is empty (the node is set up not to write)
NOT_CONFIGURED = 'not written (calibration_file is empty)'
#: IMU samples left out for want of a fresh temperature before the log warns, once, why
WARN_AFTER_STALE = 1000
#: ~/calibrate requests queued (reliable, keep last 1000): none is dropped in a burst
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


class CalibratorNode(LiveCollection, Node):
    """Collect stationary statistics from a live IMU and estimate a thermal calibration."""

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        in_depth, period, scalar_types = params.declare(self)
        #: per input: its header stamps, or the IMU's clock (header-less, or stamps 0 or
        #: on another clock), as offline
        self._clocks = LiveClocks(self.temperature_topics,
                                  [common.headerless(cls) for cls, _ in scalar_types])

        self._lock = threading.Lock()    # detector, aligner, windows, pending data
        self._busy = threading.Lock()    # held while an estimation runs
        self._busy_since = 0.0
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='estimation')
        self._reporter = ThreadPoolExecutor(max_workers=1, thread_name_prefix='report')
        self._report_lock = threading.Lock()
        self._report_running = None   # [Popen or None, temporary dir] while a report is drawn
        self._report_stopped = False  # finish() ran: no report child is started after it
        self._result = None              # last CalibrationResult
        self._last_message = ''
        self._seen_frame = ''
        self._rate = common.RateMeter()
        self.counts = {'samples': 0, 'stale_temperature': 0, 'invalid': 0,
                       'temperature_readings': 0, 'temperature_invalid': 0}
        self.readings_per_topic = [0] * self.k
        self._warned_temperature = False
        self._warned_imu = False
        self._started = time.monotonic()
        self._collection_error = ''
        self._new_collection()
        #: a collection made without a temperature nobody published is resumed once the
        #: inputs are decided (``absent_inputs``): without them, or moved aside with them
        self._resume_later = absent_inputs.made_without(self)
        if not self._resume_later:
            self._resume_all()

        data = MutuallyExclusiveCallbackGroup()
        self.imu_sub = self.create_subscription(Imu, 'imu/data_raw', self._on_imu,
                                                common.sensor_qos(in_depth), callback_group=data)
        self.temp_subs = [
            self.create_subscription(cls, topic, self._temperature_cb(i, value),
                                     common.sensor_qos(in_depth), callback_group=data)
            for i, (topic, (cls, value)) in enumerate(zip(self.temperature_topics,
                                                          scalar_types))]
        self._in_depth, self._data_group = in_depth, data
        #: a silent input whose topic is published as another thermal type is
        #: re-subscribed as that type (``thermal_types``), as calibrate reads a log
        self.type_follower = thermal_types.TypeFollower(self, self.temp_subs, self._subscribe_as)
        #: no temperature published at all: collect without one, as calibrate does a log
        #: without one (``absent_inputs``); decided once, before anything is collected
        self._inputs_decided = absent_inputs.decided_at_start(self)
        self._imu_seen_at = None      # steady clock at the first tick that saw an IMU message
        self._input_notes = []        # what was decided about the inputs (the file's notes)
        self._absent_topics = []      # the inputs' topics when decided without them
        #: the IMU's temperature under another name, as calibrate picks it (``topic_follower``)
        self._name_follower = topic_follower.NameFollower.for_node(self)
        common.steady_timer(self, 0.1, self._tick, callback_group=data)
        common.steady_timer(self, thermal_types.FOLLOW_PERIOD_S, self.type_follower,
                            callback_group=data)
        services = ReentrantCallbackGroup()
        # every call answered: a request queue deeper than the default 10 (a burst of calls
        # while one estimates is each refused with the reason, never dropped unanswered)
        self.create_service(Trigger, '~/calibrate', self._on_calibrate, callback_group=services,
                            qos_profile=SERVICE_QOS)
        self.create_service(Trigger, '~/reset', self._on_reset, callback_group=services)
        self.create_service(Trigger, '~/save', self._on_save, callback_group=services)
        self.cal_pub = self.create_publisher(String, 'imu/calibration', common.CALIBRATION_QOS)
        self.progress_pub = self.create_publisher(String, '~/progress', 10)
        self.diagnostics = common.Diagnostics(self)
        common.steady_timer(self, period, self._report,
                            callback_group=MutuallyExclusiveCallbackGroup())
        if self.lifelong is not None:
            self.lifelong.start()

    def _resume_all(self):
        """Resume the collection and its pose changes from their files."""
        self._resume()
        try:
            self._resume_transitions()
        except OSError as e:
            self._degrade(e)

    def _tick(self):
        """Process what arrived, once the thermal inputs are decided (``absent_inputs``)."""
        if self._inputs_decided or self._decide_inputs():
            self._process()
            if self._name_follower is not None:     # lifelong mode, still without one
                absent_inputs.follow_late(self)
        if self._absent_topics:
            late_inputs.watch(self)

    def _decide_inputs(self, force=False):
        """Decide whether to collect with the thermal inputs; return True once decided."""
        return self._inputs_decided or absent_inputs.settle(self, force)

    def input_notes(self):
        """Return what was done to the thermal inputs (the calibration file's notes)."""
        return self._input_notes + self.type_follower.notes + self._clocks.notes

    def _subscribe_as(self, index, typ, topic=None):
        """Subscribe input ``index`` as ``typ`` (``thermal_types``), on ``topic`` if given."""
        cls, value = common.THERMAL_TYPES[typ]
        with self._lock:
            self.temperature_topics[index] = topic or self.temperature_topics[index]
            self._clocks.retype(index, common.headerless(cls), topic)
            self._pending_temp[index] = []
        self.temp_subs[index] = self.create_subscription(
            cls, self.temperature_topics[index], self._temperature_cb(index, value),
            common.sensor_qos(self._in_depth), callback_group=self._data_group)

    # ------------------------------------------------------------------ services
    def settings(self):
        """Return the CalibrateSettings of the parameters (the CLI's defaults where unset)."""
        return params.settings(self)

    def options(self, transitions=()):
        """Return the CalibrateOptions built from the parameters (and these pose changes)."""
        return app.options(self.settings(), [self._collected(Windows.empty(self.k), [], None)],
                           transitions)

    async def _on_calibrate(self, request, response):
        # a coroutine: while the worker thread estimates, the executor keeps serving data
        if not self._busy.acquire(blocking=False):
            response.success = False
            response.message = (f'refused: an estimation is already running (started '
                                f'{time.monotonic() - self._busy_since:.1f} s ago); wait for '
                                'its result')
            return response
        try:
            gyro_unit = gyro_unit_problem(self._rows.gyro_unit)   # as calibrate's gate refuses
            if gyro_unit:
                response.success = False
                response.message = f'refused: {unit_refusal(gyro_unit)}'
                return response
            self._busy_since = time.monotonic()
            self._decide_inputs(force=True)      # no temperature published: without one
            response.success, response.message = await self._on_worker(
                self._estimate, *self.snapshot())
        finally:
            self._busy.release()
        problem = '' if response.success else input_hints.collection_problem(self)
        if problem and response.message.startswith('refused: '):
            response.message = f'refused: {problem}. ({response.message[9:]})'
        back, ahead = self.counts.get('time_resets', 0), self.counts.get('time_gaps', 0)
        if (back or ahead) and self.lifelong is None:
            jumps = ' and '.join(t for t in (f'back {back} time(s)' if back else '',
                                             f'ahead by more than resume_max_gap {ahead} '
                                             'time(s)' if ahead else '') if t)
            response.message += (f'; the IMU header stamps jumped {jumps} while collecting '
                                 '(a recording played again, or another?): the holds of every '
                                 'run are used; call ~/reset before playing one again')
        if self.resumed_holds and self.lifelong is None:
            response.message += (f'; {self.resumed_holds} of the holds were resumed from '
                                 f'{self._collection_path()}, collected before the node '
                                 'restarted (~/reset starts afresh)')
        self._last_message = response.message
        common.log(self, response.success, response.message)
        return response

    def _on_worker(self, fn, *args):
        """Return a Future (of the executor) for ``fn(*args)`` run on the estimation thread."""
        done = Future(executor=self.executor)
        done.add_done_callback(lambda _: None)  # completion wakes the executor
        job = self._worker.submit(fn, *args)
        job.add_done_callback(lambda j: done.set_result(
            j.result() if not j.cancelled() and j.exception() is None
            else (False, f'failed: {j.exception() if not j.cancelled() else "cancelled"}')))
        return done

    def _estimate(self, *snapshot):
        """Run on the worker thread: the calibrate use case, then write and publish.

        The live collection (``snapshot_collected``) goes through the calibrate of the
        command line and the fleet (``app.calibrate.calibrate_collected``, checked by the
        loader the compensator uses). Returns (success, message).
        """
        try:
            collected = self.snapshot_collected(*snapshot)
            result = app.calibrate_collected(self.settings(), [collected])
        except CalibrationRefused as e:
            return False, f'refused: {e}'
        except (CalibrationError, ValueError) as e:
            return False, f'failed: {e}'
        except Exception as e:  # noqa: B902 - report, never kill the worker or the node
            self.get_logger().error(f'estimation crashed: {e!r}')
            return False, f'failed: estimation error {e.__class__.__name__}: {e}'
        return self._publish(result, collected.windows)

    def _publish(self, result, windows):
        """Keep ``result``, write it, publish it latched; returns (success, message)."""
        self._result = result
        ok, where = self._write(result.calibration)
        text = f'{result.summary}; id {result.calibration.id}; {where}'
        if not ok and where != NOT_CONFIGURED:
            # success only when the file was written: the calibration is kept for ~/save
            # and not handed to the compensator (it would be lost at the next restart)
            return False, (f'{text}; not published: fix calibration_file, then call ~/save '
                           '(or ~/calibrate again)')
        if ok and self.get_parameter('report').value:
            self._reporter.submit(self._report_file, result.calibration, windows)
        self.cal_pub.publish(String(data=result.calibration.to_yaml()))
        return True, text

    def _write(self, cal):
        """Write ``cal`` to calibration_file (``app.calibrate.write_calibration``).

        Refused: a directory, a special file, the prior or the collection file; an
        unwritable directory fails. The previous file, whatever it holds, is kept as
        ``.bak`` (so another kind of file is replaced, not lost). Returns (ok, text);
        ``(False, NOT_CONFIGURED)`` when calibration_file is empty.
        """
        path = os.path.expanduser(self.get_parameter('calibration_file').value)
        if not path:
            return False, NOT_CONFIGURED
        try:
            inputs = [os.path.expanduser(self.get_parameter('prior_file').value),
                      self._collection_path()]
            app.write_calibration(cal, path, inputs, keep_backup=True)
        except (OSError, ValueError) as e:
            return False, f'NOT written to {path}: {e}'
        return True, f'written to {path}'

    def _report_file(self, cal, windows):
        """Write <calibration_file>.report.html; runs on the report thread, failures logged.

        The page is drawn by ``thermal-imu-calib report`` in a child process at lower
        priority (from snapshots of the calibration and the windows), so plotting never
        holds this process's GIL while data keep arriving.
        """
        path = os.path.expanduser(self.get_parameter('calibration_file').value)
        out = os.path.splitext(path)[0] + '.report.html'
        tmp = None
        try:
            with self._report_lock:
                # made, filled and recorded in one step: _stop_report removes whatever it
                # finds recorded. A temporary made outside the lock was once left empty by a
                # node stopping in between; filled outside it, _stop_report removed the
                # directory, the save made it again (write_atomic) and the process exited
                # with a .cal.yaml.*.partial in it (2026-11-29, a live scoreboard run)
                if self._report_stopped:
                    return
                tmp = tempfile.mkdtemp(prefix='thermal-imu-report-')
                self._report_running = [None, tmp]
                cal.save(os.path.join(tmp, 'cal.yaml'))
                with open(os.path.join(tmp, 'windows.jsonl'), 'w') as f:
                    f.write(windows.to_jsonl())
            cmd = [sys.executable, '-m', 'thermal_imu_calib.cli', 'report',
                   os.path.join(tmp, 'cal.yaml'), '--windows',
                   os.path.join(tmp, 'windows.jsonl'), '--html', out]
            with self._report_lock:
                if self._report_stopped:
                    return
                child = subprocess.Popen(cmd, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True,
                                         preexec_fn=lambda: os.nice(10))
                self._report_running[0] = child
            try:
                _, err = child.communicate(timeout=600)
            except subprocess.TimeoutExpired:
                child.kill()
                child.communicate()
                err = 'the report took over 600 s and was stopped'
        except OSError as e:
            self.get_logger().error(f'report {out} not written: {e!r}')
            return
        finally:
            with self._report_lock:
                self._report_running = None
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        if child.returncode and self._report_stopped:
            self.get_logger().info(f'report {out} not written: the node is shutting down')
        elif child.returncode:
            self.get_logger().error(f'report {out} not written: '
                                    f'{err.strip()[-500:] or f"exit {child.returncode}"}')
        else:
            self.get_logger().info(f'wrote report {out}')

    def _stop_report(self):
        """Stop a report being drawn (SIGTERM: it removes its temporary) and remove its inputs.

        On the way out the process does not wait for the report thread, so without this the
        child went on drawing after the node had gone and its temporary directory was left.
        """
        with self._report_lock:
            self._report_stopped = True
            running = self._report_running
        if running is None:
            return
        child, tmp = running
        if child is not None:
            try:
                child.terminate()
                child.wait(timeout=5)
            except (OSError, subprocess.SubprocessError):
                child.kill()
        shutil.rmtree(tmp, ignore_errors=True)

    def _on_save(self, request, response):
        result = self._result
        if result is None:
            response.success = False
            response.message = 'no calibration estimated yet; call ~/calibrate first'
            return response
        response.success, where = self._write(result.calibration)
        response.message = f'calibration {result.calibration.id} {where}'
        return response

    def _on_reset(self, request, response):
        life = ''
        if self.lifelong is not None:     # first: a refusal there leaves everything as it was
            ok, life = self.lifelong.reset()
            if not ok:
                response.success, response.message = False, life
                self.get_logger().warning(f'~/reset {life}')
                return response
        with self._lock:
            n, h, t = len(self.windows), len(self.windows.hold_ids), len(self.transitions)
            self._new_collection()
            self.counts.update({k: 0 for k in self.counts})
            self._clocks = self._clocks.fresh()   # stamps judged afresh, as a new log's
            if self._absent_topics:     # the watched inputs' too, from the next message on
                self._late_inputs.shadow(self)
            self._rows.gyro_unit = 0      # a driver fixed since: its data are judged afresh
            self.readings_per_topic = [0] * self.k
            path = self._collection_path()
            if path and os.path.exists(path):
                os.unlink(path)
            tdir = self._transitions_dir()
            if tdir and os.path.isdir(tdir):
                shutil.rmtree(tdir)
            self._write_inputs_signature()
        response.success = True
        response.message = f'cleared {n} windows ({h} holds) and {t} pose changes' + (
            f'; removed {path} and {tdir}/' if path else '') + (f'; {life}' if life else '')
        self.get_logger().info(response.message)
        return response

    # ------------------------------------------------------------------ reporting
    def progress(self):
        """Return the progress dict published on ~/progress."""
        with self._lock:
            windows, n_transitions = self.windows, len(self.transitions)
            status = self.detector.status()
            dropped = sum(self.transitions_dropped.values()) + sum(
                self.detector.dropped.values())
        ready = app.readiness(self.settings(), windows)
        cov = ready['coverage']
        return {
            'segments': cov['holds'], 'windows': cov['windows'],
            'faces': {f: cov['faces'][f]['holds'] for f in FACE_NAMES},
            'faces_covered': [f for f in FACE_NAMES if cov['faces'][f]['holds']],
            'missing_faces': cov['missing'], 'tilted_segments': cov['tilted_holds'],
            'temperature_span': cov['temperature_span'],
            'ready': ready['ready'], 'mode': ready['mode'], 'reason': ready['reason'],
            'next_pose': ready['next_pose'],
            'stationary': status['stationary'], 'hold_seconds': round(status['hold_seconds'], 2),
            'pose_changes': n_transitions, 'pose_changes_dropped': dropped,
            'samples': self.counts['samples'], 'imu_received': self._rate.total,
            'temperature_readings': self.counts['temperature_readings'],
            'temperature_invalid': self.counts['temperature_invalid'],
            'imu_publishers': self.imu_sub.get_publisher_count(),
            'temperature_publishers': [sub.get_publisher_count() for sub in self.temp_subs],
            'stale_temperature_samples': self.counts['stale_temperature'],
            'calibrating': self._busy.locked(), 'last_result': self._last_message,
        }

    def _report(self):
        prog = self.progress()
        self.progress_pub.publish(String(data=json.dumps(prog)))
        rate = self._rate.rate()
        values = {k: v for k, v in prog.items() if k not in ('faces', 'imu_received')}
        values.update({f'face {f}': n for f, n in prog['faces'].items()})
        values['input_rate_hz'] = rate
        values.update(self.counts)
        for topic, how in self._clocks.describe().items():
            values[f'temperature_clock[{topic}]'] = how
        for topic, typ in zip(self.temperature_topics, self.type_follower.types):
            values[f'temperature_type[{topic}]'] = typ
        level = common.OK
        msg = ('ready: ' if prog['ready'] else 'collecting: ') + prog['reason']
        if prog['next_pose']:
            msg += f'; next pose {prog["next_pose"]} up'
        if rate == 0.0:
            level, msg = common.WARN, 'no IMU input; ' + msg
        elif self.k and self.counts['stale_temperature'] and self.counts['samples'] == 0:
            level, msg = common.WARN, 'no fresh temperature; ' + msg
        # each said once; the graph is read for the hint only then, not every period
        if not self._warned_imu:
            silent = input_hints.silent_imu(self, self._started, self._rate.total)
            if silent:
                self._warned_imu = True
                self.get_logger().warning(silent)
        if rate and not self._warned_temperature \
                and self.counts['stale_temperature'] >= WARN_AFTER_STALE:
            problem = input_hints.collection_problem(self)
            if problem:
                self._warned_temperature = True
                self.get_logger().warning(problem)
        self.diagnostics.publish([common.diagnostic_status(
            f'{self.get_name()}: thermal calibration', self.get_fully_qualified_name(), level,
            msg, values)] + (self.lifelong.statuses() if self.lifelong is not None else []))

    def finish(self):
        """Stop the estimation workers and a report being drawn (idempotent; called first)."""
        self._worker.shutdown(wait=False, cancel_futures=True)
        self._reporter.shutdown(wait=False, cancel_futures=True)
        self._stop_report()
        if self.lifelong is not None:
            self.lifelong.shutdown()

    def destroy_node(self):
        """Finish (``finish``), then destroy the node."""
        self.finish()
        return super().destroy_node()


def main(args=None):
    """Run the calibrator node (estimation runs on a worker thread, data keeps flowing)."""
    process.exit_process(process.run_nodes([CalibratorNode], args))


if __name__ == '__main__':
    main()
