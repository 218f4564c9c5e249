"""Has a cell drifted? A new result against the previous one, with both uncertainties.

A user frame moves between two calibrations by d = t_new - t_prev (translation) and by the
rotation angle of R_prev^T R_new. The change has a standard error of its own, from a (6, 6)
covariance C over (t [m], phi [rad]) (core.user_frame.covariance): along the change's
direction, sigma_t^2 = u^T C u (u = d / |d|), and likewise for the rotation.

Which C: when both results measured the same points, :func:`change_covariance` fits the rigid
motion from the previous measured points to the new ones; its residuals hold only the two
touches' noise, since the table's unevenness and the robot's kinematic errors are the same in
both and cancel. The sum of the two fits' own covariances would count those systematic errors
as noise (on the simulated Sawyer cell it is 3x the real scatter of repeats) and miss a 0.3 mm
move in z. A change raises an alarm only if it is beyond
``k`` standard errors (it is not noise) AND beyond a tolerance (it matters): WARN past the
warn tolerance, ERROR past the error one. Either test alone fails: k sigma alone flags
harmless micrometres of a very precise fit, a tolerance alone flags noise of a poor one.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.frames import rotation_angle

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR'}


@dataclass(frozen=True)
class DriftLimits:
    k: float = 3.0                    # standard errors
    warn_m: float = 0.2e-3            # [m]
    error_m: float = 1.0e-3           # [m]
    warn_rad: float = 1.0e-3          # [rad]
    error_rad: float = 5.0e-3         # [rad]


@dataclass(frozen=True)
class FrameChange:
    """The change of a frame between two results, with its standard errors, and the verdict."""

    translation_m: float
    rotation_rad: float
    sigma_translation_m: float        # standard error of the change along its direction
    sigma_rotation_rad: float
    level: int                        # OK, WARN, ERROR
    message: str

    @property
    def level_name(self) -> str:
        return LEVEL_NAMES[self.level]


def change_covariance(T_prev: ArrayLike, p_prev: ArrayLike, p_new: ArrayLike) -> np.ndarray:
    """(6, 6) covariance of the frame change between two results that measured the same
    points (N, 3) [m] in the base frame (rows in the same order): the rigid fit of the new
    points to the previous ones in the previous user frame, with the noise sigma of its
    residuals (3N - 6 degrees of freedom). inf on the diagonal below 3 points."""
    from cobot_calib_ros.core.frames import apply, invert, kabsch
    from cobot_calib_ros.core.user_frame import pose_covariance
    p_prev, p_new = np.asarray(p_prev, dtype=float), np.asarray(p_new, dtype=float)
    if p_prev.shape != p_new.shape or p_prev.ndim != 2 or len(p_prev) < 3:
        return np.diag([math.inf] * 6)
    p_user = apply(invert(np.asarray(T_prev, dtype=float)), p_prev)
    motion = kabsch(p_user, p_new)
    residuals = p_new - apply(motion, p_user)
    dof = 3 * len(p_prev) - 6
    sigma = math.sqrt(float(np.sum(residuals ** 2)) / dof) if dof > 0 else math.inf
    return pose_covariance(p_user, motion[:3, :3], sigma)


def _directional_sigma(delta: np.ndarray, cov: np.ndarray) -> float:
    norm = float(np.linalg.norm(delta))
    if not np.all(np.isfinite(np.diag(cov))):
        return math.inf
    if norm == 0.0:     # no direction: the RMS of the three axes
        return math.sqrt(max(float(np.trace(cov)) / 3.0, 0.0))
    u = delta / norm
    return math.sqrt(max(float(u @ cov @ u), 0.0))


def frame_change(T_prev: ArrayLike, T_new: ArrayLike, cov_change: ArrayLike,
                 limits: DriftLimits = DriftLimits(), what: str = 'user frame',
                 since: str = '') -> FrameChange:
    """The change from the previous frame to the new one and its verdict (module docstring).
    ``cov_change``: (6, 6) over (t [m], phi [rad]), the change's covariance
    (:func:`change_covariance`, or the sum of the two fits' covariances); a non-finite one
    means the noise is unknown: nothing is significant, the verdict is OK."""
    T_prev, T_new = np.asarray(T_prev, dtype=float), np.asarray(T_new, dtype=float)
    cov = np.asarray(cov_change, dtype=float)
    if cov.shape != (6, 6) or not np.all(np.isfinite(np.diag(cov))):
        cov = np.diag([math.inf] * 6)
    d = T_new[:3, 3] - T_prev[:3, 3]
    R_delta = T_prev[:3, :3].T @ T_new[:3, :3]
    from scipy.spatial.transform import Rotation
    phi = T_prev[:3, :3] @ Rotation.from_matrix(R_delta).as_rotvec()   # in the base frame
    moved, turned = float(np.linalg.norm(d)), rotation_angle(R_delta)
    s_t, s_r = _directional_sigma(d, cov[:3, :3]), _directional_sigma(phi, cov[3:, 3:])
    significant_t = moved > limits.k * s_t
    significant_r = turned > limits.k * s_r
    level = max(_level(moved, significant_t, limits.warn_m, limits.error_m),
                _level(turned, significant_r, limits.warn_rad, limits.error_rad))
    text = (f'{what} moved {moved * 1e3:.3f} mm (+-{s_t * 1e3:.3f}) and turned '
            f'{turned * 1e3:.3f} mrad (+-{s_r * 1e3:.3f})' + (f' since {since}' if since else ''))
    if level == OK:
        message = f'{text}: within noise or tolerance'
    else:
        message = (f'{text}: beyond {limits.k:g} standard errors and the tolerance '
                   f'({(limits.warn_m if level == WARN else limits.error_m) * 1e3:g} mm / '
                   f'{(limits.warn_rad if level == WARN else limits.error_rad) * 1e3:g} mrad)'
                   ': recalibrate')
    return FrameChange(moved, turned, s_t, s_r, level, message)


def _level(change: float, significant: bool, warn: float, error: float) -> int:
    if not significant or change <= warn:
        return OK
    return ERROR if change > error else WARN
