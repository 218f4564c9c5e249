"""Pose estimators of the methods: (p_user, p_base) -> (4, 4) map user -> base [m].

``three_point`` is the paper's eqs 3-5 (section 2.1), ``five_point_lsq`` its eqs 6-8 (section
2.2, the affine M; its pose is the nearest rotation), ``rigid`` and ``robust`` Kabsch/Umeyama.
"""
from __future__ import annotations

import numpy as np

from cobot_calib_ros.core.frames import kabsch, make_transform
from cobot_calib_ros.core.user_frame.geometry import Array, Estimator

METHODS = ('three_point', 'five_point_lsq', 'rigid', 'robust')
DEFAULT_METHOD = 'rigid'
PLANAR_TOL = 1e-6         # s3 / s1 of the user points below this: coplanar layout


def _triad(p: Array) -> Array:
    """Paper eqs 3-4 on p[0..2]: columns i = v12/|v12|, j = k x i, k = v12 x v13/|..|."""
    v12, v13 = p[1] - p[0], p[2] - p[0]
    k = np.cross(v12, v13)
    k /= np.linalg.norm(k)
    i = v12 / np.linalg.norm(v12)
    return np.column_stack([i, np.cross(k, i), k])


def _three_point_pose(pu: Array, pb: Array) -> Array:
    R = _triad(pb) @ _triad(pu).T
    return make_transform(R, pb[0] - R @ pu[0])


def _affine_fit(pu: Array, pb: Array) -> tuple[Array, bool]:
    """Paper eqs 6-8: (4, 4) M with p_base ~ M p_user; True if the normal column was completed."""
    A, basis = _affine_design(pu)
    X = np.linalg.lstsq(A, pb, rcond=None)[0]
    if basis is None:
        M = np.eye(4)
        M[:3, :] = X.T
        return M, False
    return _completed_affine(X, basis, pu.mean(axis=0)), True


def _affine_design(pu: Array) -> tuple[Array, Array | None]:
    """(A, basis): the affine fit solves A X = p_base (least squares) for X.

    Non-coplanar: A rows [x y z 1], basis None. Coplanar: A rows [a b 1], the in-plane
    coordinates of the centred points in ``basis`` = :func:`_plane_basis` of their normal.
    """
    _, s, Vt = np.linalg.svd(pu - pu.mean(axis=0))
    if s[2] > PLANAR_TOL * s[0]:
        return np.column_stack([pu, np.ones(len(pu))]), None
    E = _plane_basis(Vt[2])
    return np.column_stack([(pu - pu.mean(axis=0)) @ E[:, :2], np.ones(len(pu))]), E


def _completed_affine(X: Array, E: Array, centre: Array) -> Array:
    """M from the in-plane fit X (rows g_a, g_b, g_0), its normal column completed.

    With a z = 0 layout the basis is (x, +-y, +-z), so M's z column becomes the unit normal of
    its x and y columns, scaled by their mean norm (right-handed).
    """
    g_a, g_b, g_0 = X
    normal_image = np.cross(g_a, g_b)
    mean_norm = 0.5 * (np.linalg.norm(g_a) + np.linalg.norm(g_b))
    normal_image *= mean_norm / np.linalg.norm(normal_image)
    M3 = np.column_stack([g_a, g_b, normal_image]) @ E.T
    return make_transform(M3, g_0 - M3 @ centre)


def _plane_basis(normal: Array) -> Array:
    """Right-handed orthonormal columns (e1, e2, n), e1 the user x axis in the plane if it can."""
    n = normal / np.linalg.norm(normal)
    e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(e1) < 0.5:
        e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(n, e1), n])


def nearest_rigid(M: Array) -> Array:
    """Polar decomposition: the rotation nearest M's 3x3 (det +1), with M's translation."""
    U, _, Vt = np.linalg.svd(M[:3, :3])
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return make_transform(R, M[:3, 3])


def _affine_pose(pu: Array, pb: Array) -> Array:
    return nearest_rigid(_affine_fit(pu, pb)[0])


def _estimator(method: str) -> Estimator:
    estimators: dict[str, Estimator] = {
        'three_point': _three_point_pose, 'five_point_lsq': _affine_pose,
        'rigid': kabsch, 'robust': kabsch}
    if method not in estimators:
        raise ValueError(f'unknown method {method!r}; use one of: {", ".join(METHODS)}')
    return estimators[method]
