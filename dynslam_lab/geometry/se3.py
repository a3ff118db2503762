"""SE(3) poses as 4x4 matrices, with frame-explicit names.

Convention: ``T_a_b`` maps points from frame ``b`` to frame ``a``: ``X_a = T_a_b @ X_b``.
``T_w_c`` is a camera pose (camera to world), ``T_c_w`` its inverse. Quaternions are in
the TUM file order ``(qx, qy, qz, qw)`` (scipy's default); the viser view converts to
``wxyz`` in one place (``viz/viser_scene.py``).

Every function accepts a single pose ``(4, 4)`` or a stack ``(N, 4, 4)`` where noted.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "make_pose",
    "se3_inv",
    "transform_points",
    "relative_pose",
    "quat_xyzw_to_matrix",
    "matrix_to_quat_xyzw",
    "pose_from_tum",
    "pose_to_tum",
    "skew",
    "so3_exp",
    "so3_log",
    "rotation_angle_deg",
    "nearest_rotation",
]


def make_pose(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """Build a 4x4 pose from rotation ``R (3, 3)`` and translation ``t (3,)``."""
    T = np.eye(4)
    if R is not None:
        R = np.asarray(R, dtype=np.float64)
        if R.shape != (3, 3):
            raise ValueError(f"make_pose: R must be (3, 3), got {R.shape}")
        T[:3, :3] = R
    if t is not None:
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        if t.shape != (3,):
            raise ValueError(f"make_pose: t must have 3 elements, got {t.shape}")
        T[:3, 3] = t
    return T


def se3_inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a pose ``(4, 4)`` or stack ``(N, 4, 4)``: ``[R^T, -R^T t]``."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"se3_inv expects (..., 4, 4), got {T.shape}")
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def transform_points(T_a_b: np.ndarray, X_b: np.ndarray) -> np.ndarray:
    """Map points ``(N, 3)`` from frame b to frame a with ``T_a_b (4, 4)``."""
    X_b = np.asarray(X_b, dtype=np.float64)
    if X_b.ndim != 2 or X_b.shape[1] != 3:
        raise ValueError(f"transform_points expects points (N, 3), got {X_b.shape}")
    T_a_b = np.asarray(T_a_b, dtype=np.float64)
    return X_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def relative_pose(T_w_a: np.ndarray, T_w_b: np.ndarray) -> np.ndarray:
    """``T_a_b = T_w_a^-1 T_w_b``: pose of b seen from a (works on stacks)."""
    return se3_inv(T_w_a) @ np.asarray(T_w_b, dtype=np.float64)


def quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) ``(..., 4)`` in x, y, z, w order to rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ValueError(f"quaternion must have 4 components (x, y, z, w), got shape {q.shape}")
    norms = np.linalg.norm(q, axis=-1)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-8):
        raise ValueError("quaternion with zero or non-finite norm")
    x, y, z, w = np.moveaxis(q / norms[..., None], -1, 0)  # normalised, as scipy does
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


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to quaternions ``(..., 4)`` (x, y, z, w), ``w >= 0``.

    Shepperd's method: of the four ways to read the quaternion off the matrix, each row uses
    the one whose leading component (``w`` from the trace, or ``x``/``y``/``z`` from a
    diagonal entry) is largest, so no division by a small number happens near 180 degrees.
    Plain numpy (no scipy import on the viewer's start-up path); tested against scipy.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"matrix_to_quat_xyzw expects (..., 3, 3), got {R.shape}")
    M = R.reshape(-1, 3, 3)
    m00, m01, m02 = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    m10, m11, m12 = M[:, 1, 0], M[:, 1, 1], M[:, 1, 2]
    m20, m21, m22 = M[:, 2, 0], M[:, 2, 1], M[:, 2, 2]
    # 4 * (x, y, z, w) * (leading component), one candidate per choice of leading component
    cand = np.stack([
        np.stack([1 + m00 - m11 - m22, m01 + m10, m02 + m20, m21 - m12], axis=-1),  # x leads
        np.stack([m01 + m10, 1 - m00 + m11 - m22, m12 + m21, m02 - m20], axis=-1),  # y leads
        np.stack([m02 + m20, m12 + m21, 1 - m00 - m11 + m22, m10 - m01], axis=-1),  # z leads
        np.stack([m21 - m12, m02 - m20, m10 - m01, 1 + m00 + m11 + m22], axis=-1),  # w leads
    ], axis=1)
    lead = np.argmax(np.stack([m00, m11, m22, m00 + m11 + m22], axis=-1), axis=-1)
    q = cand[np.arange(len(M)), lead]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def pose_from_tum(txyz_qxyzw: np.ndarray) -> np.ndarray:
    """``(..., 7)`` rows ``tx ty tz qx qy qz qw`` to poses ``(..., 4, 4)``."""
    a = np.asarray(txyz_qxyzw, dtype=np.float64)
    if a.shape[-1] != 7:
        raise ValueError(f"TUM pose rows need 7 values (tx ty tz qx qy qz qw), got shape {a.shape}")
    flat = a.reshape(-1, 7)
    T = np.tile(np.eye(4), (len(flat), 1, 1))
    T[:, :3, :3] = quat_xyzw_to_matrix(flat[:, 3:])
    T[:, :3, 3] = flat[:, :3]
    return T.reshape(a.shape[:-1] + (4, 4))


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """Poses ``(..., 4, 4)`` to rows ``tx ty tz qx qy qz qw`` ``(..., 7)``."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[..., :3, 3], matrix_to_quat_xyzw(T[..., :3, :3])], axis=-1)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]_x (..., 3, 3)`` of vectors ``(..., 3)``: ``[v]_x w = v x w``."""
    v = np.asarray(v, dtype=np.float64)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _cv2():
    import cv2  # here, as scipy above: reading poses needs neither

    return cv2


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation vector(s) ``(..., 3)`` (radians) to matrices ``(..., 3, 3)`` (Rodrigues)."""
    omega = np.asarray(omega, dtype=np.float64)
    if omega.shape == (3,):  # one rotation (the solvers' steps): OpenCV's Rodrigues, ~20x faster than scipy's
        return _cv2().Rodrigues(omega)[0]
    from scipy.spatial.transform import Rotation  # here: the viewer reads poses without loading scipy

    return Rotation.from_rotvec(omega.reshape(-1, 3)).as_matrix().reshape(omega.shape[:-1] + (3, 3))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to rotation vectors ``(..., 3)`` (radians)."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape == (3, 3):  # one rotation: OpenCV's Rodrigues (same vector up to rounding)
        return _cv2().Rodrigues(R)[0].reshape(3)
    from scipy.spatial.transform import Rotation  # here: the viewer reads poses without loading scipy

    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle of rotation(s) ``(..., 3, 3)`` in degrees, from the trace (clipped to [-1, 1])."""
    R = np.asarray(R, dtype=np.float64)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation closest to ``R (3, 3)`` in the Frobenius norm (SVD, with ``det = +1``), so that
    products of poses cannot drift away from SO(3)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt
