"""The hand-eye calibration's one api and its client side.

:func:`calibrate_and_store` runs the core procedure (core.landmarks.hand_eye_capture.
calibrate_hand_eye) over the robot and camera ports, stores the result with what it was
measured through and activates it when it passes its gate (hand_eye_calibrator's goal handler
calls it; the node publishes what it made active). :func:`calibrate_hand_eye` sends the goal
and waits; :func:`error_against_truth` compares a hand-eye with the mock robot's ground truth
(simulation only: a real cell has none). Used by ``cobot-calib hand-eye`` and by
``cobot-calib experiment user-frame`` before its landmark rows.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time

import numpy as np

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.core.landmarks.hand_eye_capture import (calibrate_hand_eye as
                                                             run_procedure, HandEyeRun,
                                                             ViewDone)
from cobot_calib_ros.core.provenance import missing_prerequisites
from cobot_calib_ros.core.robot_port import CameraPort, Cancelled, never, RobotPort
from cobot_calib_ros.ros.calls import call_service, CallError, run_action_once
from cobot_calib_ros.store.records import HandEyeInputs, HandEyeRecord, HandEyeResult

HAND_EYE_TIMEOUT = 600.0    # [s] for the whole calibration (12 views take 5-60 s here)


@dataclass(frozen=True)
class HandEyeError:
    """How far a hand-eye is from the truth: the optical frame's origin [m] and its rotation
    [rad]; the same for the cell's nominal hand-eye."""

    position_m: float
    rotation_rad: float
    nominal_position_m: float
    nominal_rotation_rad: float


@dataclass(frozen=True)
class HandEyeViewsRequest:
    """What a hand-eye calibration is asked for (the goal's, defaults filled)."""

    count: int = 12
    hold: float = 0.2                # [s]
    landmark_timeout: float = 5.0    # [s]
    seed: int = 0


@dataclass(frozen=True)
class HandEyeOutcome:
    """A hand-eye calibration stored: ``code`` SUCCESS (active: publish it) or SOLVER_FAILED
    (stored as rejected by its gate, not active), ``message`` what to tell the user. Truthy
    (a Failure is not)."""

    record: HandEyeRecord
    run: HandEyeRun
    code: ErrorCode
    message: str


def calibrate_and_store(request: HandEyeViewsRequest, robot: RobotPort, camera: CameraPort,
                        rig, repo, T_base_user, stamp_ns: int, *, flange_frame: str,
                        cancelled: Cancelled = never, progress: ViewDone | None = None,
                        warn: Callable[[str], None] | None = None
                        ) -> HandEyeOutcome | Failure:
    """Calibrate the wrist camera of ``rig.cell`` (core.rig.Rig: the flange poses by its
    active kinematics) from ``request.count`` views of the board where ``T_base_user`` puts
    it, and store the result in ``repo`` (a store.Repository) with ``measured_through``
    (kinematics and intrinsics); made active when it passes its gate, else kept as rejected
    (SOLVER_FAILED). A Failure stores nothing. ``warn`` is told the missing prerequisites."""
    if not (3 <= request.count <= 200) or not (0.0 < request.hold <= 10.0):
        return Failure(ErrorCode.INVALID_INPUT, f'views must be 3..200 (0 = 12) and hold '
                       f'0..10 s, got {request.count} and {request.hold}')
    cell = rig.cell
    through = {'kinematics': rig.active.kinematics_label,
               'intrinsics': rig.active.label('intrinsics')}
    prerequisites = missing_prerequisites('the hand-eye is', through)
    if prerequisites and warn is not None:
        warn(prerequisites)
    t_start = time.monotonic()
    run = run_procedure(cell, rig.model, robot, camera, rig.chain('flange'),
                        count=request.count, T_base_user=T_base_user, seed=request.seed,
                        hold=request.hold, landmark_timeout=request.landmark_timeout,
                        cancelled=cancelled, progress=progress)
    if not run:
        return run
    record = _record(run, request.count, through, stamp_ns, flange_frame, cell.camera.frame_id)
    try:
        repo.hand_eye.save_and_activate(record)   # with a gate problem: kept, rejected
    except Refusal as e:                          # another cell's (store.cells)
        return e.failure
    except (OSError, ValueError) as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the hand-eye calibration: {e}')
    if run.gate_problem:
        return HandEyeOutcome(record, run, ErrorCode.SOLVER_FAILED, (
            f'{record.id} rejected, stored as rejected and not made active (the active '
            f'hand-eye is unchanged): {run.gate_problem}'))
    solved, views = run.result, run.views
    nominal = frames.transform_error(solved.T_flange_optical, cell.camera.T_flange_optical)
    return HandEyeOutcome(record, run, ErrorCode.SUCCESS, (
        f'{record.id}: {views.used} views used, {len(views.skipped)} skipped '
        f'({views.unpaired} unpaired); residual RMS '
        f'{solved.residual_m * 1e3:.4f} mm / {solved.residual_rad * 1e3:.4f} mrad; '
        f'{nominal[0] * 1e3:.3f} mm / {nominal[1] * 1e3:.3f} mrad from the nominal '
        f'hand-eye; {time.monotonic() - t_start:.1f} s'
        + (f'; {prerequisites}' if prerequisites else '')))


def _record(run: HandEyeRun, planned: int, through: dict[str, str], stamp_ns: int,
            flange_frame: str, camera_frame: str) -> HandEyeRecord:
    """The record of a hand-eye run (residuals stored in mm / mrad, as the fields say)."""
    views, solved = run.views, run.result
    return HandEyeRecord(
        id=record_id('hand_eye'), stamp_ns=stamp_ns, method='park+least_squares',
        kinematics=through['kinematics'], measured_through=through, flange_frame=flange_frame,
        camera_frame=camera_frame, cell='', gate_problem=run.gate_problem,
        inputs=HandEyeInputs(joints=views.joints, T_base_flange=views.flange,
                             T_optical_board=views.boards,
                             board_covariances=views.covariances, skipped=views.skipped,
                             planned_views=planned),
        result=HandEyeResult(T_flange_optical=solved.T_flange_optical,
                             T_base_board=solved.T_base_board,
                             initial_T_flange_optical=solved.initial,
                             residual_mm=solved.residual_m * 1e3,
                             residual_mrad=solved.residual_rad * 1e3,
                             residuals_mm=solved.residuals_m * 1e3,
                             residuals_mrad=solved.residuals_rad * 1e3,
                             covariance=solved.covariance, views_used=views.used))


def calibrate_hand_eye(node, views: int = 0, timeout: float = HAND_EYE_TIMEOUT,
                       feedback=None, executor=None):
    """Run calibrate_hand_eye to its end; the result (CallError if the action is missing or
    does not finish in time; a failed calibration comes back with its error_code)."""
    from cobot_calib_msgs.action import CalibrateHandEye
    return run_action_once(node, CalibrateHandEye, 'calibrate_hand_eye',
                           CalibrateHandEye.Goal(views=views), timeout, feedback, executor)


def error_against_truth(node, T_flange_optical: np.ndarray, nominal: np.ndarray,
                        executor=None) -> HandEyeError:
    """The hand-eye's error (and the nominal one's) against the mock robot's truth
    (get_ground_truth)."""
    from cobot_calib_msgs.srv import GetGroundTruth
    from cobot_calib_ros.ros import convert
    client = node.create_client(GetGroundTruth, 'get_ground_truth')
    try:
        truth = call_service(node, client, GetGroundTruth.Request(), 10.0, executor,
                             idempotent=True)
    finally:
        node.destroy_client(client)
    if truth is None:
        raise CallError('get_ground_truth did not answer; is mock_robot up?')
    T_true = convert.transform_to_matrix(truth.t_flange_optical_true)
    return HandEyeError(*frames.transform_error(T_flange_optical, T_true),
                        *frames.transform_error(nominal, T_true))
