"""Rigid transforms, one convention for the whole project.

Convention: ``T_a_b`` is a (4, 4) homogeneous matrix, the pose of frame ``b`` expressed in
frame ``a``; it maps points given in ``b`` into ``a``: ``p_a = T_a_b @ p_b``. It composes
like ``T_a_c = T_a_b @ T_b_c`` (pinocchio's ``oMi`` reads the same way). Lengths are metres,
angles radians, quaternions (x, y, z, w) as in geometry_msgs.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]


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


def transform_error(T_est: Array, T_true: Array) -> tuple[float, float]:
    """Translation [m] and rotation [rad] between two poses of the same frame."""
    dT = invert(T_true) @ T_est
    angle = float(np.linalg.norm(Rotation.from_matrix(dT[:3, :3]).as_rotvec()))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), angle
