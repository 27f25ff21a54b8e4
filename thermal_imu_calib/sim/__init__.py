"""The simulator: realistic IMU recordings with temperature-induced errors.

Modules: ``simulate`` (``simulate``, ``write_scenario``, the recording), ``devices`` (the
true sensor parameters drawn per seed and family), ``schedule`` (poses, holds and thermal
tracks), ``scenarios`` (the named scenarios beyond the base set), ``unmodelled`` (errors
outside the model families) and ``proxy`` (a resonance proxy for the temperature).

``from thermal_imu_calib import sim`` gives the public names below.
"""

from .simulate import (accel_forward, DEG, DEVICES, DeviceParams, DeviceSpec,  # noqa: F401
                       draw_device, EARTH_RATE, EPOCH_NS, FACES, first_order_lag, G0,
                       gyro_forward, Hold, ScenarioConfig, SCENARIOS, sidecar_outputs,
                       SimRecording, simulate, SIX_FACES, still_noise, THERMAL_COLUMNS,
                       TILTED, TruthChunk, write_scenario)
