"""Poses of markers and ChArUco boards in the camera's optical frame, with a covariance.

The result is ``T_optical_target`` (4, 4) [m]: the marker frame (centre, x right, y up, z out
of the face) or the board frame (top-left outer grid corner, x right, y down, z into the board)
expressed in the optical frame (x right, y down, z forward). The covariance is 6x6 over
(x, y, z, rx, ry, rz): the target origin's position [m] and a small rotation [rad] about the
optical frame's x, y, z axes applied on the left (R' = exp([d]x) R), as in
geometry_msgs/PoseWithCovariance. It is sigma^2 (J^T J)^-1 with J the Jacobian of the
projected pixels, sigma the pixel noise (given, or estimated from the residuals).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import make_transform
from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.detect import BoardDetection
from cobot_calib_ros.core.landmarks.targets import BoardSpec, marker_object_points

# Pixel noise floor [px] when sigma is estimated from the residuals: four corners leave two
# degrees of freedom, and a near-perfect fit must not claim a near-zero covariance. Refined
# corners are good to ~0.03 px (ChArUco) to ~0.2 px (markers) on clean images.
SIGMA_FLOOR_PX = 0.1
# IPPE's second solution fitting less than this many times worse than the first: the marker's
# orientation is ambiguous (near-frontal view, small marker); use a prior or a board.
AMBIGUITY_RATIO = 2.0


@dataclass(frozen=True, eq=False)
class PoseEstimate:
    """One target's pose in the optical frame (see the module docstring for frames/units).

    ``rms_px``: root mean square reprojection error per point [px] (Euclidean);
    ``sigma_px``: the pixel noise the covariance assumes; ``alternative``/
    ``alternative_rms_px``: the rejected mirror solution of a single marker (IPPE), else None.
    """

    T_optical_target: NDArray[np.float64]
    covariance: NDArray[np.float64]
    rms_px: float
    sigma_px: float
    n_points: int
    alternative: NDArray[np.float64] | None = None
    alternative_rms_px: float | None = None

    @property
    def rvec(self) -> NDArray[np.float64]:
        """Rotation vector [rad] (OpenCV's rvec) of T_optical_target."""
        return cv2.Rodrigues(self.T_optical_target[:3, :3])[0].ravel()

    @property
    def tvec(self) -> NDArray[np.float64]:
        """Translation [m] (OpenCV's tvec): the target origin in the optical frame."""
        return self.T_optical_target[:3, 3].copy()

    @property
    def ambiguity_ratio(self) -> float | None:
        """Reprojection error of the rejected mirror solution over the chosen one's (>= 1;
        inf for an exact fit); None when there was no second solution (boards)."""
        if self.alternative_rms_px is None:
            return None
        if self.rms_px <= 0.0:
            return float('inf')
        return self.alternative_rms_px / self.rms_px

    @property
    def ambiguous(self) -> bool:
        ratio = self.ambiguity_ratio
        return ratio is not None and ratio < AMBIGUITY_RATIO


def _transform(rvec, tvec) -> NDArray[np.float64]:
    return make_transform(cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0],
                          np.asarray(tvec, dtype=np.float64).reshape(3))


def _rms(obj, pts, rvec, tvec, K, D) -> float:
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, D)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - pts.reshape(-1, 2)) ** 2, 1))))


def _inverse_left_jacobian(phi: NDArray[np.float64]) -> NDArray[np.float64]:
    """J_l^-1 of SO(3) at rotation vector phi: d(phi) = J_l^-1(phi) d for exp(d) exp(phi)."""
    theta = float(np.linalg.norm(phi))
    W = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) - 0.5 * W
    coef = 1.0 / theta ** 2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    return np.eye(3) - 0.5 * W + coef * (W @ W)


def pose_covariance(object_points: ArrayLike, rvec: ArrayLike, tvec: ArrayLike,
                    K: ArrayLike, D: ArrayLike, sigma_px: float) -> NDArray[np.float64]:
    """6x6 covariance of (x, y, z, rx, ry, rz) (module docstring) for pixel noise sigma_px:
    sigma^2 (J^T J)^-1 with J from cv2.projectPoints, the rotation as a left perturbation."""
    obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    rvec = np.asarray(rvec, dtype=np.float64).reshape(3)
    _, jac = cv2.projectPoints(obj, rvec, np.asarray(tvec, dtype=np.float64).reshape(3),
                               np.asarray(K, dtype=np.float64), np.asarray(D, dtype=np.float64))
    J = np.hstack([jac[:, 3:6], jac[:, 0:3] @ _inverse_left_jacobian(rvec)])
    cov = sigma_px ** 2 * np.linalg.inv(J.T @ J)
    return 0.5 * (cov + cov.T)


def _sigma(residual_rms: float, n_points: int, pixel_sigma: float | None) -> float:
    if pixel_sigma is not None:
        return float(pixel_sigma)
    dof = 2 * n_points - 6
    estimate = residual_rms * np.sqrt(n_points / dof) if dof > 0 else 0.0
    return float(max(estimate, SIGMA_FLOOR_PX))


def _check_pixels(pixels, n: int | None = None) -> NDArray[np.float64] | Failure:
    try:
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError):
        return Failure(ErrorCode.INVALID_INPUT, 'pixels must be an (N, 2) array')
    if n is not None and len(pts) != n:
        return Failure(ErrorCode.INVALID_INPUT, f'expected {n} corners, got {len(pts)}')
    if not np.all(np.isfinite(pts)):
        return Failure(ErrorCode.INVALID_INPUT, 'the pixel coordinates are not finite')
    return pts


def estimate_marker_pose(corners: ArrayLike, marker_length: float, camera: CameraModel, *,
                         pixel_sigma: float | None = None,
                         refine: bool = True) -> PoseEstimate | Failure:
    """Pose T_optical_marker of one square marker of side ``marker_length`` [m] from its (4, 2)
    raw-image corners [px] (TL, TR, BR, BL).

    SOLVEPNP_IPPE_SQUARE gives the two planar solutions; the one with the lower reprojection
    error is kept (the other is the mirror ambiguity, reported as ``alternative``) and, with
    ``refine``, polished by solvePnPRefineLM. Failure (falsy) for bad input or a degenerate quad.
    """
    if not (np.isfinite(marker_length) and marker_length > 0):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'marker length must be > 0 [m], got {marker_length}')
    pts = _check_pixels(corners, 4)
    if isinstance(pts, Failure):
        return pts
    d1, d2 = pts[2] - pts[0], pts[3] - pts[1]
    area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
    if area < 1.0:
        return Failure(ErrorCode.DEGENERATE_POINTS,
                       f'the marker corners span {area:.2g} px^2; no pose')
    obj = marker_object_points(marker_length).reshape(-1, 1, 3)
    img, K, D = camera.pnp_inputs(pts)
    try:
        n, rvecs, tvecs, _errors = cv2.solvePnPGeneric(obj, img, K, D,
                                                       flags=cv2.SOLVEPNP_IPPE_SQUARE)
    except cv2.error as e:
        return Failure(ErrorCode.DEGENERATE_POINTS, f'no marker pose: {e.err}')
    solutions = sorted(((_rms(obj, img, r, t, K, D), r, t) for r, t in zip(rvecs[:n], tvecs[:n])
                        if float(t.ravel()[2]) > 0), key=lambda s: s[0])
    if not solutions:
        return Failure(ErrorCode.DEGENERATE_POINTS, 'no marker pose in front of the camera')
    rms, rvec, tvec = solutions[0]
    alternative = solutions[1] if len(solutions) > 1 else None
    if refine:
        r2, t2 = cv2.solvePnPRefineLM(obj, img, K, D, rvec.copy(), tvec.copy())
        rms2 = _rms(obj, img, r2, t2, K, D)
        if rms2 <= rms and float(t2.ravel()[2]) > 0:
            rms, rvec, tvec = rms2, r2, t2
    sigma = _sigma(rms, 4, pixel_sigma)
    return PoseEstimate(_transform(rvec, tvec), pose_covariance(obj, rvec, tvec, K, D, sigma),
                        rms, sigma, 4,
                        None if alternative is None else _transform(alternative[1],
                                                                    alternative[2]),
                        None if alternative is None else alternative[0])


def estimate_pose(object_points: ArrayLike, pixels: ArrayLike, camera: CameraModel, *,
                  pixel_sigma: float | None = None) -> PoseEstimate | Failure:
    """Pose of a rigid set of >= 4 known points [m] (not all on one line) from their raw-image
    pixels: SOLVEPNP_SQPNP, then solvePnPRefineLM (iterative if SQPnP fails)."""
    pts = _check_pixels(pixels)
    if isinstance(pts, Failure):
        return pts
    obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    if len(obj) != len(pts):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'{len(obj)} object points but {len(pts)} pixels')
    if len(obj) < 4:
        return Failure(ErrorCode.TOO_FEW_POINTS, f'{len(obj)} points; a pose needs >= 4')
    spread = np.linalg.svd(obj - obj.mean(0), compute_uv=False)
    if spread[1] <= 1e-3 * spread[0]:
        return Failure(ErrorCode.DEGENERATE_POINTS, 'the points lie on one line; no pose')
    obj = obj.reshape(-1, 1, 3)
    img, K, D = camera.pnp_inputs(pts)
    rvec = tvec = None
    for flags in (cv2.SOLVEPNP_SQPNP, cv2.SOLVEPNP_ITERATIVE):
        try:
            ok, r, t = cv2.solvePnP(obj, img, K, D, flags=flags)
        except cv2.error:
            continue
        if ok and float(t.ravel()[2]) > 0:
            rvec, tvec = r, t
            break
    if rvec is None:
        return Failure(ErrorCode.DEGENERATE_POINTS, 'no pose in front of the camera')
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, D, rvec, tvec)
    rms = _rms(obj, img, rvec, tvec, K, D)
    sigma = _sigma(rms, len(obj), pixel_sigma)
    return PoseEstimate(_transform(rvec, tvec), pose_covariance(obj, rvec, tvec, K, D, sigma),
                        rms, sigma, len(obj))


def estimate_board_pose(detection: BoardDetection, board: BoardSpec, camera: CameraModel, *,
                        pixel_sigma: float | None = None,
                        min_corners: int = 4) -> PoseEstimate | Failure:
    """Pose T_optical_board of a ChArUco board from its detected chessboard corners (frame:
    the grid's top-left outer corner, x right, y down, z into the board)."""
    ids = np.asarray(detection.charuco_ids, dtype=np.int64)
    if len(ids) < max(min_corners, 4):
        return Failure(ErrorCode.TOO_FEW_POINTS, f'{len(ids)} ChArUco corners; a board pose '
                                                 f'needs >= {max(min_corners, 4)}')
    if ids.min() < 0 or ids.max() >= board.n_corners:
        return Failure(ErrorCode.INVALID_INPUT, f'ChArUco ids outside 0..{board.n_corners - 1}')
    return estimate_pose(board.corner_points()[ids], detection.charuco_corners, camera,
                         pixel_sigma=pixel_sigma)
