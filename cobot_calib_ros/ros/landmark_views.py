"""Landmark user frames measured live over ROS (core.landmarks.views does the planning and fit).

Used by user_frame_solver (calibrate_user_frame, ``landmark_single`` / ``landmark_multi``) and
by repeatability_trial (a landmark method's frame M_n in every cycle). Each planned view is
visited (move_to), the joints captured (capture_joints), and the first ``landmarks`` message
of an image stamped after the capture (ROS time) gives T_optical_marker;
T_base_marker = FK(captured joints; model chain with the hand-eye as tool) @ T_optical_marker.

The hand-eye used is the active one of hand_eye_calibrator (``<data_dir>/hand_eye``) when there
is one, else the cell's nominal ``camera: hand_eye``: :func:`active_hand_eye`.
"""
from __future__ import annotations

from pathlib import Path
import threading
import time
from typing import Callable

from cobot_calib_msgs.msg import Landmarks
import numpy as np
from sensor_msgs.msg import JointState

from cobot_calib_ros import store
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.landmarks import views
from cobot_calib_ros.core.user_frame import landmarks as landmark_frames
from cobot_calib_ros.ros import convert, marks
from cobot_calib_ros.ros.robot_calls import MOVE_TIMEOUT, RobotCallError, RobotCalls
from cobot_calib_ros.ros.spin import Companion
from cobot_calib_ros.ros.time import header_ns

LANDMARK_TIMEOUT = 5.0   # [s] of wall time for a landmarks message stamped after a capture
LANDMARK_MESSAGES = 3    # messages after a capture looked at before a marker counts as unseen


class LandmarkViewError(RuntimeError):
    """A landmark frame that could not be measured; ``code`` is an ErrorCode."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


def active_hand_eye(data_dir: Path, cell) -> tuple[np.ndarray, str]:
    """(T_flange_optical, its label): the active stored hand-eye calibration, else the cell's
    nominal one ('nominal')."""
    try:
        record = store.open(data_dir).hand_eye.active()
    except (OSError, ValueError):
        record = None
    if record is not None:
        X = np.array(record['result']['T_flange_optical'], dtype=float)
        if X.shape == (4, 4) and np.all(np.isfinite(X)):
            return X, record['id']
    return np.asarray(cell.camera.T_flange_optical, dtype=float), 'nominal'


class LandmarkViews:
    """Measures a landmark frame by moving the robot; every call blocks the caller's thread
    (the answers and the ``landmarks`` messages arrive on ``answers``' thread)."""

    def __init__(self, answers: Companion, robot: RobotCalls, cell, model,
                 now_ns: Callable[[], int]) -> None:
        self._answers, self._robot = answers, robot
        self._cell, self._model, self._now_ns = cell, model, now_ns
        self._cond = threading.Condition()
        self._msgs: list[Landmarks] = []
        self._sub = None
        # every view's capture, as kinematic_identifier publishes its poses: a recorded session
        # (images, camera_info, these marks) can be fitted again (bags/README.md)
        self._captures = answers.node.create_publisher(JointState, marks.CAPTURES, 100)

    def problem(self) -> str:
        """'' when the cell has a camera and landmarks, else what to add to the cell file."""
        cell = self._cell
        if cell.camera is None or cell.landmarks is None or not cell.landmarks.markers:
            return (f'cell {cell.name!r} has no wrist camera or no landmarks; add camera: and '
                    'landmarks: markers: to the cell file')
        return ''

    def frame(self, method: str, guess: np.ndarray, chain: kinematics.Chain,
              X_plan: np.ndarray, capture_duration: float, *, max_rms_error: float,
              max_scale_error: float) -> landmark_frames.LandmarkFit:
        """The landmark method's fit. ``guess``: T_base_user to plan views by; ``chain``: the
        model (its tool: the hand-eye) that maps captured joints to camera poses; ``X_plan``:
        the hand-eye the views are planned with. LandmarkViewError when it cannot be had."""
        problem = self.problem()
        if problem:
            raise LandmarkViewError(ErrorCode.INVALID_INPUT, f'{method}: {problem}')
        observations = []
        plan = views.plan_views(method, self._cell, self._model.chain(tool=X_plan), guess,
                                np.asarray(self._cell.home, dtype=float))
        for marker_id, q in plan:
            T_base_optical, msg = self._observe(chain, q, marker_id, capture_duration)
            observations += [views.observation(lm.id, T_base_optical,
                                               convert.pose_to_matrix(lm.pose.pose),
                                               lm.pose.covariance)
                             for lm in msg.landmarks if lm.kind == lm.KIND_MARKER]
        result = views.landmark_frame(method, self._cell, observations,
                                      max_rms_error=max_rms_error,
                                      max_scale_error=max_scale_error)
        if result.code in (ErrorCode.INVALID_INPUT, ErrorCode.CAPTURE_FAILED):
            raise LandmarkViewError(result.code, result.message)
        return result

    def _observe(self, chain, q, marker_id: int, capture_duration: float):
        """Move to ``q``, capture the joints, and wait for landmarks of an image stamped after
        the capture: (T_base_optical by FK of the captured joints, the first message showing
        ``marker_id``, else the last of LANDMARK_MESSAGES)."""
        self._subscribe()
        with self._cond:        # older images cannot count; later ones are kept from here on
            self._msgs.clear()
        try:
            self._robot.move_joints(q, MOVE_TIMEOUT)
            capture = self._robot.capture(capture_duration)
        except RobotCallError as e:
            raise LandmarkViewError(ErrorCode.CAPTURE_FAILED,
                                    f'view of landmark {marker_id}: {e}')
        captured = capture.position
        t0 = self._now_ns()
        self._publish_capture(marker_id, capture, t0)
        deadline = time.monotonic() + LANDMARK_TIMEOUT
        seen, last = 0, None
        with self._cond:
            while seen < LANDMARK_MESSAGES:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                if not self._msgs:
                    self._cond.wait(remaining)
                    continue
                msg = self._msgs.pop(0)
                stamp = header_ns(msg)
                if stamp <= t0:
                    continue
                seen, last = seen + 1, msg
                if any(lm.id == marker_id and lm.kind == lm.KIND_MARKER
                       for lm in msg.landmarks):
                    break
        if last is None:
            raise LandmarkViewError(ErrorCode.CAPTURE_FAILED, (
                f'no landmarks message within {LANDMARK_TIMEOUT:.0f} s of the capture at '
                f'landmark {marker_id}; are mock_camera / the camera driver and '
                'landmark_detector up?'))
        return kinematics.fk(chain, captured), last

    def _publish_capture(self, marker_id: int, capture, stamp_ns: int) -> None:
        """The view's mark: header.stamp = the time after which landmarks count (ROS time),
        frame_id = 'landmark_<id>' (the marker the view is planned for), name/position = the
        captured joints [rad], effort = their standard deviation."""
        self._captures.publish(marks.capture_mark(f'landmark_{marker_id}',
                                                  self._model.joint_names, capture.position,
                                                  capture.std, stamp_ns))

    def _subscribe(self) -> None:
        """The landmarks subscription on the answers' thread (made on first use)."""
        if self._sub is not None:
            return

        def take(msg) -> None:
            with self._cond:
                self._msgs.append(msg)
                del self._msgs[:-20]
                self._cond.notify_all()

        self._sub = self._answers.node.create_subscription(Landmarks, 'landmarks', take, 10)
