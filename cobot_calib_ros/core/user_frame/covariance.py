"""Pose covariance of the fits, the noise estimate, and the estimation limit (Monte-Carlo too).

Convention, all methods: the 6-vector (x, y, z, rx, ry, rz) perturbs the fit as
``t' = t + rho`` and ``R' = Exp(phi) @ R``: ``rho`` moves the user origin in base [m], ``phi`` is
a rotation vector in base axes about the user origin [rad], applied on the left. The Gauss-Newton
Jacobian of a residual ``R p_user + t - p_base`` is then ``[I, -[R p_user]x]``.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.frames import Rotation, skew
from cobot_calib_ros.core.user_frame.checks import _check_points, point_names
from cobot_calib_ros.core.user_frame.estimators import (
    _affine_pose, _estimator, _three_point_pose, DEFAULT_METHOD)
from cobot_calib_ros.core.user_frame.jacobians import (
    affine_pose_jacobian, scale_jacobian, three_point_jacobian)
from cobot_calib_ros.core.user_frame.geometry import _as_points, _rms, Array, Estimator

LIMIT_FACTOR = 3.0
"""An achieved frame error above ``LIMIT_FACTOR`` times :func:`estimation_limit` is suspect:
for Gaussian noise it happens in well under 1 % of calibrations."""


def pose_covariance(p_user: ArrayLike, R: Array, sigma: float) -> Array:
    """(6, 6) covariance of a rigid least-squares fit's (t, phi) [m^2, m rad, rad^2].

    ``sigma^2 (J^T J)^-1`` with J rows ``[I, -[R p_user]x]`` (convention in the module doc) for
    isotropic point noise ``sigma`` [m] per coordinate. An infinite sigma gives inf on the
    diagonal (and zeros elsewhere), never NaN.
    """
    q = _as_points(p_user, 'p_user') @ R.T
    total = skew(q.sum(axis=0))
    JtJ = np.zeros((6, 6))
    JtJ[:3, :3] = len(q) * np.eye(3)
    JtJ[:3, 3:] = -total
    JtJ[3:, :3] = total
    JtJ[3:, 3:] = (q * q).sum() * np.eye(3) - q.T @ q
    return _scaled(np.linalg.inv(JtJ), sigma)


def estimation_limit(p_user: ArrayLike, sigma: float, *, method: str = DEFAULT_METHOD,
                     n_trials: int | None = None, rng: np.random.Generator | None = None
                     ) -> tuple[float, float]:
    """Frame error expected from point noise alone: (translation [m], rotation [rad]) RMS.

    For isotropic noise ``sigma`` [m] per coordinate on the measured points, returns
    sqrt(trace) of the translation and rotation blocks of the pose covariance (the RMS of
    |t error| and |rotation error|), from the linearised covariance, or from ``n_trials``
    Monte-Carlo fits when given. It does not depend on the user frame's pose. Compare an
    achieved error with ``LIMIT_FACTOR`` times it. A degenerate layout gives (inf, inf).
    """
    pu = _as_points(p_user, 'p_user')
    estimate = _estimator(method)
    n_plane = 3 if method == 'three_point' else None
    if _check_points(pu, pu, n_plane, point_names(len(pu))) is not None:
        return math.inf, math.inf
    if n_trials is not None:
        errors = _monte_carlo_errors(estimate, pu, sigma, n_trials, rng)
        return _rms(errors[:, :3]), _rms(errors[:, 3:])
    if method in ('rigid', 'robust'):
        cov = pose_covariance(pu, np.eye(3), sigma)
    else:
        cov = _propagated_covariance(estimate, pu, pu, sigma)
    return math.sqrt(np.trace(cov[:3, :3])), math.sqrt(np.trace(cov[3:, 3:]))


def _noise_sigma(residuals: Array, dof: float, sigma_prior: float | None
                 ) -> tuple[float, str]:
    """Point noise per coordinate [m]: the prior, or sqrt(sum |r|^2 / dof); inf without dof."""
    if sigma_prior is not None:
        return float(sigma_prior), ''
    if dof <= 1e-9:
        return math.inf, ('no spare measurements to estimate the noise: covariance is inf; '
                          'give sigma_prior or touch more markers')
    return math.sqrt(float((residuals ** 2).sum()) / dof), ''


def _propagated_covariance(estimate: Estimator, pu: Array, pb: Array, sigma: float) -> Array:
    """sigma^2 J J^T: isotropic noise on p_base propagated through ``estimate`` (linearised)."""
    if not math.isfinite(sigma):
        return _scaled(np.eye(6), math.inf)
    J = _pose_jacobian(estimate, pu, pb)
    return _scaled(J @ J.T, sigma)


def _scale_standard_errors(M: Array, dM: Array, sigma: float) -> Array:
    """(3,) standard errors of the affine M's column norms (eqs 6-8) for noise ``sigma`` [m].

    Isotropic noise on p_base propagated through the fit, ``dM`` =
    :func:`jacobians.affine_jacobian` (linearised): ``sigma * sqrt(diag(J J^T))``. On a non-coplanar
    layout this is ``sigma sqrt([(A^T A)^-1]_jj)``, large along a thin direction of the layout.
    An infinite sigma gives inf.
    """
    if not math.isfinite(sigma):
        return np.full(3, math.inf)
    J = scale_jacobian(M, dM)
    return sigma * np.sqrt((J ** 2).sum(axis=1))


def _pose_jacobian(estimate: Estimator, pu: Array, pb: Array) -> Array:
    """(6, 3N) d(rho, phi) / d p_base (row-major points) of the three_point or affine pose."""
    jacobian = {_three_point_pose: three_point_jacobian, _affine_pose: affine_pose_jacobian}
    return jacobian[estimate](pu, pb)


def _effective_dof(J: Array, pu: Array, R: Array) -> float:
    """E[sum |r|^2] / sigma^2 for a rigid estimator with pose Jacobian J: ||A J - I||_F^2.

    A stacks the rows [I, -[R p]x] (residual w.r.t. pose); for least squares this is 3N - 6.
    """
    A = np.concatenate([np.hstack([np.eye(3), -skew(q)]) for q in pu @ R.T])
    return float(np.sum((A @ J - np.eye(len(A))) ** 2))


def _pose_delta(T: Array, T0: Array) -> Array:
    """(rho, phi) with T = (t0 + rho, Exp(phi) R0) [m, rad]; (n, 6) for a stack T (n, 4, 4)."""
    phi = Rotation.from_matrix(T[..., :3, :3] @ T0[:3, :3].T).as_rotvec()
    return np.concatenate([T[..., :3, 3] - T0[:3, 3], phi], axis=-1)


def _monte_carlo_errors(estimate: Estimator, pu: Array, sigma: float, n_trials: int,
                        rng: np.random.Generator | None) -> Array:
    """(n_trials, 6) pose errors of fits to p_user plus N(0, sigma^2) noise [m, rad]."""
    rng = np.random.default_rng(0) if rng is None else rng
    fits = [estimate(pu, pu + rng.normal(0.0, sigma, pu.shape)) for _ in range(n_trials)]
    return _pose_delta(np.array(fits), np.eye(4))


def _scaled(cov_unit: Array, sigma: float) -> Array:
    if math.isfinite(sigma):
        return sigma ** 2 * cov_unit
    return np.diag(np.full(6, math.inf))
