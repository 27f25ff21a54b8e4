"""Feed columns (a simulation, a log) through detector, hint gate and lifelong loop.

The same path the node takes, without ROS: the IMU rows ``calibrate`` drops are dropped
(``io.gate.LiveImuFilter``), IMU and temperature columns are aligned
(``io.align.StreamAligner``), the stationary detector closes holds, the hint gate keeps
the windows the robot was commanded still for, ``Lifelong.add`` stores them and, when
``due``, ``Lifelong.estimate`` runs (here on the caller's thread).
"""

from ..collection.feed import DEFAULT_MAX_GAP_S, fresh_part
from ..collection.stationary import DetectorConfig, StationaryDetector
from ..io.align import StreamAligner
from ..io.gate import LiveImuFilter


class Feeder:
    """Detector, aligner and hint gate in front of a ``manager.Lifelong``."""

    def __init__(self, lifelong, hints=None, detector=None,
                 temperature_timeout=DEFAULT_MAX_GAP_S, estimate=True):
        self.lifelong = lifelong
        self.hints = hints
        self.k = lifelong.k
        self.config = detector or DetectorConfig()
        self.timeout = float(temperature_timeout)
        self.estimate = estimate
        self.decisions = []
        self.restart()

    def restart(self):
        """Start detection afresh (a node restart: the open hold is lost)."""
        self.detector = StationaryDetector(DetectorConfig(**vars(self.config)), self.k)
        self.aligner = StreamAligner(self.k, self.timeout)
        self.rows = LiveImuFilter()

    def push(self, imu, temperatures=(), hint_events=()):
        """Feed ImuColumns, one TemperatureColumns per input, [(name, stamp s, still)]."""
        if self.hints is not None:
            for name, stamp, still in hint_events:
                self.hints.add(name, stamp, still)
        imu = self.rows.push(imu)
        for chunk in self.aligner.push_columns(imu, list(temperatures)):
            self._update(chunk)

    def _update(self, chunk):
        """Detect on the chunk's rows with a fresh temperature (``fresh_part``, the node's)."""
        imu, temps, _ = fresh_part(chunk, self.timeout)
        if len(imu):
            self._take(self.detector.update(imu.t, imu.accel, imu.gyro, temps))

    def finish(self):
        """Close the hold in progress."""
        for chunk in self.aligner.finish():
            self._update(chunk)
        self._take(self.detector.finish())

    def _take(self, win):
        if not len(win):
            return
        if self.hints is not None:
            win = self.hints.filter(win)
        self.lifelong.add(win)
        if self.estimate:
            why = self.lifelong.due()
            if why:
                self.decisions.append(self.lifelong.estimate(why))
