"""Collect the stationary windows of a recorded log: the first step of calibrate, evaluate, info.

Streams a log in column chunks (memory bounded by ``chunk_size`` whatever the log length)
through the input gate (``io.gate``), the temperature aligner (``io.align``) and the
stationary detector (``collection.stationary``, or ``collection.motion`` to keep the pose
changes too); returns a ``collection.collected.Collected``. ``aligned_chunks`` is the
stream the other log use cases (compensate, evaluate, noise) read through.
"""

import sys
import time

from ..collection.collected import Collected
from ..collection.feed import DEFAULT_MAX_GAP_S, fresh_part
from ..collection.motion import MotionCollector
from ..collection.segments import Windows
from ..collection.stationary import StationaryDetector
from ..input_units import DEGC, parse_unit_map
from ..io.align import StreamAligner
from ..io.bag import open_log
from ..io.gate import InputGate
from ..io.topics import resolve_topics


def progress_bar(total, desc, enabled):
    """Return a tqdm bar on stderr (None when ``enabled`` is False, or None and no terminal)."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit='msg', unit_scale=True, file=sys.stderr,
                leave=False)


def aligned_chunks(reader, imu_topic, temp_topics, chunk_size, max_gap_s, keep_raw=False,
                   bar=None, gate=None):
    """Yield the AlignedChunks of a log (IMU rows with their temperatures), gated if asked."""
    aligner = StreamAligner(temp_topics, max_gap_s)
    for raw in reader.stream(imu_topic, temp_topics, chunk_size, keep_raw=keep_raw):
        if bar is not None:
            bar.update(len(raw.imu))
        yield from aligner.push(raw if gate is None else gate.push(raw))
    yield from aligner.finish()


def collect_windows(path, imu_topic=None, temperature_topics=None, detector=None,
                    chunk_size=20000, max_gap_s=DEFAULT_MAX_GAP_S, progress=None,
                    motion=False, input_units=None):
    """Run the stationary detector over a log; returns Collected.

    Samples no sensor gives (non-finite, beyond any range, degC inputs outside -80..200,
    IMU stamps that do not increase) are dropped and counted first (``io.gate``,
    ``Collected.gate``); ``input_units`` are ``TOPIC=UNIT`` items (unnamed inputs: degC;
    None: no input is bounded, only finite).

    With ``motion`` a ``gyro_fit.MotionCollector`` also keeps the raw samples of the pose
    changes between holds (``Collected.transitions``; what the ``whole_unit`` gyro rotation
    fit needs); memory stays bounded (see its ``memory_bytes``).
    """
    with open_log(path) as reader:
        notes = []
        imu_topic, temps = resolve_topics(reader, imu_topic, temperature_topics, notes)
        n_topic_notes = len(notes)     # the readers' notes follow (``RawChunk.notes``)
        try:
            units = ([''] * len(temps) if input_units is None
                     else parse_unit_map(input_units, temps))
        except ValueError:
            units = [DEGC] * len(temps)  # the caller reports a bad --input-unit itself
        gate = InputGate(dict(zip(temps, units)))
        gate.report.notes = notes
        total = reader.topic_types() and reader.topics()[imu_topic].count
        det = (MotionCollector(detector, len(temps)) if motion
               else StationaryDetector(detector, len(temps)))
        parts, n, frame, peak = [], 0, '', 0
        bar = progress_bar(total, 'reading', progress)
        t_start = time.perf_counter()
        for ch in aligned_chunks(reader, imu_topic, temps, chunk_size, max_gap_s, bar=bar,
                                 gate=gate):
            n += len(ch)
            frame = frame or ch.imu.frame_id
            imu, temps_in, left_out = fresh_part(ch, max_gap_s)   # as calibrator_node does
            gate.report.imu_no_temperature += left_out
            if len(imu):
                parts.append(det.update(imu.t, imu.accel, imu.gyro, temps_in))
            if motion:
                peak = max(peak, det.memory_bytes())
        parts.append(det.finish())
        if bar is not None:
            bar.close()
    sd = det.det if motion else det
    return Collected(Windows.concat(parts) if any(len(p) for p in parts)
                     else Windows.empty(len(temps)), frame, n,
                     time.perf_counter() - t_start, temps,
                     det.transitions if motion else [],
                     {'dropped': dict(det.dropped), 'peak_bytes': peak} if motion else None,
                     sd.settings(), list(sd.holds),
                     gate.report, notes[n_topic_notes:])
