"""The calibrator node's live collection: holds and pose changes kept, persisted, resumed.

``LiveCollection`` is mixed into ``nodes.calibrator.CalibratorNode``: the IMU and
temperature callbacks queue messages, ``_process`` aligns them to IMU header stamps
(``io.align.StreamAligner``) and runs the stationary detector online
(``collection.motion.MotionCollector``); each closed hold and pose change is kept on disk
(``nodes.calibrator_store.CollectionStore``), so a restarted node resumes where it
stopped (``_resume``). ``_restart_with`` starts a collection with other thermal inputs
while the IMU stream goes on (``absent_inputs``, ``late_inputs``). ``snapshot`` /
``snapshot_collected`` give the calibrate use case a ``collection.collected.Collected``, as
a log gives one, without closing anything in the live collection. Times: IMU header
stamps (ns in messages, s in the windows).
"""

import copy
import itertools

import numpy as np

from . import common
from .calibrator_store import CollectionStore
from ..collection.collected import Collected
from ..collection.motion import MotionCollector, offset_holds
from ..collection.feed import fresh_part
from ..collection.segments import Windows
from ..collection.stationary import DetectorConfig, DetectorSettingsError
from ..io.align import StreamAligner
from ..io.columns import ImuColumns, TemperatureColumns
from ..io.gate import LiveImuFilter, temperature_checks


class LiveCollection(CollectionStore):
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

    def _restart_with(self, topics, units, inputs, subs, clocks, aligner=None):
        """Start a new collection with these thermal inputs; the IMU stream goes on.

        The IMU messages waiting, the input gate's state and the newest stamp are kept;
        ``aligner``: one that already holds the IMU rows of these inputs (else a new one).
        Called under ``_lock``; the caller persists the new inputs signature.
        """
        keep = (self._pending_imu, self._pending_source, self._rows, self._newest_ns)
        self.temperature_topics, self.temperature_units, self.inputs = topics, units, inputs
        self.k, self.temp_subs, self._clocks = len(topics), subs, clocks
        self._new_collection()
        self._pending_imu, self._pending_source, self._rows, self._newest_ns = keep
        self.aligner = aligner or self.aligner
        self.readings_per_topic = [0] * self.k

    def _collector(self):
        """Return a new stationary detector that also keeps the pose changes between holds."""
        return MotionCollector(DetectorConfig(**vars(self.detector_config)), self.k,
                               max_transition_s=self.max_transition_s)

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
        if self._absent_topics:         # the watched inputs' aligner: a new timeline too
            self._late_inputs.shadow(self)
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
