"""Quaternions and rotation integration: small pure helpers (no state, SI units).

Quaternions are scalar-first ``(w, x, y, z)`` arrays of shape (..., 4);
rotation vectors are in rad, rates in rad/s, time steps in s. Used by the
gyro rotation fit and the simulator.
"""

import numpy as np


# ------------------------------------------------------------------------ quaternions
def quat_from_rotvec(v):
    """Return (..., 4) unit quaternions (w, x, y, z) for rotation vectors (..., 3), rad."""
    v = np.asarray(v, float)
    th = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * th
    small = th < 1e-8
    s = np.where(small, 0.5 - th * th / 48.0, np.sin(half) / np.where(small, 1.0, th))
    return np.concatenate([np.cos(half), s * v], axis=-1)


def quat_mul(p, q):
    """Return the Hamilton product p q of (..., 4) quaternions."""
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def quat_rotate_inverse(q, v):
    """Return R(q)' v: vectors (..., 3) expressed in the rotated frame."""
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    vq = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return quat_mul(quat_mul(qc, vq), q)[..., 1:]


def quat_to_rotvec(q):
    """Return rotation vectors (..., 3) of unit quaternions (..., 4) (angle <= pi)."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return scale * q[..., 1:]


def integrate_batch(increments):
    """Return the ordered products of rotation-vector increments, one per row.

    increments: (k, n, 3) body-frame rotation vectors (zero-padded rows are identities);
    returns (k, 4) quaternions of dR = exp(inc_0) exp(inc_1) ... exp(inc_{n-1}).
    """
    q = quat_from_rotvec(increments)
    n = q.shape[1]
    size = 1 << max(int(np.ceil(np.log2(max(n, 1)))), 0)
    if size > n:
        pad = np.zeros((q.shape[0], size - n, 4))
        pad[..., 0] = 1.0
        q = np.concatenate([q, pad], axis=1)
    while q.shape[1] > 1:
        q = quat_mul(q[:, 0::2], q[:, 1::2])
    return q[:, 0] / np.linalg.norm(q[:, 0], axis=-1, keepdims=True)


def rate_increments(t, omega):
    """Return (n-1, 3) rotation increments of rates omega (n, 3) at times t (trapezoid)."""
    dt = np.diff(np.asarray(t, float))
    return 0.5 * (omega[1:] + omega[:-1]) * dt[:, None]


def integrate_rotation(t, omega):
    """Return the rotation vector (3,) of dR for body rates omega (n, 3) rad/s at times t s."""
    inc = rate_increments(t, np.asarray(omega, float))
    return quat_to_rotvec(integrate_batch(inc[None]))[0]


def prefix_products(q):
    """Return inclusive ordered prefix products q_0 ... q_i along axis 1 of (k, n, 4)."""
    q = q.copy()
    s = 1
    n = q.shape[1]
    while s < n:
        q[:, s:] = quat_mul(q[:, :-s], q[:, s:])
        s *= 2
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_matrix(q):
    """Return (..., 3, 3) rotation matrices of unit quaternions (..., 4) (w, x, y, z)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)],
        -2)
