"""Feed in-memory IMU and temperature columns (no log) through the aligner into a detector.

For simulations and tests: the same temperature alignment (``io.align.StreamAligner``) and
stationary detection as a log gets in ``app.collect.collect_windows``. Units: seconds
(``max_gap_s``).
"""

from ..io.align import fresh_rows, StreamAligner
from ..io.columns import TemperatureColumns
from .segments import Windows
from .stationary import StationaryDetector

#: temperature samples further apart than this are a gap: the nearest sample is held (s)
DEFAULT_MAX_GAP_S = 5.0


def fresh_part(chunk, max_gap_s):
    """Return (ImuColumns, temperatures, rows left out) of AlignedChunk ``chunk``'s fresh rows.

    The one collection rule (``io.align.fresh_rows``) of ``calibrate``, the simulations,
    ``calibrator_node`` and the lifelong feeder: only these rows go to the detector (none
    when the ImuColumns returned are empty).
    """
    use = fresh_rows(chunk.temp_age, max_gap_s)
    left_out = len(use) - int(use.sum())
    if not left_out:
        return chunk.imu, chunk.temps, 0
    return chunk.imu.slice(use), chunk.temps[use], left_out


def windows_from_columns(imu_chunks, temperatures=(), detector=None,
                         max_gap_s=DEFAULT_MAX_GAP_S):
    """Run the stationary detector over in-memory columns (no log): e.g. a simulation.

    imu_chunks: iterable of ImuColumns in time order; temperatures: one TemperatureColumns
    per input (whole series). Returns the Windows table.
    """
    temperatures = list(temperatures)
    return feed_columns(StationaryDetector(detector, len(temperatures)), imu_chunks,
                        temperatures, max_gap_s)


def feed_columns(det, imu_chunks, temperatures=(), max_gap_s=DEFAULT_MAX_GAP_S):
    """Feed in-memory columns through the temperature aligner into ``det``; return Windows.

    ``det`` is anything with ``update(t, accel, gyro, temps)`` and ``finish()`` returning
    Windows: a StationaryDetector, or a MotionCollector (which keeps the pose changes too).
    """
    temperatures = list(temperatures)
    aligner = StreamAligner(len(temperatures), max_gap_s)
    pending = temperatures
    parts = []

    def update(a):
        imu, temps, _ = fresh_part(a, max_gap_s)           # as a log's collection
        if len(imu):
            parts.append(det.update(imu.t, imu.accel, imu.gyro, temps))

    for ch in imu_chunks:
        for a in aligner.push_columns(ch, pending):
            update(a)
        pending = [TemperatureColumns.empty() for _ in temperatures]
    for a in aligner.finish():
        update(a)
    parts.append(det.finish())
    return Windows.concat(parts) if any(len(p) for p in parts) \
        else Windows.empty(len(temperatures))
