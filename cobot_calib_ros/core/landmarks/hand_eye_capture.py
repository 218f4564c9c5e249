"""The hand-eye views taken on the cell: move, wait for the board, capture, pair (a procedure
over the robot and camera ports, core.robot_port).

For each planned joint configuration (core.landmarks.hand_eye.hand_eye_views) the robot moves
there; ``rest`` is the camera clock once the move has returned (the arm rests from then on).
The first image stamped after ``rest`` that shows the board gives T_optical_board (a camera
stamps the exposure: mock_camera the joint_states it rendered), then the joints are captured
over ``hold``. The image lies between the two, so the view is *paired* (image and joints show
the same pose) only when the captured joints agree with the joints the move reached, within
PAIRING_TOLERANCE_RAD: an arm that had not come to rest, or that moved after, fails it. A view
that is unreachable, shows no board, or cannot be paired is skipped and counted; a capture
that fails ends the run (PortError), as does ``cancelled()`` (Stopped, checked before every
view: the caller stores nothing). Runs the same over ROS (RobotCalls, LandmarkWatch) and
in-process on the simulation (DirectRobot, DirectCamera).

:func:`calibrate_hand_eye` is the whole procedure (issue 39.2): plan the views, take them,
solve, gate; a :class:`HandEyeRun` or a core.errors.Failure. Storing and publishing are the
caller's (api.hand_eye.calibrate_and_store, hand_eye_calibrator).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.landmarks.hand_eye import (check_noise, hand_eye_views, HandEyeResult,
                                                     MIN_VIEWS, solve_hand_eye)
from cobot_calib_ros.core.robot_port import (CameraPort, CaptureFailed, Cancelled,
                                             check_cancel, MoveFailed, never, port_failure,
                                             PortError, RobotPort, Stopped)

Array = NDArray[np.float64]
# Captured joints further than this from the joints the move reached [rad] (any joint): the
# arm was not at rest around the image. 0.1 mrad moves the flange ~0.1 mm at 1 m reach, the
# size of a right hand-eye's residual; encoder noise averaged over a hold is ~1e-7 rad.
PAIRING_TOLERANCE_RAD = 1e-4
BOARD_IMAGES = 5         # images after the rest looked at before the board counts as unseen


@dataclass
class HandEyeViews:
    """What the views gave, in view order: joints captured [rad], flange poses by FK on the
    chain given, board poses T_optical_board and their 6x6 covariances [m, rad]; ``skipped``:
    {'view': index, 'reason': ...} of the views left out, ``unpaired`` how many of them could
    not be paired (image and joints from different poses)."""

    planned: int
    joints: list[Array] = field(default_factory=list)
    flange: list[Array] = field(default_factory=list)
    boards: list[Array] = field(default_factory=list)
    covariances: list[Array] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)
    unpaired: int = 0

    @property
    def used(self) -> int:
        return len(self.boards)


ViewDone = Callable[[int, bool, HandEyeViews], None]   # view index, board used, views so far


def pairing_problem(reached: Array, captured: Array,
                    tolerance: float = PAIRING_TOLERANCE_RAD) -> Failure | None:
    """None when the joints captured after the image agree with those reached at rest, else
    a MOVING Failure saying which joint moved by how much."""
    delta = np.abs(np.asarray(captured, dtype=float) - np.asarray(reached, dtype=float))
    worst = int(np.argmax(delta))
    if delta[worst] <= tolerance:
        return None
    return Failure(ErrorCode.MOVING,
                   f'joint {worst + 1} captured {delta[worst] * 1e3:.3f} mrad from where the '
                   f'move ended (at most {tolerance * 1e3:.3f}): the arm was not at rest around '
                   'the image')


def take_hand_eye_views(plan: Sequence[Array], robot: RobotPort, camera: CameraPort,
                        chain: kinematics.Chain, *, hold: float, landmark_timeout: float,
                        cancelled: Cancelled = never,
                        on_view: ViewDone | None = None) -> HandEyeViews:
    """Visit every joint configuration of ``plan`` and keep the paired views (module
    docstring). ``chain``: the model whose FK of the captured joints gives T_base_flange (no
    tool); ``hold`` [s]: the joint capture; ``landmark_timeout`` [s]: for an image after the
    rest. ``on_view`` after each view. Raises Stopped (cancelled) and CaptureFailed (a joint
    capture that failed; the message names the view)."""
    views = HandEyeViews(planned=len(plan))
    for i, q in enumerate(plan):
        where = f'view {i + 1} of {len(plan)}'
        check_cancel(cancelled, where)
        try:
            why = _take_view(views, robot, camera, chain, q, hold, landmark_timeout)
        except CaptureFailed as e:
            raise CaptureFailed(f'{where}: {e}') from e
        if why is not None:
            views.skipped.append({'view': i, 'reason': why.message})
        if on_view is not None:
            on_view(i, why is None, views)
    return views


def _take_view(views: HandEyeViews, robot: RobotPort, camera: CameraPort,
               chain: kinematics.Chain, q: Array, hold: float, timeout: float
               ) -> Failure | None:
    """One view appended to ``views``: None if it was used, else a Failure saying why it was
    skipped."""
    try:
        reached = robot.move_joints(q)
    except MoveFailed as e:
        return Failure(ErrorCode.MOTION_FAILED, f'unreachable: {e}')
    rest_ns = camera.now_ns()
    try:
        image = camera.landmarks_after(rest_ns, lambda im: im.find('board') is not None,
                                       BOARD_IMAGES, timeout)
    except CaptureFailed as e:
        return Failure(ErrorCode.CAPTURE_FAILED, f'no image: {e}')
    board = image.find('board')
    if board is None:
        return Failure(ErrorCode.CAPTURE_FAILED, f'no board seen in {BOARD_IMAGES} images')
    capture = robot.capture(hold)
    problem = pairing_problem(reached, capture.q)
    if image.stamp_ns <= rest_ns:
        problem = Failure(ErrorCode.MOVING, 'the image is stamped before the arm came to rest '
                          f'({image.stamp_ns} ns)')
    if problem is not None:
        views.unpaired += 1
        return Failure(problem.code, f'unpaired: {problem.message}')
    views.joints.append(capture.q)
    views.flange.append(kinematics.fk(chain, capture.q))
    views.boards.append(board.T_optical_target)
    views.covariances.append(board.covariance)
    return None


@dataclass(frozen=True)
class HandEyeRun:
    """What a hand-eye calibration took and solved; ``gate_problem`` '' when the result may
    become active (core.landmarks.hand_eye.check_noise), else why not."""

    views: HandEyeViews
    result: HandEyeResult
    gate_problem: str


def noise_gate(result: HandEyeResult, covariances) -> str:
    """'' when the hand-eye may become active (check_noise), else why not."""
    try:
        return check_noise(result, covariances).problem
    except ValueError as e:
        return f'cannot check the residual against the views\' noise: {e}'


def calibrate_hand_eye(cell, model, robot: RobotPort, camera: CameraPort,
                       chain: kinematics.Chain, *, count: int, T_base_user, seed: int = 0,
                       hold: float, landmark_timeout: float, cancelled: Cancelled = never,
                       progress: ViewDone | None = None) -> HandEyeRun | Failure:
    """Plan ``count`` views of ``cell``'s board (hand_eye_views on ``model``'s nominal chain,
    the board where ``T_base_user`` (4, 4) puts it), take them (:func:`take_hand_eye_views`,
    the flange poses by ``chain``), solve and gate. Failures: INVALID_INPUT (no camera or
    board, no reachable view), TOO_FEW_POINTS (fewer than three views showed the board),
    DEGENERATE_POINTS / SOLVER_FAILED (the solve), CAPTURE_FAILED, CANCELED (before a view or
    after the last): nothing to store."""
    try:
        plan = hand_eye_views(cell, model, count, seed, T_base_user=T_base_user)
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    try:
        views = take_hand_eye_views(plan, robot, camera, chain, hold=hold,
                                    landmark_timeout=landmark_timeout, cancelled=cancelled,
                                    on_view=progress)
    except Stopped as e:
        return port_failure(e, '; nothing stored or published')
    except PortError as e:
        return port_failure(e)
    if views.used < MIN_VIEWS:
        return Failure(ErrorCode.TOO_FEW_POINTS, (
            f'only {views.used} of {count} views showed the board (at least {MIN_VIEWS} '
            f'needed); {len(views.skipped)} skipped: check the user frame, the lighting and '
            'landmark_detector'))
    result = solve_hand_eye(views.flange, views.boards, covariances=views.covariances)
    if not result:
        return result
    if cancelled():
        return Failure(ErrorCode.CANCELED,
                       f'cancelled after all {count} views; nothing stored or published')
    return HandEyeRun(views, result, noise_gate(result, views.covariances))
