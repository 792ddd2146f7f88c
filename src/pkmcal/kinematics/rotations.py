"""Rotations, batch first: every function takes arrays of shape ``(..., 3)`` or ``(..., 3, 3)``.

Conventions (SPEC 1, seed 000 section 2): the platform orientation is
``R = RY(theta) @ RX(psi) @ RZ(phi)`` and a pose vector is ``[px, py, pz, psi, theta, phi]``.
Small orientation changes are rotation vectors ``dOmega`` about the *base* axes, applied on the
left: ``R_new = exp(dOmega) @ R``. Quaternions are stored scalar-last ``(qx, qy, qz, qw)``, as in
the CSV files.
"""

from __future__ import annotations

import numpy as np


def rot_x(angle):
    """Rotation about X by ``angle``.

    Parameters
    ----------
    angle : array_like, shape (...)
        Angle, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def rot_y(angle):
    """Rotation about Y by ``angle``.

    Parameters
    ----------
    angle : array_like, shape (...)
        Angle, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def rot_z(angle):
    """Rotation about Z by ``angle``.

    Parameters
    ----------
    angle : array_like, shape (...)
        Angle, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def matrix_from_euler(angles):
    """``R = RY(theta) RX(psi) RZ(phi)`` from Euler angles.

    Parameters
    ----------
    angles : array_like, shape (..., 3)
        ``[psi, theta, phi]``, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    angles = np.asarray(angles, dtype=float)
    psi, theta, phi = angles[..., 0], angles[..., 1], angles[..., 2]
    cps, sps = np.cos(psi), np.sin(psi)
    cth, sth = np.cos(theta), np.sin(theta)
    cph, sph = np.cos(phi), np.sin(phi)
    R = np.empty(angles.shape[:-1] + (3, 3))
    R[..., 0, 0] = cth * cph + sth * sps * sph
    R[..., 0, 1] = -cth * sph + sth * sps * cph
    R[..., 0, 2] = sth * cps
    R[..., 1, 0] = cps * sph
    R[..., 1, 1] = cps * cph
    R[..., 1, 2] = -sps
    R[..., 2, 0] = -sth * cph + cth * sps * sph
    R[..., 2, 1] = sth * sph + cth * sps * cph
    R[..., 2, 2] = cth * cps
    return R


def euler_from_matrix(R):
    """Inverse of :func:`matrix_from_euler`: ``[psi, theta, phi]`` with ``psi`` in [-pi/2, pi/2].

    Singular at ``psi = +/-90 deg`` (gimbal lock), where ``theta + phi`` alone is defined.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[psi, theta, phi]``, rad; ``theta`` and ``phi`` in [-pi, pi].
    """
    R = np.asarray(R, dtype=float)
    psi = np.arcsin(np.clip(-R[..., 1, 2], -1.0, 1.0))
    theta = np.arctan2(R[..., 0, 2], R[..., 2, 2])
    phi = np.arctan2(R[..., 1, 0], R[..., 1, 1])
    return np.stack([psi, theta, phi], -1)


def skew(v):
    """Cross-product matrix ``[v]x`` with ``skew(v) @ w == cross(v, w)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Vectors.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Skew-symmetric matrices.
    """
    v = np.asarray(v, dtype=float)
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    out = np.zeros(v.shape[:-1] + (3, 3))   # filled in place: nested stacks cost ~3x more
    out[..., 0, 1], out[..., 0, 2] = -w, y
    out[..., 1, 0], out[..., 1, 2] = w, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def matrix_from_rotvec(v):
    """Rodrigues: rotation matrix of a rotation vector, angle = ``|v|``.

    Small angles use series expansions, so the result keeps full precision near zero.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Rotation vectors (axis times angle), rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    v = np.asarray(v, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    theta2 = x * x + y * y + z * z
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # series for small angles keep full precision
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2**2 / 120.0, np.sin(safe) / safe)
    # (1 - cos t) / t^2 = 2 sin^2(t/2) / t^2, free of the cancellation in 1 - cos t
    half = np.sin(0.5 * safe) / safe
    b = np.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0, 2.0 * half * half)
    # I + a [v]x + b [v]x^2 with [v]x^2 = v v^T - |v|^2 I, written out element by element
    c = 1.0 - b * theta2
    bx, by, bz = b * x, b * y, b * z
    ax, ay, az = a * x, a * y, a * z
    R = np.empty(v.shape[:-1] + (3, 3))
    R[..., 0, 0] = c + bx * x
    R[..., 0, 1] = bx * y - az
    R[..., 0, 2] = bx * z + ay
    R[..., 1, 0] = bx * y + az
    R[..., 1, 1] = c + by * y
    R[..., 1, 2] = by * z - ax
    R[..., 2, 0] = bx * z - ay
    R[..., 2, 1] = by * z + ax
    R[..., 2, 2] = c + bz * z
    return R


def rotvec_from_matrix(R):
    """Rotation vector of a rotation matrix; angle in [0, pi].

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vectors, rad.
    """
    R = np.asarray(R, dtype=float)
    return rotvec_from_quaternion(quaternion_from_matrix(R))


def _columns(*cols):
    """``np.stack(cols, -1)`` of equally shaped arrays, filled in place (cheaper)."""
    out = np.empty(np.shape(cols[0]) + (len(cols),))
    for i, c in enumerate(cols):
        out[..., i] = c
    return out


def quaternion_from_matrix(R):
    """Unit quaternion ``(qx, qy, qz, qw)`` with ``qw >= 0`` from a rotation matrix.

    Uses the largest of the four candidate denominators (Shepperd) for full precision.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 4)
        Quaternions, scalar last.
    """
    R = np.asarray(R, dtype=float)
    tr = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    cand = _columns(tr, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2])
    k = np.argmax(cand, -1)
    q = np.empty(R.shape[:-2] + (4,))
    # case qw largest
    s = np.sqrt(np.maximum(1.0 + cand[..., 0], 1e-300)) * 2
    qa = _columns((R[..., 2, 1] - R[..., 1, 2]) / s, (R[..., 0, 2] - R[..., 2, 0]) / s,
                  (R[..., 1, 0] - R[..., 0, 1]) / s, 0.25 * s)
    s = np.sqrt(np.maximum(1.0 + R[..., 0, 0] - R[..., 1, 1] - R[..., 2, 2], 1e-300)) * 2
    qb = _columns(0.25 * s, (R[..., 0, 1] + R[..., 1, 0]) / s, (R[..., 0, 2] + R[..., 2, 0]) / s,
                  (R[..., 2, 1] - R[..., 1, 2]) / s)
    s = np.sqrt(np.maximum(1.0 - R[..., 0, 0] + R[..., 1, 1] - R[..., 2, 2], 1e-300)) * 2
    qc = _columns((R[..., 0, 1] + R[..., 1, 0]) / s, 0.25 * s, (R[..., 1, 2] + R[..., 2, 1]) / s,
                  (R[..., 0, 2] - R[..., 2, 0]) / s)
    s = np.sqrt(np.maximum(1.0 - R[..., 0, 0] - R[..., 1, 1] + R[..., 2, 2], 1e-300)) * 2
    qd = _columns((R[..., 0, 2] + R[..., 2, 0]) / s, (R[..., 1, 2] + R[..., 2, 1]) / s, 0.25 * s,
                  (R[..., 1, 0] - R[..., 0, 1]) / s)
    q = np.where((k == 0)[..., None], qa,
                 np.where((k == 1)[..., None], qb, np.where((k == 2)[..., None], qc, qd)))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def matrix_from_quaternion(q):
    """Rotation matrix from a quaternion ``(qx, qy, qz, qw)``; the quaternion is normalised first.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions, scalar last (any non-zero norm).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotvec_from_quaternion(q):
    """Rotation vector from a quaternion ``(qx, qy, qz, qw)``; angle in [0, pi].

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions, scalar last (``q`` and ``-q`` give the same result).

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vectors, rad.
    """
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:4] < 0, -q, q)
    v = q[..., :3]
    sin_half = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(sin_half, q[..., 3])
    small = sin_half < 1e-12
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, sin_half))
    return v * scale[..., None]


def rotation_angle(R):
    """Angle of a rotation, accurate for tiny angles.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (...)
        Rotation angles in [0, pi], rad.
    """
    return np.linalg.norm(rotvec_from_matrix(R), axis=-1)


def kabsch(source, target, weights=None):
    """Rotation ``G`` minimising ``sum w |G @ source_k - target_k|^2`` (no translation), via SVD.

    Parameters
    ----------
    source : array_like, shape (K, 3)
        Points to rotate.
    target : array_like, shape (K, 3)
        Points to match.
    weights : array_like, shape (K,), optional
        Non-negative weight of each pair; default 1.

    Returns
    -------
    ndarray, shape (3, 3)
        A proper rotation (det = +1).
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    H = (source * w[:, None]).T @ target
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d])
    return Vt.T @ D @ U.T
