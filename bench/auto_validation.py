"""``--model auto`` on a simulated MEMS cold start, judged on the same device's next cold start.

Per seed: ``mems-coldstart`` calibrated with default options (``auto``), as ``bench_mems``
calibrates (stationary windows, the pose changes, latitude 45 deg); judged on
``mems-validation`` of the same device with ``bench_mems.metrics``: the static vector error
|mean(a) - g up| and the norm error, RMS over the validation holds, ug. Prints one JSON line
per seed (the model ``auto`` chose, the accelerometer model kind, the two errors).

Usage: ``python bench/auto_validation.py [SEED ...]`` (default 0-5; about 30 s per seed)
"""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import bench_mems as bm  # noqa: E402
from thermal_imu_calib import sim  # noqa: E402


def run(seed):
    """Return the JSON-able result of one seed."""
    res, _ = bm.calibrate([sim.simulate('mems-coldstart', seed)], 'auto')
    val = sim.simulate('mems-validation', seed)
    vw, f_true, w_true = bm.validation_windows(val)
    m = bm.metrics(vw, res.calibration, f_true, w_true, val.gravity)
    return {'seed': seed, 'model': res.report['model_choice']['model'],
            'accel': res.calibration.accel.kind, 'vector_ug': m['vector_error_ug'],
            'norm_ug': m['norm_error_ug']}


if __name__ == '__main__':
    for s in [int(a) for a in sys.argv[1:]] or range(6):
        print(json.dumps(run(s)), flush=True)
