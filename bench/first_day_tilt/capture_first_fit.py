"""Re-run a month's lifelong loop (as bench_lifelong.run_seed) up to its first swap and
save the windows the first estimate was fitted on, the held-out windows and the new
calibration. Usage: capture_first_fit.py SEED OUT.pkl [high_order_margin|none] [sensors]
"""
import os
import pickle
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from bench_lifelong import DEFAULT, stop_chunks  # noqa: E402,F401
from thermal_imu_calib.app.calibrate import CalibrateSettings  # noqa: E402
from thermal_imu_calib.lifelong.feed import Feeder  # noqa: E402
from thermal_imu_calib.lifelong.hints import HintGate, HintSource  # noqa: E402
from thermal_imu_calib.lifelong.manager import Lifelong, LifelongConfig  # noqa: E402
from thermal_imu_calib.sim.robot_month import robot_month  # noqa: E402

seed, out = int(sys.argv[1]), sys.argv[2]
hom = None if len(sys.argv) < 3 + 1 or sys.argv[3] == 'none' else float(sys.argv[3])
hos = sys.argv[4] if len(sys.argv) > 4 else CalibrateSettings.high_order_sensors
m = robot_month(seed, days=30.0)
d = tempfile.mkdtemp(prefix='fd_', dir=None)
settings = CalibrateSettings(latitude=45.0, high_order_margin=hom, high_order_sensors=hos)
life = Lifelong(d, settings, 1, [m.config.temp_topic], m.config.frame_id,
                registry_dir=os.path.join(d, 'registry'), config=LifelongConfig(),
                log=lambda level, text: None)
calls = []
orig = life._calibrate


def spy(windows):
    calls.append(windows)
    return orig(windows)


life._calibrate = spy
orig_est = life.estimate
held_log = []


def est(reason='requested'):
    held = life.store.newest_holds(life.config.holdout_holds)
    held_log.append(life.store.holds(held))
    calls.append('estimate')
    return orig_est(reason)


life.estimate = est
feeder = Feeder(life, HintGate([HintSource('cmd_vel', True, 1.0)]))
restarts = list(m.restart_times)
base = m.start_ns * 1e-9
done = None
for seg in m.segments():
    if restarts and restarts[0] < seg.stop.t0:
        print('restart before first swap: not handled', file=sys.stderr)
        break
    feeder.push(seg.imu, [seg.temperature], [('cmd_vel', t, s) for t, s in seg.hints])
    for dec in feeder.decisions:
        print(f'{(dec["time"] - base) / 3600:.3f} h {dec["action"]}: {dec.get("reason")}')
        if dec['action'] == 'swap':
            done = dec
    feeder.decisions = []
    if done:
        break
# the windows of the first _calibrate call of the last estimate
last = max(i for i, c in enumerate(calls) if isinstance(c, str))
fit = calls[last + 1]
with open(out, 'wb') as f:
    pickle.dump({'seed': seed, 'fit': fit, 'all_calls': [c for c in calls[last + 1:]
                                                         if not isinstance(c, str)],
                 'held': held_log[-1], 'active': life.active.to_dict(),
                 'decision': done, 'base': base}, f)
print('saved', out, 'fit windows', len(fit), 'holds', np.unique(fit.hold).tolist(),
      'calls in last estimate', sum(1 for c in calls[last + 1:]))
print('c1', life.active.accel.coeffs if hasattr(life.active.accel, 'coeffs') else None)
