"""hand_eye_calibrator: the wrist camera's hand-eye (flange -> optical frame) from board views.

Action ``calibrate_hand_eye`` (cobot_calib_msgs/action/CalibrateHandEye): plans ``views`` views
of the cell's ChArUco board (core.landmarks.hand_eye.hand_eye_views: IK on the nominal chain
through the nominal hand-eye) and takes them with core.landmarks.hand_eye_capture.
take_hand_eye_views over the ROS ports (RobotCalls: ``move_to``, ``capture_joints``;
LandmarkWatch: ``landmarks``): for each one it moves there, takes the first board in an image
stamped after the arrival, captures the joints (``hold`` seconds) and takes the flange pose by
FK of the active kinematic calibration (nominal when none is active; the record's
``measured_through`` names it and the active intrinsics). A view that cannot be reached, shows
no board within ``landmark_timeout``, or whose captured joints are not where the move ended
(unpaired: the image may show another pose) is skipped and counted. A cancel is honoured
before every view.
The goal is one call of api.hand_eye.calibrate_and_store (the procedure core.landmarks.
hand_eye_capture.calibrate_hand_eye, the record and its activation).
With at least three views, core.landmarks.hand_eye.solve_hand_eye (closed form, then the joint
least-squares refinement of T_flange_optical and T_base_board, weighted by the landmarks'
covariances) gives the result; it is stored under ``<data_dir>/hand_eye`` (CalibrationStore:
atomic JSON, history, the newest active) and published latched on ``hand_eye``
(geometry_msgs/TransformStamped, flange_frame -> the camera's optical frame) and /tf_static.
A result whose residual is beyond what the views' noise allows (core.landmarks.hand_eye.
check_noise) is stored with its ``gate_problem``: the store keeps it as rejected (in the
history, never active; store.repository), it is not published, and the goal ends with
SOLVER_FAILED saying so.

Where the board is: the cell gives it in the user frame, so the views need T_base_user: the
``user_frame`` parameter ("x y z roll pitch yaw" [m, rad]) or, when empty, the active user-frame
calibration in data_dir. A few millimetres off only move the board in the image.

Parameters (read at start-up): cell_file, layout, data_dir, flange_frame, user_frame, seed;
hold_duration [s], speed_scale [1], landmark_timeout [s].
"""
from __future__ import annotations

from cobot_calib_msgs.action import CalibrateHandEye
from geometry_msgs.msg import TransformStamped
import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.api.hand_eye import (calibrate_and_store, HandEyeOutcome,
                                          HandEyeViewsRequest)
from cobot_calib_ros.core.errors import ErrorCode as E
from cobot_calib_ros.core.landmarks.hand_eye_capture import HandEyeViews
from cobot_calib_ros.ros import convert, qos, spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.landmark_watch import LandmarkWatch
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.tf_static import StaticBroadcaster
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.nodes.job_node import JobNode

Action = CalibrateHandEye
DEFAULT_VIEWS = 12


class HandEyeCalibrator(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('hand_eye_calibrator', job='a hand-eye calibration',
                         cell_help='Cell YAML (path or name): robot, camera (nominal '
                         'hand-eye), board', data_help='Results go to <data_dir>/hand_eye',
                         **kwargs)
        self._declare_parameters()
        self._store = self._repository().hand_eye
        self._read_board_frame()
        self._robot = RobotCalls(self._answers)
        self._watch = LandmarkWatch(lambda: now_ns(self), self._answers.node)
        self._pub = self.create_publisher(TransformStamped, 'hand_eye', qos.LATCHED)
        self._tf = StaticBroadcaster(self)
        self._health.watch(capture_retries=lambda: self._robot.capture_retries)
        self._server = ActionServer(
            self, Action, 'calibrate_hand_eye', execute_callback=self._on_goal,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        active = self._store.active()
        for warning in self._store.warnings:    # e.g. results from before keying by cell
            self.get_logger().warning(warning)
        if active is not None:
            self._publish(active)
        problem = '' if self._cell.camera and self._cell.landmarks and \
            self._cell.landmarks.board else 'the cell has no wrist camera or no board'
        self._health.set(WARN if problem else OK, problem or 'idle',
                         active_id=active['id'] if active else '')
        self.get_logger().info(f'hand-eye calibrations in {self._store.directory}'
                               + (f'; {problem}' if problem else ''))

    def _declare_parameters(self) -> None:
        read_once(self, 'flange_frame', 'flange', 'tf frame of the flange (parent of the '
                  'camera frame on hand_eye and /tf_static)')
        read_once(self, 'seed', 0, 'Seed of the view plan [1]', 0, 2 ** 31 - 1)
        declare(self, 'hold_duration', 0.2, 'Joints are averaged over this hold at every '
                'view [s]', 0.005, 10.0)
        declare(self, 'speed_scale', 1.0, 'Fraction of the joint velocity limits [1]',
                0.01, 1.0)
        declare(self, 'landmark_timeout', 5.0, 'A view without a board in an image after '
                'this long [s] is skipped', 0.1, 120.0)

    def _on_goal(self, goal_handle):
        return self._exclusive(goal_handle, self._run, Action.Result)

    def _run(self, goal_handle):
        goal, result = goal_handle.request, Action.Result()
        request = HandEyeViewsRequest(int(goal.views) or DEFAULT_VIEWS,
                                      float(goal.hold) or self._p('hold_duration'),
                                      self._p('landmark_timeout'), self._p('seed'))
        try:
            rig, T_base_user = self._rig('active'), self._T_base_user()
        except (KeyError, ValueError) as e:
            return self._end(goal_handle, result, E.INVALID_INPUT, str(e))
        feedback = Action.Feedback(total=request.count)

        def on_view(i: int, used: bool, views: HandEyeViews) -> None:
            if not used:
                self.get_logger().warning(f'view {i}: skipped: {views.skipped[-1]["reason"]}')
            feedback.view_index, feedback.board_seen = i, used
            feedback.used, feedback.skipped = views.used, len(views.skipped)
            goal_handle.publish_feedback(feedback)
        self._health.set(OK, f'calibrating: {request.count} views')
        self._robot.speed_scale = self._p('speed_scale')
        outcome = calibrate_and_store(
            request, self._robot, self._watch, rig, self._repository(), T_base_user,
            now_ns(self), flange_frame=self._p('flange_frame'),
            cancelled=lambda: goal_handle.is_cancel_requested, progress=on_view,
            warn=self.get_logger().warning)
        if outcome:
            self._answered(result, outcome)
        return self._end(goal_handle, result, outcome.code, outcome.message)

    def _answered(self, result, outcome: HandEyeOutcome) -> None:
        """The result fields of a stored hand-eye ([m, rad]; the _mm / _mrad ones in mm and
        mrad); an active one published."""
        solved, views = outcome.run.result, outcome.run.views
        result.views_used, result.views_skipped = views.used, len(views.skipped)
        result.calibration_id = outcome.record.id
        result.t_flange_optical = convert.matrix_to_transform(
            solved.T_flange_optical, '', '').transform
        result.residual_mm = solved.residual_m * 1e3
        result.residual_mrad = solved.residual_rad * 1e3
        result.covariance = [float(v) for v in solved.covariance.ravel()]
        if outcome.code == E.SUCCESS:
            self._publish(outcome.record.to_dict())

    def _publish(self, record: dict) -> None:
        stamp = self.get_clock().now().to_msg()
        msg = convert.matrix_to_transform(np.array(record['result']['T_flange_optical']),
                                          record.get('flange_frame', self._p('flange_frame')),
                                          record.get('camera_frame', ''), stamp)
        self._pub.publish(msg)
        try:
            self._tf.send(msg)
        except (TypeError, ValueError) as e:
            self.get_logger().error(f'hand-eye not on /tf_static: {e}')


def main(args=None) -> None:
    spin.run(HandEyeCalibrator, args, threads=2)


if __name__ == '__main__':
    main()
