"""Rigid transforms, one convention for the whole project.

Convention: ``T_a_b`` is a (4, 4) homogeneous matrix, the pose of frame ``b`` expressed in
frame ``a``; it maps points given in ``b`` into ``a``: ``p_a = T_a_b @ p_b``. It composes
like ``T_a_c = T_a_b @ T_b_c`` (pinocchio's ``oMi`` reads the same way). Lengths are metres,
angles radians, quaternions (x, y, z, w) as in geometry_msgs.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


class _Rotation:
    """scipy.spatial.transform.Rotation, imported on first use: importing scipy.spatial takes
    0.2 s, paid by every node and command process that imports a module using Rotation."""

    def __getattr__(self, name: str):
        from scipy.spatial.transform import Rotation
        return getattr(Rotation, name)


Rotation = _Rotation()


def make_transform(rotation: ArrayLike, translation: ArrayLike) -> Array:
    """(3, 3) rotation and (3,) translation [m] -> (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def invert(T: Array) -> Array:
    """Inverse of a rigid (4, 4) transform (or a stack (..., 4, 4))."""
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    Ti = np.zeros_like(T)
    Ti[..., :3, :3] = R
    Ti[..., :3, 3] = -(R @ T[..., :3, 3, None])[..., 0]
    Ti[..., 3, 3] = 1.0
    return Ti


def apply(T: Array, points: ArrayLike) -> Array:
    """Map (N, 3) or (3,) points [m] through T."""
    p = np.asarray(points, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]


def rot_x(angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> Array:
    """URDF convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def from_xyz_rpy(xyz: ArrayLike, rpy: ArrayLike) -> Array:
    return make_transform(rpy_to_matrix(*rpy), xyz)


def from_pose(position: ArrayLike, quaternion_xyzw: ArrayLike) -> Array:
    return make_transform(Rotation.from_quat(quaternion_xyzw).as_matrix(), position)


def to_pose(T: Array) -> tuple[Array, Array]:
    """(4, 4) -> position (3,) [m], quaternion (x, y, z, w)."""
    return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_quat()


def from_vector(xyz_rotvec: ArrayLike) -> Array:
    """(x, y, z, rx, ry, rz) with a rotation vector [m, rad] -> (4, 4)."""
    v = np.asarray(xyz_rotvec, dtype=float)
    return make_transform(Rotation.from_rotvec(v[3:]).as_matrix(), v[:3])


def to_vector(T: Array) -> Array:
    """(4, 4) -> (x, y, z, rx, ry, rz) with a rotation vector [m, rad]."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def rotation_angle(R: ArrayLike) -> float:
    """Angle [rad] in [0, pi] of a rotation matrix (its rotation vector's norm), accurate near
    0 and pi: atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2)."""
    R = np.asarray(R, dtype=float)[:3, :3]
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return abs(math.atan2(float(np.linalg.norm(axis)) / 2.0, (float(np.trace(R)) - 1.0) / 2.0))


def transform_error(T_est: Array, T_true: Array) -> tuple[float, float]:
    """Translation [m] and rotation [rad] between two poses of the same frame."""
    return (float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            rotation_angle(T_true[:3, :3].T @ T_est[:3, :3]))


def skew(v: ArrayLike) -> Array:
    """Cross-product matrix [v]x of a (3,) vector, or (..., 3, 3) of a stack (..., 3):
    skew(a) @ b == cross(a, b)."""
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:
        return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def kabsch_rotation(a: ArrayLike, b: ArrayLike) -> Array:
    """The rotation R minimising sum |R a_i - b_i|^2 over (n, 3) vectors (not centred here),
    det R = +1 even when the vectors are coplanar (Kabsch)."""
    U, _, Vt = np.linalg.svd(np.asarray(a, dtype=float).T @ np.asarray(b, dtype=float))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def kabsch(p_from: ArrayLike, p_to: ArrayLike) -> Array:
    """Least-squares rigid (4, 4) T with p_to ~ T p_from for (n, 3) points [m] (Kabsch),
    det R = +1 even for coplanar points: T_base_user from user and base points."""
    pf, pt = np.asarray(p_from, dtype=float), np.asarray(p_to, dtype=float)
    cf, ct = pf.sum(axis=0) / len(pf), pt.sum(axis=0) / len(pt)   # (.mean: slow at N ~ 5)
    R = kabsch_rotation(pf - cf, pt - ct)
    return make_transform(R, ct - R @ cf)
