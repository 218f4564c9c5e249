"""FrameFit, the result of every method, and how the methods build it."""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import apply
from cobot_calib_ros.core.user_frame.covariance import _noise_sigma, _scaled, pose_covariance
from cobot_calib_ros.core.frames import kabsch
from cobot_calib_ros.core.user_frame.geometry import _join, _rms, _spread, Array, collinearity


@dataclass(frozen=True, eq=False)
class FrameFit:
    """Result of a user-frame calibration; falsy on failure.

    ``condition_number`` is s_max / s_min of the singular values of the centred user points the
    fit used: over the two in-plane values for the rigid methods (a rigid pose needs only two
    directions), over all three for ``five_point_lsq`` on a non-coplanar layout (the affine M
    needs the third). ``collinearity`` is s2 / s1 of the same points, the smaller of the user and
    base sets (0 = collinear, 1 = isotropic in the plane). ``three_point`` reports both for its
    first three points, ``robust`` for its inliers.
    """

    method: str
    T_base_user: Array | None   # (4, 4) rigid pose of the user frame in base
    M: Array | None             # (4, 4) matrix used to map user -> base (affine for lsq)
    residuals: Array            # (N, 3) M p_user - p_base, all points incl. outliers [m]
    rms: float                  # RMS residual norm over inliers [m]
    max_residual: float         # largest residual norm over inliers [m]
    condition_number: float
    collinearity: float
    covariance: Array           # (6, 6) row-major (x y z rx ry rz) [m^2, m rad, rad^2]
    sigma: float                # point noise behind the covariance, estimated or given [m]
    scale: Array                # (3,) column norms of M's 3x3 (1 for rigid methods)
    scale_se: Array             # (3,) their standard errors from sigma (0 rigid; inf: no dof)
    noise_dof: float            # residual degrees of freedom behind sigma (inf: sigma_prior)
    shear: Array                # (3,) xy, xz, yz angles between M's columns - pi/2 [rad]
    outliers: tuple[int, ...]   # indices rejected by the robust method
    code: ErrorCode = ErrorCode.SUCCESS
    message: str = ''

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


def _rigid_fit(method: str, pu: Array, pb: Array, keep: Array, sigma_prior: float | None,
               outliers: tuple[int, ...] = (), message: str = '') -> FrameFit:
    T = kabsch(pu[keep], pb[keep])
    residuals = apply(T, pu) - pb
    dof = 3 * keep.sum() - 6
    sigma, note = _noise_sigma(residuals[keep], dof, sigma_prior)
    cov = pose_covariance(pu[keep], T[:3, :3], sigma)
    return _assemble(method, T, T, residuals, (pu[keep], pb[keep]), cov, sigma,
                     _join(message, note), outliers=outliers, keep=keep,
                     noise_dof=_noise_dof(dof, sigma_prior))


def _assemble(method: str, T: Array, M: Array, residuals: Array, used: tuple[Array, Array],
              cov: Array, sigma: float, message: str, *, noise_dof: float = 0.0,
              condition: float | None = None, outliers: tuple[int, ...] = (),
              keep: Array | None = None, scale_se: Array | None = None) -> FrameFit:
    norms = np.linalg.norm(residuals if keep is None else residuals[keep], axis=1)
    s = _spread(used[0])
    scale, shear = _scale_shear(M[:3, :3])
    return FrameFit(
        method=method, T_base_user=T, M=M, residuals=residuals, rms=_rms(norms),
        max_residual=float(norms.max()),
        condition_number=float(s[0] / s[1]) if condition is None else float(condition),
        collinearity=min(float(s[1] / s[0]) if s[0] > 0.0 else 0.0, collinearity(used[1])),
        covariance=cov,
        sigma=sigma, scale=scale, shear=shear, outliers=outliers, message=message,
        scale_se=np.zeros(3) if scale_se is None else scale_se, noise_dof=float(noise_dof))


def _failure(method: str, failure: Failure) -> FrameFit:
    return FrameFit(
        method=method, T_base_user=None, M=None, residuals=np.zeros((0, 3)), rms=math.inf,
        max_residual=math.inf, condition_number=math.inf, collinearity=0.0,
        covariance=_scaled(np.eye(6), math.inf), sigma=math.inf, scale=np.ones(3),
        scale_se=np.full(3, math.inf), noise_dof=0.0, shear=np.zeros(3), outliers=(),
        code=failure.code, message=failure.message)


def _noise_dof(dof: float, sigma_prior: float | None) -> float:
    """Degrees of freedom of the noise estimate: ``dof``, or inf when sigma is a prior."""
    return math.inf if sigma_prior is not None else float(dof)


def _scale_shear(M3: Array) -> tuple[Array, Array]:
    """Column norms of M3 and the xy, xz, yz angles between its columns minus pi/2 [rad]."""
    gram = M3.T @ M3
    shear = [math.atan2(math.sqrt(max(0.0, gram[a, a] * gram[b, b] - gram[a, b] ** 2)),
                        gram[a, b]) - math.pi / 2 for a, b in ((0, 1), (0, 2), (1, 2))]
    return np.sqrt(np.diag(gram)), np.array(shear)
