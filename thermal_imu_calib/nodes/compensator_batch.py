"""The compensator node's data path: thermal readings in, IMU batches compensated, published.

``LiveCompensation`` is mixed into ``nodes.compensator.CompensatorNode``. Each thermal
input's readings go into the node's ``common.TemperatureInputs``: header-stamped, or on
the IMU's clock when header-less (``io.headerless.LiveClocks``, the clock chosen at the
first readings as offline). The IMU callback takes a batch of queued messages (at most
``max_batch``), first the readings stamped within it (``_take_queued_temperatures``), and
compensates it with one model: the active calibration, or in registry mode each unit's
(header frame_id, ``units.RegistryUnits``), despiked first with ``despike``
(``collection.outliers.ImuSpikeFilter``, one per unit). ``process`` resolves each
sample's inputs at its header stamp, applies ``on_missing_temperature`` to stale or
absent ones, runs the model's ``CalibrationStream`` (its thermal history saved by
``compensator_state``), writes the 1-sigma into the covariances (``fill_covariance``) and
publishes in arrival order; NaN/Inf is never published and every sample is counted. Our
own messages coming back are dropped (``units.SentMessages``). Times: IMU header stamps
(ns in messages, s in the calibration).
"""

import numpy as np

from . import common, input_hints
from ..collection.outliers import ImuSpikeFilter
from ..io.columns import AlignedChunk, ImuColumns

#: IMU messages not compensated for want of any temperature reading before the log says why
SILENT_WARN_AFTER = 1000


class LiveCompensation:
    """Data path of the compensator node (a mixin: see the module).

    It uses the node's subscriptions, parameters, ``counts``, models and ``_warn_once``.
    """

    def _temperature_cb(self, index, value='temperature'):
        def cb(msg, info):
            # drained too, so temperature keeps pace with batched IMU data under load
            taken = [(msg, info)] + common.drain(self.temp_subs[index], 100, self,
                                                 with_info=True)
            if self._clocks.bare[index]:
                self._add_headerless(index, value, taken)
            elif self._clocks.undecided(index):
                self._choose_clock(index, taken)     # no ``until``: nothing is left over
            else:
                self._add_temperatures(index, value, [m for m, _ in taken])
        return cb

    def _choose_clock(self, index, taken, until=None):
        """Hold (message, info) readings of an input whose clock is not chosen yet.

        Once its first reading after the first IMU message is judged
        (``io.headerless.StampChoice``, as offline) the held readings go on: on the IMU's
        clock, or by their header stamps, those stamped at or before ``until`` (ns) added
        now. Returns the messages to add after the batch (see
        ``_take_queued_temperatures``).
        """
        self.temps.received[index] += len(taken)    # received while held, counted once
        arrived = self._clocks.choices[index].waiting   # taken before this batch
        held, note = self._clocks.choose(index, taken,
                                         lambda t: common.stamp_to_ns(t[0].header.stamp))
        if self._clocks.undecided(index):
            return []
        self.temps.received[index] -= len(held)     # counted again as they are added
        if self._clocks.bare[index]:
            self.get_logger().warning(note)
            self._add_headerless(index, self._temp_fields[index], held)
            return []
        return self._add_until(index, [m for m, _ in held], until, arrived)

    def _add_temperatures(self, index, value, msgs):
        for m in msgs:
            self.temps.add(index, common.stamp_to_ns(m.header.stamp), getattr(m, value))

    def _add_until(self, index, msgs, until, start=0):
        """Add header-stamped readings up to the first after ``until`` (ns); return the rest.

        Only ``msgs[start:]`` are compared (the ones before arrived in their own callbacks
        and are all added); ``until`` None adds all.
        """
        cut = len(msgs) if until is None else next(
            (j for j, m in enumerate(msgs[start:], start)
             if common.stamp_to_ns(m.header.stamp) > until), len(msgs))
        self._add_temperatures(index, self._temp_fields[index], msgs[:cut])
        return msgs[cut:]

    def _add_headerless(self, index, value, taken):
        """Add (message, info) readings without a header, on the IMU's clock.

        Each takes the header stamp of the IMU message published before it (DDS source
        timestamps, ``io.headerless.LiveImuClock``); one published after every IMU message
        received so far waits for the next.
        """
        got = self._clocks.stamp(index, [(info['source_timestamp'], getattr(m, value))
                                         for m, info in taken])
        for stamp, v in zip(got.stamp_ns.tolist(), got.temperature.tolist()):
            self.temps.add(index, stamp, v)
        self.counts['temperature_before_imu'] = self._clocks.clock.left_out   # not used

    def _take_queued_temperatures(self, msgs):
        """Take readings still queued that are stamped within the IMU batch ``msgs``.

        The executor runs the IMU callback before the temperature callbacks of the same
        wake-up; under load, readings stamped within the batch would otherwise still wait in
        their queue and the batch would be compensated with an older, held reading.
        Readings stamped after the batch's newest IMU stamp are returned, to be added after
        the batch as if taken in arrival order: what a sample uses never depends on
        readings newer than the samples around it.
        """
        until = max(common.stamp_to_ns(m.header.stamp) for m in msgs)
        later = []
        for i, sub in enumerate(self.temp_subs):
            if self._clocks.bare[i]:     # stamped by the IMU messages published before them
                self._add_headerless(i, self._temp_fields[i],
                                     common.drain(sub, 1000, self, with_info=True))
                later.append([])
                continue
            if self._clocks.undecided(i):      # its clock not chosen yet
                later.append(self._choose_clock(
                    i, common.drain(sub, 1000, self, with_info=True), until))
                continue
            later.append(self._add_until(i, common.drain(sub, 1000, self), until))
        return later

    def _on_lost(self, info):
        # DDS-reported losses on imu/data_raw (sequence gaps the reader saw): diagnostics
        self.counts['input_lost'] += info.total_count_change

    def _on_imu(self, msg, info):
        taken = [(msg, info)] + common.drain(self.imu_sub, self.batch_limit - 1, self,
                                             with_info=True)
        msgs = [m for m, _ in taken]
        if self._clocks.on:     # the publish order, for readings on the IMU's clock
            self._clocks.add_imu([i['source_timestamp'] for _, i in taken],
                                 [common.stamp_to_ns(m.header.stamp) for m in msgs])
        later = self._take_queued_temperatures(msgs)
        try:
            if not self.registry_dir:
                self._compensate(msgs, self._active)
            else:
                units = {}
                for m in msgs:     # one model per unit: a batch may hold several units
                    units.setdefault(m.header.frame_id, []).append(m)
                for frame, group in units.items():
                    model = self.units.model(frame)
                    if model is None:
                        self.counts['uncalibrated_unit'] += len(group)
                    else:
                        self._active = model
                    self._compensate(group, model, frame)
        finally:
            for i, taken in enumerate(later):
                self._add_temperatures(i, self._temp_fields[i], taken)

    def _compensate(self, msgs, active, unit=None):
        msgs = self._drop_own(msgs)
        if not msgs:
            return
        gate = (self._unit_gates.setdefault(unit, ImuSpikeFilter())   # one per unit
                if self._gate is not None and self.registry_dir else self._gate)
        if gate is None:
            self.process(msgs, active=active)
            return
        stamps, accel, gyro = common.imu_to_arrays(msgs)
        obj = np.empty(len(msgs), object)
        obj[:] = msgs
        out = gate.push(AlignedChunk(ImuColumns(stamps, accel, gyro), np.zeros((
            len(msgs), 0)), np.zeros((len(msgs), 0)), {'msg': obj}))
        if len(out):
            self.process(list(out.extra['msg']), (out.imu.stamp_ns, out.imu.accel,
                                                  out.imu.gyro), active=active)

    def _drop_own(self, msgs):
        keep, own = self._sent.drop_own(msgs)    # the loop guard: never compensated twice
        if own:
            self.counts['own_messages_dropped'] += own
            self._warn_once('own', 'received messages this node published (output routed '
                                   'back to its input): dropped (own_messages_dropped)')
        return keep

    def process(self, msgs, arrays=None, active=False):
        """Compensate and publish a batch of Imu messages (in arrival order).

        ``arrays`` = (stamps, accel, gyro) replaces the messages' own values (despiked);
        ``active`` is the model to use (default: the active calibration).
        """
        if active is False:
            active = self._active  # read once: the whole batch uses one model
        try:
            self._process(msgs, arrays, active)
        finally:    # counted once handled, so a reader of the counts sees the whole batch
            self.counts['received'] += len(msgs)

    def _process(self, msgs, arrays, active):
        c = self.counts
        n = len(msgs)
        self._rate.add(n)
        stamps, accel, gyro = arrays if arrays is not None else common.imu_to_arrays(msgs)
        self._last_stamp_ns = int(stamps[-1])
        send = np.isfinite(accel).all(1) & np.isfinite(gyro).all(1)  # rows to publish
        c['invalid'] += n - int(send.sum())
        self._check_units(accel, gyro)
        if active is None:
            if self.passthrough_uncalibrated:
                c['passthrough'] += self._publish(msgs, send)
            else:
                c['dropped'] += int(send.sum())
            return
        cal = active.calibration
        if cal.frame_id and msgs[0].header.frame_id != cal.frame_id:
            c['frame_mismatch'] += n
            self._warn_once('frame', f'IMU frame_id {msgs[0].header.frame_id!r} differs from '
                                     f'the calibration frame {cal.frame_id!r}; compensating '
                                     'anyway')
        comp = send.copy()  # rows to compensate; the other sent rows pass through
        temps = np.zeros((n, len(active.columns)))
        if active.columns:
            if self.temps.check_time(int(stamps.min())):
                active.stream.reset()
                self._warn_once('jump', 'IMU header stamps jumped back by more than '
                                f'{common.JUMP_S:.0f} s: temperature history cleared')
            temps, age = self.temps.resolve(stamps, active.columns, self.temperature_timeout)
            known = np.isfinite(temps).all(1)
            stale = send & (~known | (age > self.temperature_timeout).any(1))
            if stale.any():
                if self.on_missing == 'hold_last':
                    c['temperature_held'] += int((stale & known).sum())
                    c['temperature_missing'] += int((stale & ~known).sum())
                    comp &= known
                else:
                    c['temperature_missing'] += int(stale.sum())
                    comp &= ~stale
                    if self.on_missing == 'drop':
                        send &= ~stale
                        c['dropped'] += int(stale.sum())
                if 'silent' not in self._warned and \
                        c['temperature_missing'] >= SILENT_WARN_AFTER:
                    self._warn_silent_temperature(active.columns)
        rows = np.flatnonzero(comp)
        if len(rows):
            self.state.before(active, stamps[rows[0]] * 1e-9)
            res = active.stream.apply(stamps[rows] * 1e-9, accel[rows], gyro[rows], temps[rows])
            self.state.after(active)
            good = np.isfinite(res.accel).all(1) & np.isfinite(res.gyro).all(1)
            if not good.all():  # never publish NaN/Inf
                c['invalid'] += int((~good).sum())
                send[rows[~good]] = False
            sel = rows[good]
            va = None if res.accel_std is None else res.accel_std[good] ** 2
            vg = None if res.gyro_std is None else res.gyro_std[good] ** 2
            va = va if va is not None and np.isfinite(va).all() else None
            vg = vg if vg is not None and np.isfinite(vg).all() else None
            if not self.fill_covariance:
                va = vg = None
            common.write_imu([msgs[i] for i in sel], res.accel[good], res.gyro[good], va, vg)
            c['clamped'] += int(res.out_of_range[good].sum())
            c['compensated'] += len(sel)
            comp[:] = False
            comp[sel] = True
        c['passthrough'] += int((send & ~comp).sum())
        self._publish(msgs, send)

    def _check_units(self, accel, gyro):
        """Watch the input for values not in m/s^2 and rad/s; warn once per sensor."""
        self._units_seen.push(accel, gyro)
        for sensor, (seen, rule, fix) in self._units_seen.problems().items():
            self._warn_once(f'unit_{sensor}', f'{seen}, {rule}: {fix}. Every output sample is '
                            'wrong until the driver publishes SI units: compensating anyway')

    def _publish(self, msgs, send):
        count = 0
        for m, s in zip(msgs, send.tolist()):
            if s:
                self.pub.publish(m)
                self._sent.add(m)
                count += 1
        self.counts['published'] += count
        return count

    def _warn_silent_temperature(self, columns):
        """Say once which needed thermal input never had a reading, and what is on the graph."""
        silent = [self.temp_subs[i] for i in columns if not self.temps.received[i]]
        if not silent:
            return
        c = self.counts
        self._warn_once('silent', 'no temperature reading has arrived on '
                        + ', '.join(f'{s.topic_name} ({s.get_publisher_count()} publishers)'
                                    for s in silent)
                        + f' while {c["received"]} IMU messages did: they are '
                        + ('dropped' if self.on_missing == 'drop' else 'published uncompensated')
                        + f' (on_missing_temperature {self.on_missing})'
                        + input_hints.wrong_type_hint(self, silent)
                        + input_hints.thermal_topics_hint(self, self.temp_subs))
