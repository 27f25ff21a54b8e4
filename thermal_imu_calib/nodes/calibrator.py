"""Live field calibration: collect stationary segments, estimate on request, publish.

Subscribes ``imu/data_raw`` and ``temperature_topics`` (each in its ``temperature_units``
entry, degC or a thermal proxy's unit such as Hz, written into the calibration; the gyro
follows the one non-degC input by default); aligns them to IMU header stamps
(``io.align.StreamAligner``), runs the stationary detector online
(``gyro_fit.MotionCollector``) and keeps only the closed holds' window statistics
(``Windows``), appending each to ``collection_file`` (JSON lines), and the raw samples of the
pose changes between consecutive holds (what ``whole_unit`` fits gyro scale and misalignment
from), one ``.npz`` each written atomically into ``<collection_file>.transitions/``, so a
restarted node resumes where it stopped. Services (std_srvs/Trigger):
``~/calibrate`` estimates with ``calibrate_windows`` on a worker thread, writes
``calibration_file`` atomically (previous kept as ``.bak``) and publishes it latched on
``imu/calibration``; ``~/reset`` clears the collection; ``~/save`` writes the current model.
``~/progress`` (JSON) and ``/diagnostics`` report coverage and what to hold next.

Cohesive: one rclpy node (parameters, subscriptions, services) around the collection and
estimation core; no maths.
"""

from concurrent.futures import ThreadPoolExecutor
import copy
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger

from . import common, lifelong as lifelong_mode, process
from ..calibration import CalibrationError, TemperatureInput
from ..estimation import calibrate as estimation
from ..app import calibrate as app
from ..app.calibrate import CalibrateSettings
from ..estimation.calibrate import CalibrationRefused, readiness
from ..collection.motion import load_transitions, MotionCollector, offset_holds, save_transitions
from ..collection.segments import FACE_NAMES, Windows
from ..collection.stationary import DetectorConfig, DetectorSettingsError
from ..gravity import resolve_gravity
from ..io.align import StreamAligner
from ..io.columns import ImuColumns, TemperatureColumns
from ..io.output import CALIBRATION, OutputError, Outputs, write_atomic
from ..pipeline import Collected

NODE_NAME = 'thermal_imu_calibrator'
#: what ``_write`` says when calibration_file is empty (the node is set up not to write)
NOT_CONFIGURED = 'not written (calibration_file is empty)'
#: ~/calibrate requests queued (reliable, keep last 1000): none is dropped in a burst
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

#: the defaults every calibrate path shares (app.calibrate.CalibrateSettings)
DEFAULTS = CalibrateSettings()
_DET = DEFAULTS.detector


def _param_default(value, derived=0.0):
    """Return a detector default as a parameter value: None (derived) becomes ``derived``."""
    return derived if value is None else float(value)


#: DetectorConfig fields exposed as parameters: (default, lo, hi, description); 0 (the guard:
#: -1) means derived from the first samples, as the command line's options left out
DETECTOR_PARAMS = {
    'block_s': (_param_default(_DET.block_s), 0.0, 60.0,
                'Block length (s) of the stillness test; 0: derived from the rate (~0.1 s, '
                '>= 5 samples).'),
    'window_s': (_param_default(_DET.window_s), 0.0, 3600.0,
                 'Length (s) of the windows a hold is cut into; 0: derived.'),
    'min_hold_s': (_param_default(_DET.min_hold_s), 0.0, 36000.0,
                   'Minimum segment length (s): shorter holds (after the guards) are '
                   'discarded; 0: derived.'),
    'guard_s': (_param_default(_DET.guard_s, -1.0), -1.0, 600.0,
                'Seconds trimmed from both ends of each hold; -1: derived.'),
    'accel_factor': (_param_default(_DET.accel_factor), 0.0, 1e4,
                     'A block is still when its accel variance is below this factor times '
                     'the noise floor; 0: derived (chi-square).'),
    'gyro_factor': (_param_default(_DET.gyro_factor), 0.0, 1e4,
                    'Same for the gyro variance; 0: derived.'),
    'mean_sigmas': (_DET.mean_sigmas, 1.0, 1000.0, 'Neighbouring block means may differ by '
                                                   'this many standard errors in a hold.'),
    'noise_quantile': (_DET.noise_quantile, 0.001, 0.9,
                       'Quantile of block variances taken as noise floor.'),
    'rotation_dps': (_DET.rotation_dps, 0.001, 100.0,
                     'Rotation rate (deg/s) still counted as held (tremor).'),
}


class CalibratorNode(Node):
    """Collect stationary statistics from a live IMU and estimate a thermal calibration."""

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        p = common.Parameters(self)
        ro = {'read_only': True}
        self.calibration_file = p.declare(
            'calibration_file', '~/.ros/thermal_imu_calib/calibration.yaml',
            'Where ~/calibrate and ~/save write the calibration (atomically; the previous '
            'file is kept as <file>.bak).')
        self.collection_file = p.declare(
            'collection_file', '~/.ros/thermal_imu_calib/collection.jsonl',
            'JSON-lines file the collected windows are appended to and resumed from at start '
            '(empty: keep them in memory only).', **ro)
        self.temperature_topics = common.topic_list(p.declare(
            'temperature_topics', ['imu/temperature'],
            'Thermal input topics (sensor_msgs/Temperature unless temperature_types says '
            'otherwise), one model input each, in this order; they are written into the '
            'calibration as the inputs\' topics; empty ([] or [\'\']): no thermal input (a '
            'temperature-independent calibration).', **ro))
        self.temperature_units, scalar_types = common.declare_thermal_inputs(
            p, self.temperature_topics, ' Written into the calibration; by default the gyro '
            'follows the one non-degC input and the accelerometer the degC ones.')
        self.temperature_timeout = p.declare(
            'temperature_timeout', 2.0,
            'Seconds (header stamps) a reading may be interpolated over or held; IMU samples '
            'without a temperature that fresh are not collected.', lo=0.001, hi=3600.0, **ro)
        self.model = p.declare('model', DEFAULTS.model,
                               'Model to estimate: auto chooses held out, as the command line '
                               'does (the standard static fit unless a richer model predicts '
                               'held-out holds better); whole_unit (seed 002) also fits gyro '
                               'scale and misalignment from the pose changes between holds.',
                               choices=_model_choices())
        self.order = p.declare('order', DEFAULTS.order, 'Highest polynomial order in '
                               'temperature (reduced automatically when the span is small).',
                               lo=0, hi=2)
        self.out_of_range = p.declare('out_of_range', DEFAULTS.out_of_range,
                                      'Written into the calibration: what the compensator does '
                                      'outside the collected temperature range.',
                                      choices=('clamp', 'extrapolate'))
        self.gravity = p.declare('gravity', 0.0, 'Local gravity in m/s^2 (9.7..9.9); 0 derives '
                                 'it from latitude/altitude (use_latitude) or uses standard '
                                 'gravity.', lo=0.0, hi=9.9, validator=_check_gravity)
        self.use_latitude = p.declare('use_latitude', False,
                                      'Derive gravity from latitude and altitude (WGS84 normal '
                                      'gravity) when gravity is 0.')
        self.latitude = p.declare('latitude', 45.0, 'Geodetic latitude, degrees.',
                                  lo=-90.0, hi=90.0)
        self.altitude = p.declare('altitude', DEFAULTS.altitude, 'Ellipsoidal height, metres.',
                                  lo=-1000.0, hi=10000.0)
        p.declare('range_margin', DEFAULTS.range_margin, 'Valid range = collected '
                  'temperature range widened by this (degC).', lo=0.0, hi=50.0)
        self.frame_id = p.declare('frame_id', '', 'IMU frame written into the calibration; '
                                  'empty: the header frame_id of the first IMU message.')
        self.prior_file = p.declare('prior_file', '', 'Optional lab calibration (k0, b0, S at '
                                    'T0) the field estimate refines; empty: none.')
        det = {name: p.declare(name, d, desc, lo=lo, hi=hi, **ro)
               for name, (d, lo, hi, desc) in DETECTOR_PARAMS.items()}
        # 0 (-1 for the guard) means: derived by the detector from the first samples
        det = {k: (None if v == (-1.0 if k == 'guard_s' else 0.0) else v)
               for k, v in det.items()}
        self.detector_config = DetectorConfig(**det)
        self.detector_config.validate()
        self.max_transitions = p.declare(
            'max_transitions', DEFAULTS.max_transitions, 'Most pose changes between holds '
            'kept (raw samples, ~70 kB each at 200 Hz) for the gyro scale/misalignment fit; '
            'further ones are counted as dropped; 0: keep none.', lo=0, hi=10000, **ro)
        self.max_transition_s = p.declare(
            'max_transition_s', DEFAULTS.max_transition_s, 'Longest pose change kept (s, end '
            'of one hold to the start of the next); longer ones are dropped and counted.',
            lo=1.0, hi=600.0, **ro)
        p.declare(
            'report', True, 'After each successful ~/calibrate also write an HTML report '
            '(<calibration_file>.report.html, figures embedded) next to the calibration file, '
            'on a background thread.')
        in_depth = p.declare('input_depth', 1000, 'QoS history depth (best effort) of the '
                             'input subscriptions.', lo=1, hi=100000, **ro)
        period = p.declare('progress_period', 1.0, 'Seconds between ~/progress and '
                           '/diagnostics messages.', lo=0.05, hi=60.0, **ro)
        self.lifelong = lifelong_mode.declare(self, p)   # None unless lifelong: true
        self.k = len(self.temperature_topics)
        self.inputs = [TemperatureInput(app.input_name(t, i), t, u) for i, (t, u) in
                       enumerate(zip(self.temperature_topics, self.temperature_units))]

        self._lock = threading.Lock()    # detector, aligner, windows, pending data
        self._busy = threading.Lock()    # held while an estimation runs
        self._busy_since = 0.0
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='estimation')
        self._reporter = ThreadPoolExecutor(max_workers=1, thread_name_prefix='report')
        self._result = None              # last CalibrationResult
        self._last_message = ''
        self._seen_frame = ''
        self._rate = common.RateMeter()
        self.counts = {'samples': 0, 'stale_temperature': 0, 'invalid': 0,
                       'temperature_readings': 0, 'temperature_invalid': 0}
        self._collection_error = ''
        self._new_collection()
        self._resume()
        try:
            self._resume_transitions()
        except OSError as e:
            self._degrade(e)

        data = MutuallyExclusiveCallbackGroup()
        self.imu_sub = self.create_subscription(Imu, 'imu/data_raw', self._on_imu,
                                                common.sensor_qos(in_depth), callback_group=data)
        self.temp_subs = [
            self.create_subscription(cls, topic, self._temperature_cb(i, value),
                                     common.sensor_qos(in_depth), callback_group=data)
            for i, (topic, (cls, value)) in enumerate(zip(self.temperature_topics,
                                                          scalar_types))]
        self.create_timer(0.1, self._process, callback_group=data)
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
        self.create_timer(period, self._report, callback_group=MutuallyExclusiveCallbackGroup())
        if self.lifelong is not None:
            self.lifelong.start()

    # ------------------------------------------------------------------ collection state
    def _new_collection(self):
        self.detector = self._collector()
        self.aligner = StreamAligner(self.k, self.temperature_timeout)
        self.windows = Windows.empty(self.k)
        self.transitions = []            # replaced, never mutated: snapshots stay consistent
        self.transitions_dropped = {'too_long': 0, 'incomplete': 0, 'over_limit': 0}
        self._hold_offset = 0
        self._newest_ns = None
        self._pending_imu = []
        self._pending_temp = [[] for _ in range(self.k)]

    def _collector(self):
        """Return a new stationary detector that also keeps the pose changes between holds."""
        return MotionCollector(DetectorConfig(**vars(self.detector_config)), self.k,
                               max_transition_s=self.max_transition_s)

    def _collection_path(self):
        if getattr(self, '_collection_error', None):
            return ''
        return os.path.expanduser(self.collection_file) if self.collection_file else ''

    def _transitions_dir(self):
        path = self._collection_path()
        return path + '.transitions' if path else ''

    def _inputs_signature(self):
        """Return what the collected windows' thermal columns mean (topics and units)."""
        return {'temperature_topics': list(self.temperature_topics),
                'temperature_units': list(self.temperature_units)}

    def _write_inputs_signature(self):
        path = self._collection_path()
        if path:
            try:
                os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
                write_atomic(path + '.inputs.json',
                             json.dumps(self._inputs_signature(), indent=1) + '\n')
            except (OSError, OutputError) as e:
                self._degrade(e)

    def _signature_mismatch(self, path):
        """Return why the collection at ``path`` has other thermal inputs (None: same)."""
        try:
            with open(path + '.inputs.json') as f:
                old = json.load(f)
        except FileNotFoundError:
            return None                  # written by an older version: only k is checked
        except (OSError, ValueError) as e:
            return f'its {path}.inputs.json is unreadable ({e})'
        new = self._inputs_signature()
        if old != new:
            return (f'it was collected with temperature inputs {old.get("temperature_topics")} '
                    f'in {old.get("temperature_units")}, this node has '
                    f'{new["temperature_topics"]} in {new["temperature_units"]}')
        return None

    def _resume(self):
        try:
            self._resume_file()
        except (OSError, OutputError) as e:
            self._degrade(e)

    def _degrade(self, err):
        """Collect in memory only when the collection file cannot be read or written."""
        path = self._collection_path()
        self._collection_error = f'{err.__class__.__name__}: {err}'
        self.get_logger().error(f'collection file {path} cannot be used ({err}); collecting '
                                'in memory only (set collection_file to a writable path to '
                                'keep the collection across restarts)')

    def _resume_file(self):
        path = self._collection_path()
        if not path or not os.path.exists(path):
            self._write_inputs_signature()
            return
        with open(path, 'rb') as f:
            data = f.read()
        text, skipped, total = _good_records(data, self.k)
        try:
            win = Windows.from_jsonl(text, self.k)
            if total and not skipped and len(win) == 0:
                raise ValueError('no record could be read')
            if total and skipped == total:
                raise ValueError(f'none of its {total} records could be read')
        except (KeyError, TypeError, ValueError, IndexError) as e:
            win, why = None, f'unreadable ({e.__class__.__name__}: {e})'
        else:
            if skipped:
                self.get_logger().warning(f'collection file {path}: skipped {skipped} of '
                                          f'{total} records that could not be read (not '
                                          'UTF-8, not JSON, or missing a field)')
            why = (None if len(win) == 0 or win.n_inputs == self.k else
                   f'it has {win.n_inputs} temperature inputs, this node {self.k}')
            why = why or self._signature_mismatch(path)
        if why:
            aside = f'{path}.incompatible-{int(time.time())}'
            os.replace(path, aside)
            tdir = self._transitions_dir()
            if os.path.isdir(tdir):
                os.replace(tdir, aside + '.transitions')
            if os.path.exists(path + '.inputs.json'):
                os.replace(path + '.inputs.json', aside + '.inputs.json')
            self._write_inputs_signature()
            self.get_logger().error(f'collection file {path} not resumed: {why}; moved to '
                                    f'{aside}, starting a new collection')
            return
        self.windows = win
        self._hold_offset = int(win.hold.max()) + 1 if len(win) else 0
        # rewrite only the complete records, so appends never follow a torn last line
        write_atomic(path, win.to_jsonl())
        self._write_inputs_signature()
        self.get_logger().info(f'resumed {len(win)} windows ({len(win.hold_ids)} holds) from '
                               f'{path}')

    def _resume_transitions(self):
        """Load the pose changes persisted next to the collection file.

        Those whose holds were not resumed (killed between the two writes) are removed: the
        next holds reuse their ids. Unreadable files are renamed ``*.unreadable``.
        """
        tdir = self._transitions_dir()
        if not tdir or not os.path.isdir(tdir):
            return
        holds = set(self.windows.hold_ids.tolist())
        kept, stale = [], 0
        for name in sorted(os.listdir(tdir)):
            path = os.path.join(tdir, name)
            if name.startswith('.'):     # a temporary file of a write that was cut short
                os.unlink(path)
                continue
            if not name.endswith('.npz'):
                continue
            try:
                trs = load_transitions(path)
            except ValueError as e:
                os.replace(path, path + '.unreadable')
                self.get_logger().error(f'pose change not resumed: {e}; renamed to '
                                        f'{path}.unreadable (one pose change lost)')
                continue
            if all(t.hold_from in holds and t.hold_to in holds and len(t.temps) == self.k
                   for t in trs):
                kept.extend(trs)
            else:
                stale += 1
                os.unlink(path)
        self.transitions = sorted(kept, key=lambda t: t.hold_to)[:self.max_transitions]
        self.get_logger().info(f'resumed {len(self.transitions)} pose changes from {tdir}' + (
            f' ({stale} removed: their holds were not in the collection file)' if stale
            else ''))

    def _persist(self, win):
        path = self._collection_path()
        if not path:
            return
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            with open(path, 'a') as f:
                f.write(win.to_jsonl())
                f.flush()
                os.fsync(f.fileno())
        except OSError as e:
            self._degrade(e)

    def _persist_transition(self, tr):
        tdir = self._transitions_dir()
        if not tdir:
            return
        try:
            os.makedirs(tdir, exist_ok=True)
            buf = io.BytesIO()
            save_transitions(buf, [tr])
            write_atomic(os.path.join(tdir, f'{tr.hold_from:06d}-{tr.hold_to:06d}.npz'),
                         buf.getvalue())
        except (OSError, OutputError) as e:
            self._degrade(e)

    def _store(self, win, detector, offset):
        """Add closed holds and the pose changes ``detector`` made, with ids offset; persist.

        Windows are written before the pose changes that refer to them (see
        ``_resume_transitions``); beyond ``max_transitions`` pose changes are counted only.
        """
        if len(win):
            win.hold = win.hold + offset
            self._persist(win)
            self.windows = Windows.concat([self.windows, win])
            if self.lifelong is not None:
                self.lifelong.on_windows(win)
        new = offset_holds(detector.pop_transitions(), offset)
        room = max(self.max_transitions - len(self.transitions), 0)
        self.transitions_dropped['over_limit'] += max(len(new) - room, 0)
        for tr in new[:room]:
            self._persist_transition(tr)
        if new[:room]:
            self.transitions = self.transitions + new[:room]

    # ------------------------------------------------------------------ data
    def _temperature_cb(self, index, value='temperature'):
        def cb(msg):
            # drained too, so temperature keeps pace with batched IMU data under load
            for m in [msg] + common.drain(self.temp_subs[index], 100, self):
                v = getattr(m, value)
                if not np.isfinite(v):
                    self.counts['temperature_invalid'] += 1
                    continue
                self.counts['temperature_readings'] += 1
                with self._lock:
                    self._pending_temp[index].append((common.stamp_to_ns(m.header.stamp), v))
        return cb

    def _on_imu(self, msg):
        msgs = [msg]
        msgs.extend(common.drain(self.imu_sub, 999, self))
        if not self._seen_frame:
            self._seen_frame = msg.header.frame_id
        stamps, accel, gyro = common.imu_to_arrays(msgs)
        self._rate.add(len(msgs))
        with self._lock:
            self._pending_imu.append((stamps, accel, gyro))

    def _process(self):
        with self._lock:
            pending, self._pending_imu = self._pending_imu, []
            temps, self._pending_temp = self._pending_temp, [[] for _ in range(self.k)]
            if not pending and not any(temps):
                return
            imu = ImuColumns(*(np.concatenate(c) for c in zip(*pending))) if pending \
                else ImuColumns.empty()
            tcols = [TemperatureColumns(np.array([s for s, _ in t], np.int64),
                                        np.array([v for _, v in t], float)) for t in temps]
            if len(imu):
                self._check_time(int(imu.stamp_ns.min()))
                self._newest_ns = max(self._newest_ns or 0, int(imu.stamp_ns.max()))
            for chunk in self.aligner.push_columns(imu, tcols):
                self._collect(chunk)

    def _check_time(self, stamp_ns):
        """Close the open hold and restart detection when header stamps jump back.

        A replayed bag restarting or a second recording must not be merged into the hold
        in progress; the windows collected so far are kept.
        """
        if self._newest_ns is None or stamp_ns >= self._newest_ns - int(common.JUMP_S * 1e9):
            return
        for chunk in self.aligner.finish():
            self._collect(chunk)
        try:
            self._store(self.detector.finish(), self.detector, self._hold_offset)
        except DetectorSettingsError as e:
            self._detector_failed(e)
        self._hold_offset = int(self.windows.hold.max()) + 1 if len(self.windows) else 0
        for why, n in self.detector.dropped.items():
            self.transitions_dropped[why] += n
        self.detector = self._collector()   # no pose change across the jump
        self.aligner = StreamAligner(self.k, self.temperature_timeout)
        self._newest_ns = None
        self.counts['time_resets'] = self.counts.get('time_resets', 0) + 1
        self.get_logger().warning('IMU header stamps jumped back by more than '
                                  f'{common.JUMP_S:.0f} s: closed the hold in progress and '
                                  'restarted detection (collected windows kept)')

    def _collect(self, chunk):
        imu = chunk.imu
        finite = np.isfinite(imu.accel).all(1) & np.isfinite(imu.gyro).all(1)
        use = _usable(chunk, self.k, self.temperature_timeout)
        self.counts['invalid'] += int((~finite).sum())
        self.counts['stale_temperature'] += int((finite & ~use).sum())
        self.counts['samples'] += int(use.sum())
        if not use.any():
            return
        try:
            win = self.detector.update(imu.t[use], imu.accel[use], imu.gyro[use],
                                       chunk.temps[use])
        except DetectorSettingsError as e:
            self._detector_failed(e)
            return
        self._store(win, self.detector, self._hold_offset)

    def _detector_failed(self, err):
        """Restart detection after samples whose stamps give no usable detector settings.

        The samples since the last restart are dropped (counted in ``detector_restarts``);
        the windows and pose changes collected before are kept.
        """
        self.detector = self._collector()
        self._hold_offset = int(self.windows.hold.max()) + 1 if len(self.windows) else 0
        self.counts['detector_restarts'] = self.counts.get('detector_restarts', 0) + 1
        self.get_logger().warning(f'stationary detection restarted, samples dropped: {err}',
                                  throttle_duration_sec=10.0)

    # ------------------------------------------------------------------ services
    def settings(self):
        """Return the CalibrateSettings of the parameters (the CLI's defaults where unset)."""
        def value(name):
            return self.get_parameter(name).value
        g = value('gravity')
        use_latitude = value('use_latitude')
        return CalibrateSettings(
            model=value('model'), order=value('order'), out_of_range=value('out_of_range'),
            range_margin=value('range_margin'), gravity=g if g > 0 else None,
            latitude=value('latitude') if use_latitude else None,
            altitude=value('altitude') if use_latitude else DEFAULTS.altitude,
            prior=value('prior_file') or None, frame_id=value('frame_id'),
            input_units=[f'{t}={u}' for t, u in
                         zip(self.temperature_topics, self.temperature_units)],
            detector=DetectorConfig(**vars(self.detector_config)),
            max_transitions=self.max_transitions, max_transition_s=self.max_transition_s)

    def options(self, transitions=()):
        """Return the CalibrateOptions built from the parameters (and these pose changes)."""
        return app.options(self.settings(), [self._collected(Windows.empty(self.k), [], None)],
                           transitions)

    def _collected(self, windows, transitions, detector):
        """Return the live collection as the Collected a log gives (``pipeline``)."""
        return Collected(windows, self._seen_frame, self._rate.total, 0.0,
                         list(self.temperature_topics), list(transitions),
                         detector=detector)

    async def _on_calibrate(self, request, response):
        # a coroutine: while the worker thread estimates, the executor keeps serving data
        if not self._busy.acquire(blocking=False):
            response.success = False
            response.message = (f'refused: an estimation is already running (started '
                                f'{time.monotonic() - self._busy_since:.1f} s ago); wait for '
                                'its result')
            return response
        try:
            self._busy_since = time.monotonic()
            self._process()  # take in what arrived since the last timer tick
            with self._lock:
                # never mutated in place: consistent snapshots
                windows, transitions = self.windows, self.transitions
                detector = copy.deepcopy(self.detector)
                aligner = copy.deepcopy(self.aligner)
                offset = self._hold_offset
            done = Future(executor=self.executor)
            done.add_done_callback(lambda _: None)  # completion wakes the executor
            job = self._worker.submit(self._estimate, windows, transitions, detector, aligner,
                                      offset)
            job.add_done_callback(lambda j: done.set_result(
                j.result() if not j.cancelled() and j.exception() is None
                else (False, f'failed: {j.exception() if not j.cancelled() else "cancelled"}')))
            response.success, response.message = await done
        finally:
            self._busy.release()
        self._last_message = response.message
        common.log(self, response.success, response.message)
        return response

    def _estimate(self, windows, transitions, detector, aligner, offset):
        """Run on the worker thread: estimate, write, publish. Returns (success, message).

        ``detector`` and ``aligner`` are copies of the live ones: finishing them adds the
        samples still waiting for a newer temperature reading and the hold in progress (if
        long enough), and the pose change into it, to this estimate without closing
        anything in the live collection.
        """
        try:
            parts = []
            for chunk in aligner.finish():
                use = _usable(chunk, self.k, self.temperature_timeout)
                if use.any():
                    imu = chunk.imu
                    parts.append(detector.update(imu.t[use], imu.accel[use], imu.gyro[use],
                                                 chunk.temps[use]))
            parts.append(detector.finish())
            tail = Windows.concat(parts)
            if len(tail):
                tail.hold = tail.hold + offset
                windows = Windows.concat([windows, tail])
            room = max(self.max_transitions - len(transitions), 0)
            transitions = list(transitions) + offset_holds(detector.pop_transitions(),
                                                           offset)[:room]
            # the calibrate of the command line and the fleet (checked by the loader the
            # compensator uses: never publish a calibration it would refuse)
            result = app.calibrate_collected(
                self.settings(), [self._collected(windows, transitions,
                                                  detector.det.settings())])
        except CalibrationRefused as e:
            return False, f'refused: {e}'
        except (CalibrationError, ValueError) as e:
            return False, f'failed: {e}'
        except Exception as e:  # noqa: B902 - report, never kill the worker or the node
            self.get_logger().error(f'estimation crashed: {e!r}')
            return False, f'failed: estimation error {e.__class__.__name__}: {e}'
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
        """Write ``cal`` to calibration_file (checked by ``io.output``); returns (ok, text).

        Refused: a directory, a special file, the prior or the collection file; an
        unwritable directory fails. The previous file, whatever it holds, is kept as
        ``.bak`` (so another kind of file is replaced, not lost). ``(False, NOT_CONFIGURED)``
        when calibration_file is empty.
        """
        path = os.path.expanduser(self.get_parameter('calibration_file').value)
        if not path:
            return False, NOT_CONFIGURED
        try:
            inputs = [os.path.expanduser(self.get_parameter('prior_file').value),
                      self._collection_path()]
            Outputs(inputs, force=True).file(path, 'calibration_file', 'calibration file',
                                             CALIBRATION)
            if os.path.exists(path):
                _atomic_copy(path, path + '.bak')
            cal.save(path)
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
        with tempfile.TemporaryDirectory(prefix='thermal-imu-report-') as tmp:
            cal.save(os.path.join(tmp, 'cal.yaml'))
            with open(os.path.join(tmp, 'windows.jsonl'), 'w') as f:
                f.write(windows.to_jsonl())
            cmd = [sys.executable, '-m', 'thermal_imu_calib.cli', 'report',
                   os.path.join(tmp, 'cal.yaml'), '--windows', os.path.join(tmp, 'windows.jsonl'),
                   '--html', out]
            try:
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                                   preexec_fn=lambda: os.nice(10))
            except (OSError, subprocess.SubprocessError) as e:
                self.get_logger().error(f'report {out} not written: {e!r}')
                return
        if r.returncode:
            self.get_logger().error(f'report {out} not written: {r.stderr.strip()[-500:]}')
        else:
            self.get_logger().info(f'wrote report {out}')

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
        with self._lock:
            n, h, t = len(self.windows), len(self.windows.hold_ids), len(self.transitions)
            self._new_collection()
            self.counts.update({k: 0 for k in self.counts})
            path = self._collection_path()
            if path and os.path.exists(path):
                os.unlink(path)
            tdir = self._transitions_dir()
            if tdir and os.path.isdir(tdir):
                shutil.rmtree(tdir)
            self._write_inputs_signature()
        response.success = True
        response.message = f'cleared {n} windows ({h} holds) and {t} pose changes' + (
            f'; removed {path} and {tdir}/' if path else '')
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
        ready = readiness(windows, model=self.get_parameter('model').value)
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
        level = common.OK
        msg = ('ready: ' if prog['ready'] else 'collecting: ') + prog['reason']
        if prog['next_pose']:
            msg += f'; next pose {prog["next_pose"]} up'
        if rate == 0.0:
            level, msg = common.WARN, 'no IMU input; ' + msg
        elif self.k and self.counts['stale_temperature'] and self.counts['samples'] == 0:
            level, msg = common.WARN, 'no fresh temperature; ' + msg
        self.diagnostics.publish([common.diagnostic_status(
            f'{self.get_name()}: thermal calibration', self.get_fully_qualified_name(), level,
            msg, values)] + (self.lifelong.statuses() if self.lifelong is not None else []))

    def destroy_node(self):
        """Stop the estimation worker, then destroy the node."""
        self._worker.shutdown(wait=False, cancel_futures=True)
        if self.lifelong is not None:
            self.lifelong.shutdown()
        return super().destroy_node()


def _good_records(data, k):
    """Return (text of the readable records, records skipped, records seen) of a collection.

    A record (one line) is skipped when it is not UTF-8, not JSON or lacks a field the
    windows table needs; the others are kept (one bad line no longer loses the collection).
    """
    good, skipped, total = [], 0, 0
    for line in data.splitlines():
        if not line.strip():
            continue
        total += 1
        try:
            text = line.decode('utf-8')
            win = Windows.from_jsonl(text, k)
            if len(win) != 1 or win.n_inputs != k:
                raise ValueError('not one record of this node\'s inputs')
        except Exception:  # noqa: B902 - any bad record is skipped and counted
            skipped += 1
            continue
        good.append(text)
    return '\n'.join(good) + ('\n' if good else ''), skipped, total


def _usable(chunk, k, timeout):
    """Rows of an AlignedChunk with finite IMU data and every temperature fresher than timeout."""
    imu = chunk.imu
    use = np.isfinite(imu.accel).all(1) & np.isfinite(imu.gyro).all(1)
    if k:
        use &= (chunk.temp_age <= timeout).all(1)
    return use


def _model_choices():
    """Return the estimator names the core accepts (older cores: a constant tuple)."""
    if hasattr(estimation, 'model_choices'):
        return tuple(estimation.model_choices())
    return tuple(getattr(estimation, 'MODEL_CHOICES', ('auto', 'field', 'offset')))


def _check_gravity(value):
    if value == 0.0:
        return None
    try:
        resolve_gravity(value)
    except ValueError as e:
        return str(e)
    return None


def _atomic_copy(src, dst):
    """Copy file ``src`` to ``dst`` through the output writer (temporary + rename)."""
    with open(src, 'rb') as f:
        write_atomic(dst, lambda out: shutil.copyfileobj(f, out))


def main(args=None):
    """Run the calibrator node (estimation runs on a worker thread, data keeps flowing)."""
    process.exit_process(process.run_nodes([CalibratorNode], args))


if __name__ == '__main__':
    main()
