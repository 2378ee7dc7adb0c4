"""Quaternion and rotation kernels (scalar-last ``[x, y, z, w]``, scipy's Hamilton convention).

All functions are Numba-compiled and match :mod:`scipy.spatial.transform` exactly in meaning:
``quat_to_dcm(q) == Rotation.from_quat(q).as_matrix()``, ``quat_mul(q, p) == (R(q) * R(p)).as_quat()``
(up to the sign of the quaternion), ``rotvec_to_quat(phi) == Rotation.from_rotvec(phi).as_quat()``.
Functions with an ``out`` argument write into it and allocate nothing. Also the body-frame
attitude step of the filter (:func:`apply_body_rotation`, :func:`apply_body_quat`: the body turned
by a body-axes rotation vector) and the SO(3) left Jacobian (:func:`left_jacobian`).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel


@kernel
def quat_mul_into(q, p, out):
    """out = q ⊗ p (Hamilton; the rotation ``R(q) @ R(p)``). q, p, out: (4,) scalar-last."""
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    px, py, pz, pw = p[0], p[1], p[2], p[3]
    x = qw * px + qx * pw + qy * pz - qz * py
    y = qw * py - qx * pz + qy * pw + qz * px
    z = qw * pz + qx * py - qy * px + qz * pw
    w = qw * pw - qx * px - qy * py - qz * pz
    out[0] = x
    out[1] = y
    out[2] = z
    out[3] = w


@kernel
def quat_mul(q, p):
    """Return q ⊗ p as a new (4,) array (see :func:`quat_mul_into`)."""
    out = np.empty(4)
    quat_mul_into(q, p, out)
    return out


@kernel
def quat_conj(q):
    """Inverse of a unit quaternion: (4,) → (4,)."""
    out = np.empty(4)
    out[0] = -q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = q[3]
    return out


@kernel
def quat_normalize_inplace(q):
    """Normalize q in place to unit norm with w ≥ 0. Returns 0, or 3 if q is zero or non-finite."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if not (n > 0.0) or not math.isfinite(n):
        return 3
    s = 1.0 / n
    if q[3] < 0.0:
        s = -s
    for i in range(4):
        q[i] *= s
    return 0


@kernel
def quat_to_dcm_into(q, out):
    """Rotation matrix of unit quaternion q (4,) into out (3, 3); equals scipy's as_matrix()."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@kernel
def quat_to_dcm(q):
    """Rotation matrix (3, 3) of unit quaternion q (4,)."""
    out = np.empty((3, 3))
    quat_to_dcm_into(q, out)
    return out


@kernel
def dcm_to_quat(m):
    """Unit quaternion (4,), w ≥ 0, of a rotation matrix (3, 3) (Shepperd's method)."""
    q = np.empty(4)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr >= m[0, 0] and tr >= m[1, 1] and tr >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[3] = 0.25 * s
        q[0] = (m[2, 1] - m[1, 2]) / s
        q[1] = (m[0, 2] - m[2, 0]) / s
        q[2] = (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q[0] = 0.25 * s
        q[3] = (m[2, 1] - m[1, 2]) / s
        q[1] = (m[0, 1] + m[1, 0]) / s
        q[2] = (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q[1] = 0.25 * s
        q[3] = (m[0, 2] - m[2, 0]) / s
        q[0] = (m[0, 1] + m[1, 0]) / s
        q[2] = (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q[2] = 0.25 * s
        q[3] = (m[1, 0] - m[0, 1]) / s
        q[0] = (m[0, 2] + m[2, 0]) / s
        q[1] = (m[1, 2] + m[2, 1]) / s
    quat_normalize_inplace(q)
    return q


@kernel
def rotvec_to_quat_into(phi, out):
    """Quaternion (4,) of rotation vector phi (3,) [rad], exact for any angle; writes out."""
    a2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    a = math.sqrt(a2)
    if a < 1e-6:
        # Taylor series of sin(a/2)/a and cos(a/2); error below 1e-26 for a < 1e-6.
        s = 0.5 - a2 / 48.0
        c = 1.0 - a2 / 8.0
    else:
        s = math.sin(0.5 * a) / a
        c = math.cos(0.5 * a)
    out[0] = s * phi[0]
    out[1] = s * phi[1]
    out[2] = s * phi[2]
    out[3] = c


@kernel
def rotvec_to_quat(phi):
    """Quaternion (4,) of rotation vector phi (3,) [rad]."""
    out = np.empty(4)
    rotvec_to_quat_into(phi, out)
    return out


@kernel
def quat_to_rotvec(q):
    """Rotation vector (3,) [rad], angle in [0, π], of unit quaternion q (4,)."""
    out = np.empty(3)
    x, y, z, w = q[0], q[1], q[2], q[3]
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    sn = math.sqrt(x * x + y * y + z * z)
    a = 2.0 * math.atan2(sn, w)
    if sn < 1e-7:
        k = 2.0 / w * (1.0 - sn * sn / (3.0 * w * w))  # a/sn = 2 atan(sn/w)/sn to third order
    else:
        k = a / sn
    out[0] = k * x
    out[1] = k * y
    out[2] = k * z
    return out


@kernel
def rotvec_to_dcm(phi):
    """Rotation matrix (3, 3) of rotation vector phi (3,) [rad]; equals scipy from_rotvec().as_matrix()."""
    return quat_to_dcm(rotvec_to_quat(phi))


@kernel
def quat_rotate(q, v):
    """v' = R(q) @ v for unit quaternion q (4,) and vector v (3,)."""
    m = quat_to_dcm(q)
    out = np.empty(3)
    for i in range(3):
        out[i] = m[i, 0] * v[0] + m[i, 1] * v[1] + m[i, 2] * v[2]
    return out


@kernel
def skew(v):
    """Cross-product matrix [v×] (3, 3) so that skew(v) @ u == cross(v, u)."""
    m = np.zeros((3, 3))
    m[0, 1] = -v[2]
    m[0, 2] = v[1]
    m[1, 0] = v[2]
    m[1, 2] = -v[0]
    m[2, 0] = -v[1]
    m[2, 1] = v[0]
    return m


@kernel
def apply_body_rotation(q, theta, work4, dq):
    """q_body_from_inertial ← R(theta)ᵀ ∘ q: the body turned by theta (3,) [rad, body axes]."""
    rotvec_to_quat_into(theta, dq)
    apply_body_quat(q, dq, work4)


@kernel
def apply_body_quat(q, dq, work4):
    """:func:`apply_body_rotation` with the quaternion dq (4,) of R(theta) already computed (dq
    is conjugated in place); work4 (4,) work."""
    dq[0], dq[1], dq[2] = -dq[0], -dq[1], -dq[2]
    quat_mul_into(dq, q, work4)
    for k in range(4):
        q[k] = work4[k]
    quat_normalize_inplace(q)


@kernel
def left_jacobian(phi):
    """SO(3) left Jacobian J_l(phi) (3, 3): exp([(phi+δ)×]) ≈ exp([J_l δ ×]) exp([phi×])."""
    a = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 0] = -phi[2], phi[1], phi[2]
    K[1, 2], K[2, 0], K[2, 1] = -phi[0], -phi[1], phi[0]
    c1, c2 = (0.5, 0.0) if a < 1e-8 else ((1.0 - math.cos(a)) / (a * a), (a - math.sin(a)) / (a ** 3))
    J = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            kk = K[r, 0] * K[0, c] + K[r, 1] * K[1, c] + K[r, 2] * K[2, c]
            J[r, c] = (1.0 if r == c else 0.0) + c1 * K[r, c] + c2 * kk
    return J
