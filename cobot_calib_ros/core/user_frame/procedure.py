"""The user-frame calibration as one procedure over the robot port (issue 39.2): named points
touched (live, or their joints given), the one FK of captures, the fit, its gate and the
optional surface; or a landmark method's views (core.landmarks.views.measure_frame).

user_frame_solver runs it over ros.robot_calls / ros.landmark_watch, ``cobot-calib user-frame
--points`` over joints or points read from a file, tests over sim.robot.DirectRobot. Storing
and activation are api.user_frame's. SI: points [m], joints [rad], durations [s].
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.robot_port import (Cancelled, check_cancel, MoveFailed, never,
                                             PortError, RobotPort, Stopped)
from cobot_calib_ros.core.user_frame import landmarks as landmark_frames
from cobot_calib_ros.core.user_frame.fit import calibrate
from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR
from cobot_calib_ros.core.user_frame.result import FrameFit
from cobot_calib_ros.core.user_frame.robust import ROBUST_THRESHOLD
from cobot_calib_ros.core.user_frame.surface import fit_surface, SurfaceModel

CAPTURE_DURATION = 0.5     # [s] a capture's hold (capture_joints' default)


@dataclass(frozen=True)
class Gate:
    """The fit's options and gate: user_frame_solver's parameters of the same names."""

    max_rms_error: float = MAX_RMS_ERROR        # [m]
    max_scale_error: float = MAX_SCALE_ERROR    # [1]
    robust_threshold: float = ROBUST_THRESHOLD  # [m] the robust method's
    fit_surface: bool = False


@dataclass(frozen=True)
class FrameMeasurement:
    """A fitted, gated user frame and the point pairs behind it."""

    fit: FrameFit
    surface: SurfaceModel | None
    names: list[str]
    p_user: np.ndarray      # (N, 3) nominal points, user frame [m]
    p_base: np.ndarray      # (N, 3) measured points, base frame [m]


def points_of_joints(chain: kinematics.Chain, joints) -> np.ndarray:
    """(N, 3) [m] where the tool centre of ``chain`` is at each of ``joints`` (N, n) [rad]:
    the one FK of captures."""
    return kinematics.fk(chain, np.atleast_2d(np.asarray(joints, dtype=float)))[:, :3, 3]


def check_names(cell, names: Sequence[str]) -> None:
    """Refusal (UNKNOWN_POINT) unless every name is a point of the cell's layout."""
    unknown = [n for n in names if cell.marker(n) is None]
    if unknown and not cell.point_names:
        raise Refusal(Failure(ErrorCode.UNKNOWN_POINT, (
            f'named points {unknown}: a calibration of named points needs the cell\'s '
            'layouts: section, which this cell has not; give points_user + points_base, '
            'or measure offline (cobot-calib user-frame --points)')))
    if unknown:
        raise Refusal(Failure(ErrorCode.UNKNOWN_POINT, (
            f'unknown point(s) {unknown}; the cell defines {cell.point_names}')))


def touch_joints(robot: RobotPort, names: Sequence[str], duration: float = CAPTURE_DURATION,
                 cancelled: Cancelled = never,
                 progress: Callable[[str], None] | None = None) -> list[np.ndarray]:
    """Each named point touched and held for ``duration`` [s]: the mean joints [rad];
    Refusal MOTION_FAILED / CAPTURE_FAILED when a touch / a capture did not happen, CANCELED
    when ``cancelled()`` between points."""
    joints = []
    for name in names:
        try:
            check_cancel(cancelled, f'point {name}')
            robot.touch(name)
            joints.append(robot.capture(duration).q)
        except Stopped as e:
            raise Refusal(Failure(ErrorCode.CANCELED, str(e))) from None
        except PortError as e:
            cause = ErrorCode.MOTION_FAILED if isinstance(e, MoveFailed) else \
                ErrorCode.CAPTURE_FAILED
            raise Refusal(Failure(cause, f'capture at {name} failed: {e}')) from None
        if progress is not None:
            progress(name)
    return joints


def fit_points(method: str, names: Sequence[str], p_user, p_base,
               gate: Gate = Gate()) -> FrameMeasurement | Failure:
    """The fit of ``method`` (refused beyond the gate: IMPLAUSIBLE_FIT) and, when the gate asks,
    the surface's height field."""
    opts = {'threshold': gate.robust_threshold} if method == 'robust' else {}
    fit = calibrate(method, p_user, p_base, names=list(names),
                    max_rms_error=gate.max_rms_error, max_scale_error=gate.max_scale_error,
                    **opts)
    return _measured(fit, method, list(names), p_user, p_base, gate)


def _measured(fit: FrameFit, method: str, names, p_user, p_base,
              gate: Gate) -> FrameMeasurement | Failure:
    if not fit:
        return Failure(ErrorCode(fit.code), fit.message)
    # landmark_multi: the fiducials' centres lie on the table, so they carry its height field
    # like touched points do; one marker's single frame has nothing to fit
    surface = (fit_surface(p_user, p_base, fit.M, names=names)
               if gate.fit_surface and method != landmark_frames.LANDMARK_SINGLE else None)
    return FrameMeasurement(fit, surface, list(names), np.asarray(p_user, dtype=float),
                            np.asarray(p_base, dtype=float))


def touched_frame(method: str, cell, names: Sequence[str], chain: kinematics.Chain,
                  robot: RobotPort | None, *, joints=None, gate: Gate = Gate(),
                  capture_duration: float = CAPTURE_DURATION, cancelled: Cancelled = never,
                  progress: Callable[[str], None] | None = None) -> FrameMeasurement | Failure:
    """The user frame of the cell's named points: touched over ``robot`` (or at ``joints``
    given, one per name [rad]), mapped through ``chain`` (its tool: the TCP), fitted, gated."""
    try:
        check_names(cell, names)
        if joints is None:
            joints = touch_joints(robot, names, capture_duration, cancelled, progress)
    except Refusal as e:
        return e.failure
    p_user = np.array([cell.marker(n).nominal_top for n in names])
    return fit_points(method, names, p_user, points_of_joints(chain, joints), gate)


def landmark_frame(method: str, cell, robot: RobotPort, camera, *, guess: np.ndarray,
                   plan_chain: kinematics.Chain, chain: kinematics.Chain, gate: Gate = Gate(),
                   capture_duration: float = CAPTURE_DURATION, cancelled: Cancelled = never,
                   on_view=None) -> FrameMeasurement | Failure:
    """A landmark method's user frame (core.landmarks.views.measure_frame), with the surface
    when the gate asks."""
    from cobot_calib_ros.core.landmarks import views
    try:
        result = views.measure_frame(
            method, cell, robot, camera, T_base_user_guess=guess, plan_chain=plan_chain,
            chain=chain, capture_duration=capture_duration, max_rms_error=gate.max_rms_error,
            max_scale_error=gate.max_scale_error, cancelled=cancelled, on_view=on_view)
    except Stopped as e:
        return Failure(ErrorCode.CANCELED, str(e))
    return _measured(result.fit, method, result.names, result.p_user, result.p_base, gate)
