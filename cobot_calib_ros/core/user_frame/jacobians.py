"""Analytic first derivatives of the pose estimators w.r.t. the measured points.

They replace refitting per coordinate by central differences (test_jacobians compares the
two). Each derivative is an array whose last axis runs over the row-major flattened p_base (3N)
[m]; pose derivatives follow covariance.py's (rho, phi) convention.

The affine fit (paper eqs 6-8): its parameters X (``A X = p_base`` by least squares) are
linear in p_base, ``dX[j, k] / dpb[i, l] = pinv(A)[j, i] delta_kl``, so M's derivative is exact
on a non-coplanar layout; the completed normal column (coplanar layout), the column norms and the
nearest rotation follow by the chain rule. The three-point pose (eqs 3-5) is differentiated
through its triad.
"""
from __future__ import annotations

import numpy as np

from cobot_calib_ros.core.frames import skew
from cobot_calib_ros.core.user_frame.estimators import (
    _affine_design, _affine_fit, _triad, nearest_rigid)
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


def affine_pose_jacobian(pu: Array, pb: Array) -> Array:
    """(6, 3N) d(rho, phi) of the five_point_lsq pose (the rotation nearest the affine M)."""
    return nearest_rigid_jacobian(_affine_fit(pu, pb)[0], affine_jacobian(pu, pb))


def scale_jacobian(M: Array, dM: Array) -> Array:
    """(3, 3N) derivative of the column norms of M's 3x3 given dM = :func:`affine_jacobian`."""
    M3 = M[:3, :3]
    return np.einsum('kj,kjx->jx', M3, dM[:, :3]) / np.linalg.norm(M3, axis=0)[:, None]


def nearest_rigid_jacobian(M: Array, dM: Array) -> Array:
    """(6, 3N) d(rho, phi) of :func:`nearest_rigid` (M) given dM (covariance.py's convention).

    With M3 = R S (S = R^T M3 symmetric), R^T dM3 - dM3^T R = [(tr S I - S) w]x for the body
    rotation w of dR = R [w]x; phi = R w is the same rotation in base axes. tr S I - S is
    singular only for a mirror (det M < 0, which check_plausible refuses) whose two smaller
    singular values are equal: least squares keeps that case finite instead of raising.
    """
    R = nearest_rigid(M)[:3, :3]
    S = R.T @ M[:3, :3]
    Q = np.einsum('ka,kbx->abx', R, dM[:, :3])
    vee = np.stack([Q[2, 1] - Q[1, 2], Q[0, 2] - Q[2, 0], Q[1, 0] - Q[0, 1]])
    body = np.linalg.lstsq(np.trace(S) * np.eye(3) - S, vee, rcond=None)[0]
    return np.concatenate([dM[:, 3], R @ body])


def three_point_jacobian(pu: Array, pb: Array) -> Array:
    """(6, 3N) d(rho, phi) of the three-point pose (eqs 3-5); zero beyond the first 3 points.

    R = triad(p_base) triad(p_user)^T, so dR R^T = d triad triad^T and phi = 1/2 sum over the
    triad's columns c of c x dc; t = p_base[0] - R p_user[0].
    """
    triad = _triad(pb)
    d_triad = _triad_jacobian(pb[:3])
    phi = 0.5 * sum(skew(triad[:, c]) @ d_triad[c] for c in range(3))
    R = triad @ _triad(pu).T
    rho = np.hstack([np.eye(3), np.zeros((3, 6))]) + skew(R @ pu[0]) @ phi
    J = np.zeros((6, pb.size))
    J[:, :9] = np.vstack([rho, phi])
    return J


def _triad_jacobian(p: Array) -> list[Array]:
    """(3, 9) derivatives of the triad's columns i, j, k w.r.t. the flattened p[0..2]."""
    I3, Z3 = np.eye(3), np.zeros((3, 3))
    v12, v13 = p[1] - p[0], p[2] - p[0]
    d12, d13 = np.hstack([-I3, I3, Z3]), np.hstack([-I3, Z3, I3])
    normal = np.cross(v12, v13)
    d_k = _unit_jacobian(normal, skew(v12) @ d13 - skew(v13) @ d12)
    d_i = _unit_jacobian(v12, d12)
    i, k = v12 / np.linalg.norm(v12), normal / np.linalg.norm(normal)
    return [d_i, skew(k) @ d_i - skew(i) @ d_k, d_k]


def _unit_jacobian(v: Array, dv: Array) -> Array:
    """Derivative of v / |v| given dv."""
    length = np.linalg.norm(v)
    u = v / length
    return (np.eye(3) - np.outer(u, u)) @ dv / length
