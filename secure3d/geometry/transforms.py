"""Rotations, quaternions and the camera mounting chain.

Frames: world is z-up; the body frame has x forward, y left, z up; the camera optical frame follows
OpenCV (z forward, x right, y down). Quaternions are ``(w, x, y, z)`` (scalar first, Hamilton
product), as in the quadrotor's state; **scipy's ``Rotation.from_quat`` and Rerun's
``Quaternion(xyzw=...)`` take ``(x, y, z, w)``**: reorder with ``q[[1, 2, 3, 0]]`` (ours to theirs)
and ``q[[3, 0, 1, 2]]`` (theirs to ours). Functions marked "numpy or CasADi" share one body through :mod:`.backend`; their numpy
versions broadcast over leading batch dimensions.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from secure3d.errors import GeometryError
from secure3d.geometry import backend as B
from secure3d.geometry.backend import ArrayOrSym

#: Largest ``max |R^T R - I|`` accepted by :func:`check_rotation`. Loose enough for rotations that
#: went through float32 or a few products, tight enough to reject scaled or sheared matrices.
ROTATION_TOL = 1e-6

#: Columns are the optical x, y, z axes expressed in the body frame (x forward, y left, z up):
#: optical x (image right) = -body y, optical y (image down) = -body z, optical z = body x.
BODY_FROM_OPTICAL = np.array(
    [
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ]
)
BODY_FROM_OPTICAL.setflags(write=False)


def yaw_matrix(yaw: ArrayOrSym) -> ArrayOrSym:
    """Rotation about the world z axis by ``yaw`` (rad), numpy or CasADi.

    Parameters
    ----------
    yaw : float, (...,) float array, or CasADi scalar

    Returns
    -------
    (..., 3, 3) float array, or CasADi 3x3.
    """
    c, s = B.cos(yaw), B.sin(yaw)
    return B.block([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pitch_matrix(pitch: ArrayOrSym) -> ArrayOrSym:
    """Rotation about the body y axis by ``pitch`` (rad), numpy or CasADi.

    The body y axis points left, so a positive pitch turns body x toward -z: the nose goes DOWN
    (a camera with ``mount_pitch > 0`` looks below the horizon).

    Returns
    -------
    (..., 3, 3) float array, or CasADi 3x3.
    """
    c, s = B.cos(pitch), B.sin(pitch)
    return B.block([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def camera_rotation(body2world_R: ArrayOrSym, mount_pitch: ArrayOrSym) -> ArrayOrSym:
    """World-from-optical rotation of a camera pitched by ``mount_pitch`` on the body, numpy or
    CasADi: ``body2world_R @ pitch_matrix(mount_pitch) @ BODY_FROM_OPTICAL``.

    Parameters
    ----------
    body2world_R : (..., 3, 3) float or CasADi 3x3
        Body-to-world rotation.
    mount_pitch : float or CasADi scalar
        Downward pitch of the optical axis relative to body x (rad).

    Returns
    -------
    (..., 3, 3) float, or CasADi 3x3: its columns are the optical axes in the world frame.
    """
    return B.matmul(B.matmul(body2world_R, pitch_matrix(mount_pitch)), BODY_FROM_OPTICAL)


def quat_to_matrix(q: ArrayOrSym) -> ArrayOrSym:
    """Rotation matrix of the quaternion ``q = (w, x, y, z)``, numpy or CasADi.

    The numpy version normalises ``q`` first (and rejects a zero or non-finite ``q``); the CasADi
    version uses ``q`` as given, so the optimiser must keep it unit (a constraint or a dynamics
    invariant).

    Parameters
    ----------
    q : (..., 4) float, or CasADi (4, 1)

    Returns
    -------
    (..., 3, 3) float, or CasADi 3x3.
    """
    if not B.is_symbolic(q):
        q = np.asarray(q, dtype=float)
        if q.shape[-1:] != (4,):
            raise GeometryError(f"quaternion: expected shape (..., 4), got {q.shape}")
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        if not np.all(np.isfinite(q)) or np.any(n < 1e-12):
            raise GeometryError("quaternion: must be finite and non-zero")
        q = q / n
        if q.ndim == 1:  # one rotation: the same products on floats, without the batch machinery
            return np.array(_quat_entries(*q.tolist()))
    return B.block(_quat_entries(*(B.component(q, i) for i in range(4))))


def _quat_entries(w: Any, x: Any, y: Any, z: Any) -> list[list[Any]]:
    """The rotation matrix of the unit quaternion (w, x, y, z), row by row, in whatever the
    components are (floats, numpy arrays of a batch, CasADi scalars)."""
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def check_rotation(R: object, tol: float = ROTATION_TOL) -> np.ndarray:
    """Validate rotation matrices and return them re-orthonormalised.

    Parameters
    ----------
    R : (..., 3, 3) array-like
    tol : float
        Largest accepted ``max |R^T R - I|``.

    Returns
    -------
    (..., 3, 3) float: the nearest proper rotation (polar factor), equal to ``R`` up to ``tol``.

    Raises
    ------
    GeometryError
        Wrong shape, non-finite entries, not orthonormal within ``tol``, or a reflection.
    """
    try:
        R = np.asarray(R, dtype=float)
    except (TypeError, ValueError):
        raise GeometryError(f"rotation: expected a (3, 3) array, got {R!r}") from None
    if R.shape[-2:] != (3, 3):
        raise GeometryError(f"rotation: expected shape (..., 3, 3), got {R.shape}")
    if not np.all(np.isfinite(R)):
        raise GeometryError("rotation: entries must be finite")
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0)
    if err > tol:
        raise GeometryError(f"rotation: not orthonormal, max |R^T R - I| = {err:.3g} > {tol:g}")
    if np.any(np.linalg.det(R) <= 0):
        raise GeometryError("rotation: determinant must be +1 (got a reflection)")
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def matrix_to_quat(R: object) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0`` of rotation matrices (numpy).

    Shepperd's method: each matrix uses the best conditioned of the four closed forms.

    Parameters
    ----------
    R : (..., 3, 3) array-like, validated with :func:`check_rotation`.

    Returns
    -------
    (..., 4) float
    """
    R = check_rotation(R)
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    d21, d02, d10 = (
        R[..., 2, 1] - R[..., 1, 2],
        R[..., 0, 2] - R[..., 2, 0],
        R[..., 1, 0] - R[..., 0, 1],
    )
    s01, s02, s12 = (
        R[..., 0, 1] + R[..., 1, 0],
        R[..., 0, 2] + R[..., 2, 0],
        R[..., 1, 2] + R[..., 2, 1],
    )
    radicands = np.stack(
        [1 + r00 + r11 + r22, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22], -1
    )
    best = np.argmax(radicands, axis=-1)
    # The chosen radicand is >= 1 for a rotation (the four sum to 4), so dividing by it is safe.
    big = 0.5 * np.sqrt(np.take_along_axis(radicands, best[..., None], -1)[..., 0])
    k = 0.25 / big
    candidates = np.stack(
        [
            np.stack([big, d21 * k, d02 * k, d10 * k], -1),
            np.stack([d21 * k, big, s01 * k, s02 * k], -1),
            np.stack([d02 * k, s01 * k, big, s12 * k], -1),
            np.stack([d10 * k, s02 * k, s12 * k, big], -1),
        ],
        -2,
    )
    q = np.take_along_axis(candidates, best[..., None, None], -2)[..., 0, :]
    q = np.where(q[..., :1] < 0, -q, q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_multiply(q1: object, q2: object) -> np.ndarray:
    """Hamilton product ``q1 * q2`` (rotation ``q2`` first, then ``q1``), numpy.

    Parameters
    ----------
    q1, q2 : (..., 4) array-like, broadcast against each other.

    Returns
    -------
    (..., 4) float
    """
    q1, q2 = np.asarray(q1, dtype=float), np.asarray(q2, dtype=float)
    if q1.shape[-1:] != (4,) or q2.shape[-1:] != (4,):
        raise GeometryError(f"quat_multiply: expected (..., 4) arrays, got {q1.shape}, {q2.shape}")
    w1, v1 = q1[..., :1], q1[..., 1:]
    w2, v2 = q2[..., :1], q2[..., 1:]
    w = w1 * w2 - np.sum(v1 * v2, axis=-1, keepdims=True)
    v = w1 * v2 + w2 * v1 + np.cross(v1, v2)
    return np.concatenate([w, v], axis=-1)


def quat_from_yaw(yaw: object) -> np.ndarray:
    """Quaternion of a rotation by ``yaw`` (rad) about world z, numpy: ``(..., 4)``."""
    half = 0.5 * np.asarray(yaw, dtype=float)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)


def quat_from_axis_angle(axis: object, angle: object) -> np.ndarray:
    """Quaternion of a rotation by ``angle`` (rad) about ``axis`` (any non-zero length), numpy.

    Parameters
    ----------
    axis : (..., 3) array-like
    angle : (...,) array-like

    Returns
    -------
    (..., 4) float
    """
    axis = np.asarray(axis, dtype=float)
    if axis.shape[-1:] != (3,):
        raise GeometryError(f"axis: expected shape (..., 3), got {axis.shape}")
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    if not np.all(np.isfinite(axis)) or np.any(n < 1e-12):
        raise GeometryError(f"axis: must be finite and non-zero, got {axis.tolist()}")
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis / n], axis=-1)
