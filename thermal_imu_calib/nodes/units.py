"""The compensator's registry units and loop guard (no rclpy objects held).

``RegistryUnits``: with ``registry_dir`` each IMU unit, told by its header frame_id, gets
its own model, looked up once in the fleet registry (``fleet.registry.valid_at``, the id
exactly as recorded) and kept, so interleaved units never reload; a unit with no usable
calibration is remembered as such (None) and its messages pass through, counted.

``SentMessages``: the keys (header and the six values) of the last messages published, so
a message that comes back (output routed to the input by a relay or a remap) is dropped
instead of being compensated again; ``refuse_loop`` refuses an output topic that resolves
to an input topic at start.
"""

from collections import deque
import os

from ..calibration import Calibration, CalibrationError

#: most units (frame_ids) looked up and kept; further ones pass through uncompensated
MAX_UNITS = 256
#: published messages remembered to recognise them if they come back
SENT_MEMORY = 10000


class RegistryUnits:
    """One model per IMU unit from a fleet registry, looked up at the unit's first message.

    ``make_model(cal, source) -> (model, reason)`` builds a model the node can serve;
    ``counts`` (the node's dict) gets ``calibrations_loaded`` / ``calibrations_rejected``;
    ``logger`` is the node's.
    """

    def __init__(self, registry_dir, make_model, counts, logger, max_units=MAX_UNITS):
        self.root = os.path.expanduser(registry_dir)
        self.models = {}
        self.last_rejection = ''
        self._make, self._counts, self._log = make_model, counts, logger
        self._max = max_units
        self._warned = False

    def model(self, frame):
        """Return the model of unit ``frame`` (None: no usable calibration), looked up once."""
        if frame in self.models:
            return self.models[frame]
        if len(self.models) >= self._max:
            if not self._warned:
                self._warned = True
                self._log.warning(f'more than {self._max} IMU frame_ids seen: the others are '
                                  'not looked up in the registry and pass through '
                                  'uncompensated (counted as uncalibrated_unit)')
            return None
        from ..fleet.registry import display_id, valid_at
        try:
            path = valid_at(self.root, frame)
            model, reason = self._make(Calibration.load(path), path)
        except (LookupError, CalibrationError, OSError, ValueError) as e:
            model, reason = None, str(e)
        self.models[frame] = model
        if model is None:
            self.last_rejection = f'unit {display_id(frame)}: {reason}'
            self._counts['calibrations_rejected'] += 1   # after the why, for its readers
            self._log.warning(f'IMU unit {display_id(frame)}: no usable calibration in '
                              f'registry {self.root} ({reason}); its messages pass through '
                              'uncompensated')
        else:
            self._counts['calibrations_loaded'] += 1
            self._log.info(f'IMU unit {display_id(frame)}: {active_text(model)}')
        return model

    def reload(self):
        """Look every unit seen so far up again; returns (True, summary)."""
        frames = list(self.models)
        self.models.clear()
        for frame in frames:
            self.model(frame)
        have = self.calibrated()
        return True, (f'registry {self.root}: {have} of {len(frames)} units seen have a '
                      'calibration' + (f'; without: {self.uncalibrated_text()}'
                                       if have < len(frames) else ''))

    def calibrated(self):
        """Return how many units seen have a model."""
        return sum(m is not None for m in self.models.values())

    def uncalibrated_text(self, limit=5):
        """Return the units seen without a calibration, for people (at most ``limit``)."""
        from ..fleet.registry import display_id
        names = [display_id(f) for f, m in self.models.items() if m is None]
        return ', '.join(names[:limit]) + (f' and {len(names) - limit} more'
                                           if len(names) > limit else '')

    def diagnostics(self):
        """Return the /diagnostics values of the units."""
        return {'units_calibrated': self.calibrated(),
                'units_without_calibration': len(self.models) - self.calibrated(),
                'units_without_calibration_ids': self.uncalibrated_text(20)}


def active_text(model):
    """Return 'calibration ID active from SOURCE: accel ..., gyro ..., inputs ...'."""
    cal = model.calibration
    return (f'calibration {cal.id} active from {model.source}: accel '
            f'{cal.accel.kind if cal.accel else "none"}, gyro '
            f'{cal.gyro.kind if cal.gyro else "none"}, inputs '
            f'{cal.temperature_topics or "none"}')


def refuse_loop(output, inputs):
    """Raise ValueError when the output topic (resolved) is an input topic: a feedback loop."""
    if output in inputs:
        raise ValueError(f'output topic {output} is also an input topic: every compensated '
                         'message would come back and be compensated again; remap '
                         'imu/data_compensated and imu/data_raw to different topics')


def message_key(msg):
    """Return what identifies a published Imu message: header and the six values."""
    h, a, w = msg.header, msg.linear_acceleration, msg.angular_velocity
    return (h.frame_id, h.stamp.sec, h.stamp.nanosec, a.x, a.y, a.z, w.x, w.y, w.z)


class SentMessages:
    """The keys of the last ``size`` messages published, with O(1) membership."""

    def __init__(self, size=SENT_MEMORY):
        self._order = deque()
        self._set = set()
        self.size = size

    def add(self, msg):
        """Remember a published message, forgetting the oldest beyond ``size``."""
        key = message_key(msg)
        if key in self._set:
            return
        self._order.append(key)
        self._set.add(key)
        if len(self._order) > self.size:
            self._set.discard(self._order.popleft())

    def drop_own(self, msgs):
        """Return (``msgs`` not published by this node, how many were)."""
        if not self._set:
            return msgs, 0
        keep = [m for m in msgs if message_key(m) not in self._set]
        return keep, len(msgs) - len(keep)
