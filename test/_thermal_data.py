"""Window statistics for the thermal-model tests: from the simulator, or synthetic."""

import numpy as np

from thermal_imu_calib.calibration import TemperatureInput
from thermal_imu_calib.estimation.calibrate import CalibrateOptions
from thermal_imu_calib.estimation.segments import Windows
from thermal_imu_calib.estimation.stationary import StationaryDetector
from thermal_imu_calib.io.align import StreamAligner
from thermal_imu_calib.io.columns import TemperatureColumns

G = 9.80665


def sim_windows(rec):
    """Run the stationary detector over a simulated recording (no bag round trip)."""
    topics = list(rec.config.temp_topics)
    aligner = StreamAligner(len(topics), 5.0)
    det = StationaryDetector(None, len(topics))
    empty = [TemperatureColumns.empty() for _ in topics]
    parts, first = [], True
    for ch in rec.imu_chunks():
        temps = [rec.temperatures[t] for t in topics] if first else empty
        first = False
        for a in aligner.push_columns(ch, temps):
            parts.append(det.update(a.imu.t, a.imu.accel, a.imu.gyro, a.temps))
    for a in aligner.finish():
        parts.append(det.update(a.imu.t, a.imu.accel, a.imu.gyro, a.temps))
    parts.append(det.finish())
    return Windows.concat(parts)


def options(k=1):
    """Return calibration options for k temperature topics."""
    return CalibrateOptions(inputs=[TemperatureInput(f't{i}', f'/imu/temperature{i or ""}')
                                    for i in range(k)])


def make_windows(t, temp, accel, gyro, hold=None, n=500, sigma_a=1e-3, sigma_g=1e-4,
                 rng=None, window_s=5.0):
    """Return Windows with the given means plus white noise of n-sample averages.

    t: (m,) window start times s; temp: (m,) degC; accel, gyro: (m, 3) noise-free means.
    """
    rng = rng or np.random.default_rng(0)
    m = len(t)
    hold = np.zeros(m, int) if hold is None else np.asarray(hold)
    acc = accel + rng.normal(0, sigma_a / np.sqrt(n), (m, 3))
    gyr = gyro + rng.normal(0, sigma_g / np.sqrt(n), (m, 3))
    rate = np.gradient(temp, t) if m > 1 else np.zeros(m)
    return Windows(hold, np.asarray(t, float), np.asarray(t, float) + window_s,
                   np.full(m, n), acc, gyr, np.full((m, 3), sigma_a ** 2),
                   np.full((m, 3), sigma_g ** 2), np.asarray(temp, float)[:, None],
                   rate[:, None])
