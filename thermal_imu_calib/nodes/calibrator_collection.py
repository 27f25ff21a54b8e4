"""The calibrator node's live collection: holds and pose changes kept, persisted, resumed.

``LiveCollection`` is mixed into ``nodes.calibrator.CalibratorNode``: the IMU and
temperature callbacks queue messages, ``_process`` aligns them to IMU header stamps
(``io.align.StreamAligner``) and runs the stationary detector online
(``collection.motion.MotionCollector``); each closed hold's window statistics are appended
to ``collection_file`` (JSON lines) and each pose change between holds is written as one
``.npz`` into ``<collection_file>.transitions/``, so a restarted node resumes where it
stopped (``_resume``). ``snapshot`` / ``snapshot_collected`` give the calibrate use case a
``collection.collected.Collected``, as a log gives one, without closing anything in the
live collection. Times: IMU header stamps (ns in messages, s in the windows).
"""

import copy
import io
import itertools
import json
import os
import time

import numpy as np

from . import common
from ..collection.collected import Collected
from ..collection.motion import load_transitions, MotionCollector, offset_holds, save_transitions
from ..collection.feed import fresh_part
from ..collection.segments import readable_records, Windows
from ..collection.stationary import DetectorConfig, DetectorSettingsError
from ..io.align import StreamAligner
from ..io.columns import ImuColumns, TemperatureColumns
from ..io.gate import LiveImuFilter, temperature_checks
from ..io.output import free_name, OutputError, write_atomic


class LiveCollection:
    """Collection state of the calibrator node (a mixin: it uses the node's logger)."""

    # ------------------------------------------------------------------ collection state
    def _new_collection(self):
        self.detector = self._collector()
        self.aligner = StreamAligner(self.k, self.temperature_timeout)
        self.windows = Windows.empty(self.k)
        self.transitions = []            # replaced, never mutated: snapshots stay consistent
        self.transitions_dropped = {'too_long': 0, 'incomplete': 0, 'over_limit': 0}
        self._hold_offset = 0
        self._newest_ns = None
        self._rows = LiveImuFilter(common.JUMP_S)   # drops what calibrate drops (io.gate)
        self._pending_imu = []
        self._pending_source = []     # the IMU messages' DDS source timestamps (header-less)
        self._pending_temp = [[] for _ in range(self.k)]
        self._resumed_until = None    # newest resumed hold end (s) until new data judge it
        self.resumed_holds = 0        # holds in the collection that came from the file

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
        text, skipped, total = readable_records(data, self.k)
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
            aside = self._move_aside('incompatible')
            self._write_inputs_signature()
            self.get_logger().error(f'collection file {path} not resumed: {why}; moved to '
                                    f'{aside}, starting a new collection')
            return
        self.windows = win
        self._resumed_until = float(win.t1.max()) if len(win) else None
        self.resumed_holds = len(win.hold_ids)
        self._hold_offset = int(win.hold.max()) + 1 if len(win) else 0
        # rewrite only the complete records, so appends never follow a torn last line
        write_atomic(path, win.to_jsonl())
        self._write_inputs_signature()
        self.get_logger().info(f'resumed {len(win)} windows ({len(win.hold_ids)} holds) from '
                               f'{path}')

    def _move_aside(self, tag):
        """Rename the collection file (and its pose changes and inputs) to ``PATH.TAG-TIME[-N]``.

        Returns the new name ('' when there is no file, or it could not be moved: then the
        collection continues in memory only, ``_degrade``).
        """
        path = self._collection_path()
        if not path or not os.path.exists(path):
            return ''
        aside = free_name(f'{path}.{tag}-{int(time.time())}', ('.transitions', '.inputs.json'))
        try:
            os.replace(path, aside)
            tdir = self._transitions_dir()
            if os.path.isdir(tdir):
                os.replace(tdir, aside + '.transitions')
            if os.path.exists(path + '.inputs.json'):
                os.replace(path + '.inputs.json', aside + '.inputs.json')
        except OSError as e:
            self._degrade(e)
            return ''
        return aside

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
        unit = self.temperature_units[index]

        bare = self._clocks.bare[index]          # the type has no header

        def add(m, info):
            v = getattr(m, value)
            finite, out = temperature_checks([v], unit)   # what calibrate drops
            if not finite[0] or out[0]:
                self.counts['temperature_invalid'] += 1
                return
            self.counts['temperature_readings'] += 1
            self.readings_per_topic[index] += 1
            # (header stamp, DDS source timestamp, value): the source timestamp orders a
            # reading put on the IMU's clock (header-less, or ``StampChoice``)
            with self._lock:
                self._pending_temp[index].append(
                    (0 if bare else common.stamp_to_ns(m.header.stamp),
                     info['source_timestamp'], v))

        def cb(msg, info):
            # drained too, so temperature keeps pace with batched IMU data under load
            for m, i in [(msg, info)] + common.drain(self.temp_subs[index], 100, self,
                                                     with_info=True):
                add(m, i)
        return cb

    def _on_imu(self, msg, info):
        taken = [(msg, info)] + common.drain(self.imu_sub, 999, self, with_info=True)
        msgs = [m for m, _ in taken]
        if not self._seen_frame:
            self._seen_frame = msg.header.frame_id
        stamps, accel, gyro = common.imu_to_arrays(msgs)
        self._rate.add(len(msgs))
        with self._lock:
            self._pending_imu.append((stamps, accel, gyro))
            if self._clocks.on:     # the publish order, for readings on the IMU's clock
                self._pending_source.append([i['source_timestamp'] for _, i in taken])

    def _process(self):
        with self._lock:
            pending, self._pending_imu = self._pending_imu, []
            temps, self._pending_temp = self._pending_temp, [[] for _ in range(self.k)]
            if not pending and not any(temps):
                return
            imu = ImuColumns(*(np.concatenate(c) for c in zip(*pending))) if pending \
                else ImuColumns.empty()
            tcols = self._on_clocks(imu.stamp_ns, temps)
            imu = self._filtered(imu)       # an invalid row's stamp counts for nothing
            if len(imu) and self._resumed_until is not None:
                self._check_session(int(imu.stamp_ns[0]))
            if len(imu):
                self._check_time(int(imu.stamp_ns.min()))
                self._count_gaps(imu.stamp_ns)
                self._newest_ns = max(self._newest_ns or 0, int(imu.stamp_ns.max()))
            for chunk in self.aligner.push_columns(imu, tcols):
                self._collect(chunk)

    def _on_clocks(self, imu_stamps, temps):
        """Return the readings taken since the last call as TemperatureColumns per input.

        ``imu_stamps``: the IMU messages taken meanwhile (before the input gate, as
        offline); ``temps`` entries: (header stamp, source timestamp, value). Each input's
        clock is chosen and applied as offline (``io.headerless.LiveClocks``): header
        stamps, or the stamp of the IMU message published before each reading (header-less,
        or stamped 0 or by another clock: logged once; held until that is decided).
        """
        clocks = self._clocks
        sources, self._pending_source = self._pending_source, []
        clocks.add_imu([s for part in sources for s in part], imu_stamps)
        out = []
        for j, t in enumerate(temps):
            if clocks.undecided(j):
                t, note = clocks.choose(j, t, lambda r: r[0])
                if note:
                    self.get_logger().warning(note)
            out.append(clocks.stamp(j, [(s, v) for _, s, v in t]) if clocks.bare[j] else
                       TemperatureColumns(np.array([h for h, _, _ in t], np.int64),
                                          np.array([v for _, _, v in t], float)))
        if any(clocks.bare):
            self.counts['temperature_before_imu'] = clocks.clock.left_out   # not used
        return out

    def _check_session(self, stamp_ns):
        """Keep a resumed collection only when the first data after the restart continue it.

        A restart mid-session (a crash, a kill) continues within ``resume_max_gap`` of the
        newest resumed hold. Data stamped before it (the same recording played again) or
        long after it (another recording, another day) are a new session: the resumed
        collection would otherwise be merged into it (a bench once calibrated 76 holds of
        two runs against the 38 of one). It is moved aside, not deleted; lifelong mode
        keeps its own store and is not judged here.
        """
        until, self._resumed_until = self._resumed_until, None
        s = stamp_ns * 1e-9
        if self.lifelong is not None or until - common.JUMP_S <= s <= until + self.resume_max_gap:
            return
        when = 'before' if s < until else f'{(s - until) / 3600:.1f} h after'
        holds = len(self.windows.hold_ids)
        aside = self._move_aside('previous')
        self.windows = Windows.empty(self.k)
        self.transitions = []
        self._hold_offset = 0
        self.resumed_holds = 0
        self._write_inputs_signature()
        self.get_logger().warning(
            f'the first data after the restart are stamped {when} the end of the '
            f'{holds} holds resumed: a new session, started afresh'
            + (f'; the resumed collection was moved to {aside}' if aside else '')
            + ' (to continue a collection across a longer gap, raise resume_max_gap)')

    def _count_gaps(self, stamps):
        """Count steps forward by more than ``resume_max_gap`` (another recording played?).

        Kept, as a jump back is (a robot's stream may pause); ``~/calibrate`` says so.
        """
        before = [] if self._newest_ns is None else [self._newest_ns]
        steps = np.diff(np.concatenate([before, stamps]).astype(np.int64))
        n = int((steps > self.resume_max_gap * 1e9).sum())
        if n:
            self.counts['time_gaps'] = self.counts.get('time_gaps', 0) + n

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

    def _filtered(self, imu):
        """Drop the IMU rows ``calibrate`` drops (``io.gate.LiveImuFilter``); count them.

        Invalid values (non-finite, beyond any sensor's range, an all-zero accelerometer)
        count as ``invalid``; stamps that do not increase (duplicated, a step back) as
        ``stamp_not_increasing``. A jump back beyond ``common.JUMP_S`` is a new timeline,
        kept (the filter judges its stamps from there on; ``_check_time`` then restarts
        detection for it).
        """
        f = self._rows
        bad, back = f.invalid, f.not_increasing
        kept = f.push(imu)
        self.counts['invalid'] += f.invalid - bad
        if f.not_increasing > back:
            self.counts['stamp_not_increasing'] = (self.counts.get('stamp_not_increasing', 0)
                                                   + f.not_increasing - back)
        return kept

    def _collect(self, chunk):
        """Detect on the rows with a fresh temperature (``fresh_part``, as ``calibrate``).

        The IMU rows are valid: ``_filtered`` dropped the others before the aligner, as
        ``calibrate``'s gate does.
        """
        imu, temps, left_out = fresh_part(chunk, self.temperature_timeout)
        self.counts['stale_temperature'] += left_out
        self.counts['samples'] += len(imu)
        if not len(imu):
            return
        try:
            win = self.detector.update(imu.t, imu.accel, imu.gyro, temps)
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

    # ------------------------------------------------------------------ snapshots
    def snapshot(self):
        """Return a consistent copy of the collection for one estimate (taken under the lock).

        What arrived since the last timer tick is taken in first. The windows and pose
        changes are never mutated in place, so they are shared; the detector and aligner
        are copied (``snapshot_collected`` finishes the copies).
        """
        self._process()
        with self._lock:
            tail = None     # header-less readings after the newest IMU message (as offline)
            if any(self._clocks.bare):
                clock = copy.deepcopy(self._clocks.clock)
                tail = [clock.take(j, everything=True) if bare else TemperatureColumns.empty()
                        for j, bare in enumerate(self._clocks.bare)]
            return (self.windows, self.transitions, copy.deepcopy(self.detector),
                    copy.deepcopy(self.aligner), self._hold_offset, tail)

    def snapshot_collected(self, windows, transitions, detector, aligner, offset, tail=None):
        """Return the Collected of a ``snapshot``, its open hold closed in the copies.

        Finishing the copied ``detector`` and ``aligner`` adds the samples still waiting for
        a newer temperature reading and the hold in progress (if long enough), and the pose
        change into it, without closing anything in the live collection. ``tail``: the
        header-less readings still waiting for an IMU message, stamped with the newest.
        """
        parts = []
        pushed = aligner.push_columns(ImuColumns.empty(), tail) if tail else []
        for chunk in itertools.chain(pushed, aligner.finish()):
            imu, temps, _ = fresh_part(chunk, self.temperature_timeout)
            if len(imu):
                parts.append(detector.update(imu.t, imu.accel, imu.gyro, temps))
        parts.append(detector.finish())
        tail = Windows.concat(parts)
        if len(tail):
            tail.hold = tail.hold + offset
            windows = Windows.concat([windows, tail])
        room = max(self.max_transitions - len(transitions), 0)
        transitions = list(transitions) + offset_holds(detector.pop_transitions(),
                                                       offset)[:room]
        return self._collected(windows, transitions, detector.det.settings())

    def _collected(self, windows, transitions, detector):
        """Return the live collection as the Collected a log gives (``app.collect``)."""
        return Collected(windows, self._seen_frame, self._rate.total, 0.0,
                         list(self.temperature_topics), list(transitions), detector=detector,
                         input_notes=self.input_notes())
