"""What a collection is: the stationary windows of one log (or of a live node) and merging them.

``Collected`` is what ``app.collect.collect_windows`` returns for a log and what the
calibrator node builds from its live collection; ``merge_windows`` / ``merge_transitions``
join several of them with distinct hold ids, as ``app.calibrate`` estimates from them.
Units: seconds (``Collected.seconds``, wall time of the read).
"""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .motion import offset_holds
from .segments import Windows


@dataclass
class Collected:
    """Stationary windows of one log (and the pose changes between them) plus what was read."""

    windows: Windows
    frame_id: str
    imu_messages: int
    seconds: float
    temperature_topics: list
    #: pose changes between consecutive holds (gyro_fit.Transition), with ``motion=True``
    transitions: list = field(default_factory=list)
    #: with ``motion=True``: pose changes dropped by reason and the collector's peak bytes
    motion: Optional[dict] = None
    #: the detector's derived settings (StationaryDetector.settings) and hold records
    detector: Optional[dict] = None
    holds: list = field(default_factory=list)
    #: what the input gate dropped and saw (io.gate.GateReport)
    gate: Optional[object] = None
    #: what was done to the thermal inputs while reading (put on the IMU's clock; live: a
    #: message type followed), for the calibration file's notes
    input_notes: list = field(default_factory=list)


def hold_offsets(collected):
    """Return what to add to the hold ids of each Collected so merged ids stay distinct."""
    out, offset = [], 0
    for c in collected:
        out.append(offset)
        if len(c.windows):
            offset += int(c.windows.hold.max()) + 1
    return out


def merge_windows(collected):
    """Concatenate windows of several logs, keeping hold ids distinct (``hold_offsets``)."""
    parts = []
    for c, offset in zip(collected, hold_offsets(collected)):
        w = c.windows
        if len(w):
            w = w.select(np.ones(len(w), bool))
            w.hold = w.hold + offset
        parts.append(w)
    return Windows.concat(parts)


def merge_transitions(collected):
    """Concatenate the pose changes of several logs with the hold ids of ``merge_windows``."""
    return [tr for c, offset in zip(collected, hold_offsets(collected))
            for tr in offset_holds(c.transitions, offset)]
