"""Analytic first derivatives of the affine fit (paper eqs 6-8) w.r.t. the measured points.

Each derivative is an array whose last axis runs over the row-major flattened p_base (3N) [m].
The fit's parameters X (``A X = p_base`` by least squares) are linear in p_base,
``dX[j, k] / dpb[i, l] = pinv(A)[j, i] delta_kl``, so M's derivative is exact on a non-coplanar
layout; the completed normal column (coplanar layout), the column norms and the nearest rotation
are differentiated by the chain rule. Replaces refitting per coordinate by central differences
(test_affine_jacobian compares the two).
"""
from __future__ import annotations

import numpy as np

from cobot_calib_ros.core.frames import skew
from cobot_calib_ros.core.user_frame.estimators import _affine_design, nearest_rigid
from cobot_calib_ros.core.user_frame.geometry import Array


def affine_jacobian(pu: Array, pb: Array) -> Array:
    """(3, 4, 3N) derivative of M[:3] (the affine fit's M of ``pu``, ``pb``) w.r.t. p_base."""
    A, basis = _affine_design(pu)
    G = np.linalg.pinv(A)
    dX = np.einsum('ji,kl->kjil', G, np.eye(3)).reshape(3, len(G), pb.size)   # dX^T
    if basis is None:
        return dX
    g_a, g_b, _ = G @ pb
    d_a, d_b, d_0 = dX[:, 0], dX[:, 1], dX[:, 2]
    normal = np.cross(g_a, g_b)
    length = np.linalg.norm(normal)
    unit = normal / length
    norm_a, norm_b = np.linalg.norm(g_a), np.linalg.norm(g_b)
    mean_norm = 0.5 * (norm_a + norm_b)
    d_normal = skew(g_a) @ d_b - skew(g_b) @ d_a
    d_mean = 0.5 * (g_a @ d_a / norm_a + g_b @ d_b / norm_b)
    d_image = (np.outer(unit, d_mean)
               + mean_norm / length * (np.eye(3) - np.outer(unit, unit)) @ d_normal)
    dM3 = np.einsum('kqx,jq->kjx', np.stack([d_a, d_b, d_image], axis=1), basis)
    d_t = d_0 - np.einsum('kjx,j->kx', dM3, pu.mean(axis=0))
    return np.concatenate([dM3, d_t[:, None]], axis=1)


def scale_jacobian(M: Array, dM: Array) -> Array:
    """(3, 3N) derivative of the column norms of M's 3x3 given dM = :func:`affine_jacobian`."""
    M3 = M[:3, :3]
    return np.einsum('kj,kjx->jx', M3, dM[:, :3]) / np.linalg.norm(M3, axis=0)[:, None]


def nearest_rigid_jacobian(M: Array, dM: Array) -> Array:
    """(6, 3N) d(rho, phi) of :func:`nearest_rigid` (M) given dM (covariance.py's convention).

    With M3 = R S (S = R^T M3 symmetric), R^T dM3 - dM3^T R = [(tr S I - S) w]x for the body
    rotation w of dR = R [w]x; phi = R w is the same rotation in base axes.
    """
    R = nearest_rigid(M)[:3, :3]
    S = R.T @ M[:3, :3]
    Q = np.einsum('ka,kbx->abx', R, dM[:, :3])
    vee = np.stack([Q[2, 1] - Q[1, 2], Q[0, 2] - Q[2, 0], Q[1, 0] - Q[0, 1]])
    body = np.linalg.solve(np.trace(S) * np.eye(3) - S, vee)
    return np.concatenate([dM[:, 3], R @ body])
