"""Small sample-level generator for unit tests of the core (independent of sim.py)."""

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from thermal_imu_calib.models.field import FieldPolynomialModel

G = 9.80665
FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def truth_model(rng, scale=1.0):
    """Return a MEMS-like seed-000 model with random parameters."""
    th = np.zeros((3, 6))
    th[:, 0] = rng.normal(0, 2e-3, 3) * scale
    th[:, 1] = rng.normal(0, 1e-4, 3) * scale
    th[:, 2] = rng.normal(0, 2e-6, 3) * scale
    th[:, 3] = rng.normal(0, 0.1, 3) * scale
    th[:, 4] = rng.normal(0, 1e-3, 3) * scale
    th[:, 5] = rng.normal(0, 2e-5, 3) * scale
    return FieldPolynomialModel([30.0] * 3, th)


def recording(rng, model, directions, hold_s=30.0, move_s=3.0, rate=100.0, sigma_a=0.01,
              sigma_g=0.002, temp=lambda t: 20 + 15 * (1 - np.exp(-t / 300.0))):
    """Return (t, raw accel, gyro, temperature, hold intervals) for a sequence of poses.

    Each direction is the gravity-up axis in the sensor frame; between holds the sensor
    rotates smoothly over ``move_s`` seconds (gyro sees it, accel sees gravity turning).
    """
    def rot_to(d):
        d = d / np.linalg.norm(d)
        r, _ = Rotation.align_vectors([d], [[0, 0, 1]])
        return r  # maps world-up to sensor-frame d

    ts, fs, ws, holds = [], [], [], []
    t = 0.0
    prev = None
    dt = 1.0 / rate
    for d in directions:
        r = rot_to(np.asarray(d, float))
        if prev is not None:
            n = int(move_s * rate)
            tt = t + np.arange(n) * dt
            s = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, n))
            rots = Slerp([0, 1], Rotation.concatenate([prev, r]))(s)
            f = rots.apply([0, 0, G]) + rng.normal(0, 0.5, (n, 3))  # hand jitter
            rv = (prev.inv() * r).as_rotvec()
            w = np.outer(np.gradient(s, dt), rv)
            ts.append(tt), fs.append(f), ws.append(w)
            t += n * dt
        n = int(hold_s * rate)
        tt = t + np.arange(n) * dt
        ts.append(tt), fs.append(np.tile(r.apply([0, 0, G]), (n, 1))), ws.append(np.zeros((n, 3)))
        holds.append((t, t + n * dt))
        t += n * dt
        prev = r
    t = np.concatenate(ts)
    f = np.concatenate(fs)
    w = np.concatenate(ws)
    temps = temp(t)
    raw = model.forward(f, np.repeat(temps[:, None], 3, 1)) + rng.normal(0, sigma_a, f.shape)
    gyro = w + 1e-3 * (temps[:, None] - 30) * np.array([1, -2, 0.5]) * 1e-1 \
        + rng.normal(0, sigma_g, w.shape)
    return t, raw, gyro, temps, holds
