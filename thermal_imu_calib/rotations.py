"""Quaternions and rotation integration: small pure helpers (no state, SI units).

Quaternions are scalar-first ``(w, x, y, z)`` arrays of shape (..., 4);
rotation vectors are in rad, rates in rad/s, time steps in s. Used by the
gyro rotation fit and the simulator.
"""

import numpy as np


# ------------------------------------------------------------------------ quaternions
def sum_sq(v):
    """Return ``np.sum(v * v, axis=-1)`` of a float array (..., 3 or 4), bit for bit.

    numpy reduces a short last axis left to right, element by element, with a per-row
    overhead that dominates on these small batches; the same additions in the same order
    over whole columns give the same bits.
    """
    s = v[..., 0] * v[..., 0]
    for i in range(1, v.shape[-1]):
        s = s + v[..., i] * v[..., i]
    return s


def cross(a, b):
    """Return the cross products of (..., 3) float arrays as numpy's cross, bit for bit.

    The same products and differences, without numpy's per-call set-up.
    """
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.subtract(a[..., j] * b[..., k], a[..., k] * b[..., j], out=out[..., i])
    return out


def _norm(v):
    """Return ``np.linalg.norm(v, axis=-1, keepdims=True)`` of a float array, bit for bit."""
    return np.sqrt(sum_sq(v))[..., None]


def quat_from_rotvec(v):
    """Return (..., 4) unit quaternions (w, x, y, z) for rotation vectors (..., 3), rad."""
    v = np.asarray(v, float)
    th = _norm(v)
    half = 0.5 * th
    small = th < 1e-8
    if small.any():
        s = np.where(small, 0.5 - th * th / 48.0, np.sin(half) / np.where(small, 1.0, th))
    else:
        s = np.sin(half) / th
    out = np.empty(v.shape[:-1] + (4,))
    np.cos(half, out=out[..., :1])
    np.multiply(s, v, out=out[..., 1:])
    return out


def _product_tensors():
    """Return (16, 4) Hamilton and (16, 9) rotation-matrix coefficients of q_i q_j."""
    ham = np.zeros((4, 4, 4))
    # (p q)_k = sum_ij ham[i, j, k] p_i q_j, scalar first
    for i, j, k, s in ((0, 0, 0, 1), (1, 1, 0, -1), (2, 2, 0, -1), (3, 3, 0, -1),
                       (0, 1, 1, 1), (1, 0, 1, 1), (2, 3, 1, 1), (3, 2, 1, -1),
                       (0, 2, 2, 1), (1, 3, 2, -1), (2, 0, 2, 1), (3, 1, 2, 1),
                       (0, 3, 3, 1), (1, 2, 3, 1), (2, 1, 3, -1), (3, 0, 3, 1)):
        ham[i, j, k] = s
    # R = I + sum_ij rot[i, j] q_i q_j (unit q), the terms of quat_to_matrix's docstring
    rot = np.zeros((4, 4, 3, 3))
    w, x, y, z = range(4)
    for a, b, i, j, s in ((0, 0, y, y, -2), (0, 0, z, z, -2), (1, 1, x, x, -2),
                          (1, 1, z, z, -2), (2, 2, x, x, -2), (2, 2, y, y, -2),
                          (0, 1, x, y, 2), (0, 1, w, z, -2), (0, 2, x, z, 2), (0, 2, w, y, 2),
                          (1, 0, x, y, 2), (1, 0, w, z, 2), (1, 2, y, z, 2), (1, 2, w, x, -2),
                          (2, 0, x, z, 2), (2, 0, w, y, -2), (2, 1, y, z, 2), (2, 1, w, x, 2)):
        rot[i, j, a, b] += s
    return ham.reshape(16, 4), rot.reshape(16, 9)


_HAMILTON, _ROTATION = _product_tensors()


_I16, _J16 = np.repeat(np.arange(4), 4), np.tile(np.arange(4), 4)
_I9, _J9 = np.repeat(np.arange(3), 3), np.tile(np.arange(3), 3)


def _outer(p, q):
    """Return (..., 16) products p_i q_j (index 4 i + j) of (..., 4) arrays (broadcast)."""
    return np.asarray(p, float)[..., _I16] * np.asarray(q, float)[..., _J16]


def quat_mul(p, q):
    """Return the Hamilton product p q of (..., 4) quaternions.

    One bilinear map (a (16, 4) coefficient matrix on the outer product): a few array
    operations whatever the batch shape, as the rotation fit calls it thousands of times
    on small batches.
    """
    return _outer(p, q) @ _HAMILTON


def quat_rotate_inverse(q, v):
    """Return R(q)' v: vectors (..., 3) expressed in the rotated frame (q unit)."""
    return np.einsum('...ji,...j->...i', quat_to_matrix(q), v)


#: [v]x = (v @ SKEW).reshape(3, 3), the cross-product matrix of v
SKEW = np.array([[0, 0, 0, 0, 0, -1, 0, 1, 0], [0, 0, 1, 0, 0, 0, -1, 0, 0],
                 [0, -1, 0, 1, 0, 0, 0, 0, 0]], float)


def _so3_series(v, a, c, t2):
    """Return (..., 3, 3) I + a [v]x + c [v]x^2 of vectors v (..., 3), |v|^2 = t2.

    With [v]x^2 = v v' - t^2 I: the form of both ``right_jacobian`` and its inverse.
    """
    out = (v @ SKEW) * np.asarray(a)[..., None] + v[..., _I9] * v[..., _J9] * c[..., None]
    out[..., 0::4] += (1.0 - c * t2)[..., None]
    return out.reshape(v.shape[:-1] + (3, 3))


def right_jacobian(v):
    """Return (..., 3, 3) right Jacobians of SO(3) at rotation vectors (..., 3), rad.

    exp(v + d) = exp(v) exp(J_r(v) d) to first order in d:
    J_r = I - (1 - cos t) / t^2 [v]x + (t - sin t) / t^3 [v]x^2, t = |v|, with
    [v]x^2 = v v' - t^2 I.
    """
    v = np.asarray(v, float)
    t2 = sum_sq(v)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / ts ** 2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - np.sin(ts)) / ts ** 3)
    return _so3_series(v, -a, b, t2)


def right_jacobian_inverse(v):
    """Return (..., 3, 3) inverses of ``right_jacobian`` (|v| < pi), rad.

    rotvec(exp(v) exp(d)) = v + J_r^-1(v) d to first order:
    J_r^-1 = I + [v]x / 2 + (1 / t^2 - (1 + cos t) / (2 t sin t)) [v]x^2.
    """
    v = np.asarray(v, float)
    t2 = sum_sq(v)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    c = np.where(small, 1.0 / 12.0 + t2 / 720.0,
                 1.0 / ts ** 2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    return _so3_series(v, 0.5, c, t2)


def quat_to_rotvec(q):
    """Return rotation vectors (..., 3) of unit quaternions (..., 4) (angle <= pi)."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = _norm(q[..., 1:])
    ang = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return scale * q[..., 1:]


def integrate_batch(increments):
    """Return the ordered products of rotation-vector increments, one per row.

    increments: (k, n, 3) body-frame rotation vectors (zero-padded rows are identities);
    returns (k, 4) quaternions of dR = exp(inc_0) exp(inc_1) ... exp(inc_{n-1}).
    """
    return integrate_quaternions(quat_from_rotvec(increments))


def integrate_quaternions(q):
    """Return the (k, 4) ordered products of (k, n, 4) unit quaternions along axis 1.

    A pairwise tree product (``integrate_batch`` on the increments' quaternions).
    """
    n = q.shape[1]
    size = 1 << max(int(np.ceil(np.log2(max(n, 1)))), 0)
    if size > n:
        pad = np.zeros((q.shape[0], size - n, 4))
        pad[..., 0] = 1.0
        q = np.concatenate([q, pad], axis=1)
    while q.shape[1] > 1:
        q = quat_mul(q[:, 0::2], q[:, 1::2])
    return q[:, 0] / _norm(q[:, 0])


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
    return q / _norm(q)


def quat_to_matrix(q):
    """Return (..., 3, 3) rotation matrices of unit quaternions (..., 4) (w, x, y, z).

    R = [[1 - 2(y^2 + z^2), 2(xy - wz), 2(xz + wy)], [2(xy + wz), 1 - 2(x^2 + z^2),
    2(yz - wx)], [2(xz - wy), 2(yz + wx), 1 - 2(x^2 + y^2)]].
    """
    q = np.asarray(q, float)
    r = _outer(q, q) @ _ROTATION
    r[..., 0::4] += 1.0
    return r.reshape(q.shape[:-1] + (3, 3))
