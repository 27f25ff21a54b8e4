"""Live thermal compensation: imu/data_raw + temperature -> imu/data_compensated.

Subscribes ``imu/data_raw`` (sensor_msgs/Imu) and every topic of ``temperature_topics``
(sensor_msgs/Temperature, or another stamped scalar per ``temperature_types``; each in its
``temperature_units`` entry: degC or a thermal proxy's unit such as Hz), resolves each
calibration input's value at the IMU header stamp (interpolated between readings, else
the nearest reading held) and publishes the ``Calibration.apply`` result on
``imu/data_compensated`` with the same header and orientation. The calibration comes
from ``calibration_file`` (at start and on ``~/reload``) or from the latched
``imu/calibration`` topic; a bad one is rejected with its reason and the previous one stays
active, also when its input units differ from ``temperature_units``.

With ``registry_dir`` every IMU unit (header frame_id) has its own model, looked up once
(``units.RegistryUnits``); a unit without one passes through (or is dropped, per
``passthrough_without_calibration``), counted in /diagnostics; a batch is compensated
per unit (order kept within each unit). Loop guard (``units``): an output topic that is
an input is refused at start, and this node's own messages coming back are dropped.
With ``state_file`` the thermal-history state outlives a restart (``compensator_state``).

Cohesive: one node's calibration hand-over, per-batch compensation and diagnostics around
one shared active model; the parameters are in ``compensator_params``, the maths in
``calibration`` and ``thermal_input``, the registry units in ``units``, the saved state in
``compensator_state``.
"""

from dataclasses import dataclass
import math
import os
import time

import numpy as np
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger

from . import (common, compensator_params as params, input_hints, process, thermal_types,
               topic_follower, units)
from .compensator_state import StreamStateFile
from ..calibration import Calibration, CalibrationError
from ..collection.outliers import ImuSpikeFilter
from ..gravity import STANDARD_GRAVITY
from ..io.columns import AlignedChunk, ImuColumns
from ..io.headerless import LiveClocks
from ..io.imu_units import UnitWatch
from ..thermal_input import CalibrationStream

NODE_NAME = 'thermal_imu_compensator'
#: IMU messages not compensated for want of any temperature reading before the log says why
SILENT_WARN_AFTER = 1000


@dataclass(frozen=True)
class ActiveModel:
    """The calibration in use and how its inputs map to subscribed topics (never mutated)."""

    calibration: Calibration
    columns: tuple
    id: str
    source: str
    loaded_at: float
    #: carries the thermal-input filter state (lagged temperature) of this model only
    stream: CalibrationStream = None


class CompensatorNode(Node):
    """Apply a thermal calibration to a live IMU stream."""

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        start = params.declare(self)
        self._unit_gates = {}             # registry mode: per unit despike state
        self._sent = units.SentMessages()
        self._gate = ImuSpikeFilter() if self.despike else None
        self.temps = common.TemperatureInputs(self.temperature_topics,
                                              max(60.0, 4 * self.temperature_timeout))
        self._active = None
        self.counts = {'received': 0, 'published': 0, 'compensated': 0, 'passthrough': 0,
                       'dropped': 0, 'invalid': 0, 'clamped': 0, 'temperature_held': 0,
                       'temperature_missing': 0, 'frame_mismatch': 0,
                       'calibrations_rejected': 0, 'calibrations_loaded': 0,
                       'input_lost': 0, 'uncalibrated_unit': 0, 'own_messages_dropped': 0}
        self.last_rejection = ''
        self.units = (units.RegistryUnits(self.registry_dir, self._model, self.counts,
                                          self.get_logger()) if self.registry_dir else None)
        if start.state_file and self.registry_dir:
            self.get_logger().warning('state_file is not used with registry_dir (one state '
                                      'per unit is not kept)')
        self.state = StreamStateFile('' if self.registry_dir else start.state_file,
                                     start.state_save_period, start.state_max_gap,
                                     self.get_logger(), self.get_fully_qualified_name())
        self._last_stamp_ns = None
        self._units_seen = UnitWatch(STANDARD_GRAVITY)   # g, milli-g, counts, deg/s in
        self._rate = common.RateMeter()
        self._warned = set()
        self._started = time.monotonic()
        self._finished = False     # finish() has written the state on the way out

        self.pub = self.create_publisher(Imu, 'imu/data_compensated',
                                         common.output_qos(start.output_reliability,
                                                           start.output_depth))
        self.imu_sub = self.create_subscription(
            Imu, 'imu/data_raw', self._on_imu, common.sensor_qos(start.input_depth),
            event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_lost))

        self._temp_fields = [value for _, value in start.scalar_types]
        #: per input: its header stamps, or the IMU's clock (header-less, or stamps 0 or
        #: on another clock), as offline
        self._clocks = LiveClocks(self.temperature_topics,
                                  [common.headerless(cls) for cls, _ in start.scalar_types])
        self.temp_subs = [
            self.create_subscription(cls, topic, self._temperature_cb(i, value),
                                     common.sensor_qos(start.input_depth))
            for i, (topic, (cls, value)) in enumerate(zip(self.temperature_topics,
                                                          start.scalar_types))]
        units.refuse_loop(self.pub.topic_name, [s.topic_name for s in [self.imu_sub]
                                                + self.temp_subs])
        self._in_depth = start.input_depth
        #: a silent input whose topic is published as another thermal type is
        #: re-subscribed as that type (``thermal_types``), as calibrate reads a log
        self.type_follower = thermal_types.TypeFollower(self, self.temp_subs, self._subscribe_as)
        #: a calibration whose one input was followed under another name is served from
        #: that topic when nothing is on the default one (``topic_follower``)
        self.adopter = topic_follower.InputAdopter(self)
        common.steady_timer(self, thermal_types.FOLLOW_PERIOD_S, self._follow)
        self.cal_sub = self.create_subscription(String, 'imu/calibration', self._on_calibration,
                                                common.CALIBRATION_QOS)
        self.reload_srv = self.create_service(Trigger, '~/reload', self._on_reload)
        self.diagnostics = common.Diagnostics(self)
        self.diag_timer = common.steady_timer(self, start.diagnostics_period,
                                              self._publish_diagnostics)
        if self.calibration_file and not self.registry_dir:
            ok, msg = self.load_file()
            common.log(self, ok, msg, failure='warning')
        if self._active is None:
            self.get_logger().warning(
                'no calibration loaded: ' + ('passing IMU data through uncompensated'
                                             if self.passthrough_uncalibrated
                                             else 'publishing nothing') + ' until one arrives')

    # ------------------------------------------------------------------ calibration
    @property
    def active(self):
        """Return the ActiveModel in use, or None."""
        return self._active

    def activate(self, cal, source):
        """Make ``cal`` the active calibration if this node can serve its inputs.

        Returns (ok, message). On failure the previous calibration stays active.
        """
        model, reason = self._model(cal, source)
        if reason:
            return self._reject(source, reason)
        # one reference swap: a message is compensated entirely with the old or the new model
        self._active = model
        self.adopter.waiting = None
        self.state.activated(model)
        self.counts['calibrations_loaded'] += 1
        return True, units.active_text(model)

    def _model(self, cal, source):
        """Return (ActiveModel, None) if this node can serve ``cal``'s inputs, else (None, why)."""
        columns, reason = common.match_topics(self, cal.temperature_topics,
                                              self.temperature_topics)
        if reason and self.adopter.applies(cal):     # a followed input's
            if self.adopter.adopt(cal.temperature_topics[0]):      # (topic_follower)
                columns, reason = common.match_topics(self, cal.temperature_topics,
                                                      self.temperature_topics)
            else:
                self.adopter.waiting = (cal, source)
                reason += (f'; it is activated once {cal.temperature_topics[0]} is published '
                           f'while nothing is on {self.temp_subs[0].topic_name}')
        reason = reason or self._unit_mismatch(cal, columns) or _probe(cal)
        if reason:
            return None, reason
        return ActiveModel(cal, tuple(columns), cal.id, source, time.time(),
                           CalibrationStream(cal)), None

    def _unit_mismatch(self, cal, columns):
        """Return why the calibration's input units differ from ``temperature_units``, or None."""
        bad = [f'{inp.topic} is in {inp.unit} in the calibration but '
               f'{self.temperature_units[c]} here'
               for inp, c in zip(cal.inputs, columns) if inp.unit != self.temperature_units[c]]
        if not bad:
            return None
        return (f'input units differ: {"; ".join(bad)}; set temperature_units (aligned with '
                f'temperature_topics {self.temperature_topics}) to the units the topics carry, '
                'or use a calibration made for them')

    def _reject(self, source, reason):
        self.last_rejection = f'{source}: {reason}'
        self.counts['calibrations_rejected'] += 1     # last: a reader of the count sees the why
        keep = (f'; keeping calibration {self._active.id}' if self._active
                else '; no calibration active')
        return False, f'rejected calibration from {source}: {reason}{keep}'

    def load_file(self):
        """(Re)load ``calibration_file`` (or every known unit from ``registry_dir``).

        Returns (ok, message).
        """
        if self.registry_dir:
            return self.units.reload()
        path = os.path.expanduser(self.get_parameter('calibration_file').value)
        if not path:
            return self._reject('calibration_file', 'the parameter is empty')
        try:
            cal = Calibration.load(path)
        except CalibrationError as e:
            return self._reject(path, str(e))
        except Exception as e:  # noqa: B902 - never die on a file: reject it, keep the old one
            return self._reject(path, f'unreadable ({e.__class__.__name__}: {e})')
        return self.activate(cal, path)

    def _on_reload(self, request, response):
        response.success, response.message = self.load_file()
        common.log(self, response.success, response.message)
        return response

    def _on_calibration(self, msg):
        active = self._active
        if self.registry_dir:
            common.log(self, *self._reject('imu/calibration', 'registry_dir is set: each unit '
                                           'takes its calibration from the registry'))
            return
        try:
            cal = Calibration.from_yaml(msg.data, 'imu/calibration')
            if active is not None and cal.id == active.id:
                return
            ok, text = self.activate(cal, 'imu/calibration topic')
        except CalibrationError as e:
            ok, text = self._reject('imu/calibration', str(e))
        except Exception as e:  # noqa: B902 - a latched bad message must never kill the node
            ok, text = self._reject('imu/calibration', f'unusable ({e.__class__.__name__}: '
                                                       f'{str(e)[:300]})')
        common.log(self, ok, text)

    # ------------------------------------------------------------------ data
    def _follow(self):
        """Follow an input's type (``thermal_types``) or a waiting calibration's input."""
        self.type_follower()
        done = self.adopter.poll()
        if done is not None:
            common.log(self, *done)

    def _subscribe_as(self, index, typ, topic=None):
        """Subscribe input ``index`` as ``typ`` (``thermal_types``), on ``topic`` if given.

        Another topic (``topic_follower.InputAdopter``) starts the input's readings afresh.
        """
        cls, value = common.THERMAL_TYPES[typ]
        if topic:
            self.temperature_topics[index] = self.temps.topics[index] = topic
            self.temps.tracks[index].clear()
            self.temps.received[index] = 0
        self._clocks.retype(index, common.headerless(cls), topic)
        self._temp_fields[index] = value
        self.temp_subs[index] = self.create_subscription(
            cls, self.temperature_topics[index], self._temperature_cb(index, value),
            common.sensor_qos(self._in_depth))

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

    def _warn_once(self, key, text):
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def finish(self):
        """Write the thermal-history state once more (``state_file``); once, on the way out.

        ``process.run_nodes`` calls this for every node before any middleware teardown,
        which can hang (see ``process.TEARDOWN_LIMIT_S``).
        """
        if self.units is None and not self._finished:
            self._finished = True
            self.state.after(self._active, force=True)

    def destroy_node(self):
        """Finish (``finish``), then destroy."""
        try:
            self.finish()
        finally:
            super().destroy_node()

    # ------------------------------------------------------------------ diagnostics
    def diagnostics_values(self):
        """Return (level, message, values) describing the node's state now."""
        active = self._active
        rate = self._rate.rate()
        values = {'model_loaded': active is not None,
                  'model_id': active.id if active else '',
                  'model_source': active.source if active else '',
                  'input_rate_hz': rate,
                  'on_missing_temperature': self.on_missing,
                  'temperature_units': ','.join(self.temperature_units)}
        ages = (self.temps.age_at(self._last_stamp_ns) if self._last_stamp_ns is not None
                else {t: math.inf for t in self.temperature_topics})
        for topic, age in ages.items():
            values[f'temperature_age_s[{topic}]'] = age
        for topic, how in self._clocks.describe().items():
            values[f'temperature_clock[{topic}]'] = how
        for topic, typ in zip(self.temperature_topics, self.type_follower.types):
            values[f'temperature_type[{topic}]'] = typ
        values.update(self.counts)
        values['temperature_invalid'] = self.temps.invalid
        values['temperature_time_resets'] = self.temps.time_resets
        if self._gate is not None:
            values['spikes_replaced'] = self._gate.counts()['rejected_total']
        values['last_rejection'] = self.last_rejection
        level, msg = common.OK, 'compensating'
        seen = self._units_seen
        values['accel_median_over_g'] = (math.nan if seen.accel_ratio is None
                                         else seen.accel_ratio)
        values['gyro_deg_per_s_samples'] = seen.gyro_unit
        wrong = seen.problems()
        if self.units is not None:
            values.update(self.units.diagnostics())
            values['last_rejection'] = self.units.last_rejection or self.last_rejection
        if self.units is not None and values['units_without_calibration']:
            level = common.WARN
            msg = (f'{values["units_without_calibration"]} unit(s) without calibration passed '
                   f'through: {self.units.uncalibrated_text()}')
        elif active is None:
            level = common.WARN
            msg = ('no calibration loaded: passing through' if self.passthrough_uncalibrated
                   else 'no calibration loaded: dropping all samples')
        elif active.columns and any(ages[self.temperature_topics[i]] > self.temperature_timeout
                                    for i in active.columns):
            level, msg = common.WARN, f'temperature stale or missing ({self.on_missing})'
        elif rate == 0.0:
            level, msg = common.WARN, 'no IMU input'
        if wrong:    # it outranks the other warnings: every output sample is wrong
            level = common.WARN
            msg = 'IMU input not in SI units: ' + '; '.join(seen for seen, _, _ in wrong.values())
        return level, msg, values

    def _publish_diagnostics(self):
        if 'silent_imu' not in self._warned:
            silent = input_hints.silent_imu(self, self._started, self.counts['received'])
            if silent:
                self._warn_once('silent_imu', silent)
        level, msg, values = self.diagnostics_values()
        self.diagnostics.publish([common.diagnostic_status(
            f'{self.get_name()}: thermal compensation', self.get_fully_qualified_name(),
            level, msg, values)])


def _probe(cal):
    """Return why ``cal`` cannot compensate one sample mid-range, or None when it can."""
    mid = (np.zeros((1, 0)) if cal.valid_range is None or not cal.inputs
           else cal.valid_range.mean(1).reshape(1, -1))
    try:
        res = cal.apply(np.array([[0.0, 0.0, cal.gravity]]), np.zeros((1, 3)), mid)
    except Exception as e:  # noqa: B902 - any failure makes the model unusable
        return f'applying it to a test sample failed ({e.__class__.__name__}: {e})'
    if not (np.isfinite(res.accel).all() and np.isfinite(res.gyro).all()):
        return 'it turns a test sample into NaN/Inf'
    return None


def main(args=None):
    """Run the compensator node."""
    process.exit_process(process.run_nodes([CompensatorNode], args))


if __name__ == '__main__':
    main()
