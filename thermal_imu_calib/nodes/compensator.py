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

The node is split by concern:

* ``nodes/compensator_params.py``: the parameters, declared on the node and changed at run
  time;
* ``nodes/compensator_batch.py``: the data path (``LiveCompensation``: thermal readings in,
  each IMU batch compensated with one model and published, counted);
* here: the calibration hand-over (file, topic, ``~/reload``, registry units), the input
  subscriptions, the saved state on the way out and the diagnostics.

The maths is in ``calibration`` and ``thermal_input``, the registry units in ``units``, the
saved state in ``compensator_state``.
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
from .compensator_batch import LiveCompensation
from .compensator_state import StreamStateFile
from ..calibration import Calibration, CalibrationError
from ..collection.outliers import ImuSpikeFilter
from ..gravity import STANDARD_GRAVITY
from ..io.headerless import LiveClocks
from ..io.imu_units import UnitWatch
from ..thermal_input import CalibrationStream

NODE_NAME = 'thermal_imu_compensator'


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


class CompensatorNode(LiveCompensation, Node):
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
