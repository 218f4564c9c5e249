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

import time

from cobot_calib_msgs.action import CalibrateHandEye
from geometry_msgs.msg import TransformStamped
import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode as E
from cobot_calib_ros.core.landmarks.hand_eye import check_noise, hand_eye_views, solve_hand_eye
from cobot_calib_ros.core.landmarks.hand_eye_capture import (HandEyeViews,
                                                             take_hand_eye_views)
from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.core.provenance import missing_prerequisites
from cobot_calib_ros.core.robot_port import CaptureFailed, Stopped
from cobot_calib_ros.ros import convert, qos, results, spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.landmark_watch import LandmarkWatch
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.tf_static import StaticBroadcaster
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.store.records import HandEyeInputs, HandEyeRecord, HandEyeResult

Action = CalibrateHandEye
DEFAULT_VIEWS = 12


def _gate_problem(solved, covariances) -> str:
    """'' when the hand-eye may become active (core.landmarks.hand_eye.check_noise), else
    why not."""
    try:
        return check_noise(solved, covariances).problem
    except ValueError as e:
        return f'cannot check the residual against the views\' noise: {e}'


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

    def _cancelled(self, goal_handle, result, where: str):
        return self._end(goal_handle, result, E.CANCELED,
                         f'cancelled {where}; nothing stored or published')

    def _run(self, goal_handle):
        goal, result = goal_handle.request, Action.Result()
        count = int(goal.views) or DEFAULT_VIEWS
        hold = float(goal.hold) or self._p('hold_duration')
        if not (3 <= count <= 200) or not (0.0 < hold <= 10.0):
            return self._end(goal_handle, result, E.INVALID_INPUT,
                             f'views must be 3..200 (0 = {DEFAULT_VIEWS}) and hold 0..10 s, '
                             f'got {goal.views} and {goal.hold}')
        try:
            plan = hand_eye_views(self._cell, self._model, count, self._p('seed'),
                                  T_base_user=self._T_base_user())
            rig = self._rig('active')       # the flange poses by the active kinematics
            active, chain = rig.active, rig.chain('flange')
        except (KeyError, ValueError) as e:
            return self._end(goal_handle, result, E.INVALID_INPUT, str(e))
        through = {'kinematics': active.kinematics_label,
                   'intrinsics': active.label('intrinsics')}
        prerequisites = missing_prerequisites('the hand-eye is', through)
        if prerequisites:
            self.get_logger().warning(prerequisites)
        self._health.set(OK, f'calibrating: {count} views')
        t_start = time.monotonic()
        feedback = Action.Feedback(total=count)

        def on_view(i: int, used: bool, views: HandEyeViews) -> None:
            if not used:
                self.get_logger().warning(f'view {i}: skipped: {views.skipped[-1]["reason"]}')
            feedback.view_index, feedback.board_seen = i, used
            feedback.used, feedback.skipped = views.used, len(views.skipped)
            goal_handle.publish_feedback(feedback)

        self._robot.speed_scale = self._p('speed_scale')
        try:
            views = take_hand_eye_views(
                plan, self._robot, self._watch, chain, hold=hold,
                landmark_timeout=self._p('landmark_timeout'),
                cancelled=lambda: goal_handle.is_cancel_requested, on_view=on_view)
        except Stopped as e:
            return self._cancelled(goal_handle, result, str(e).removeprefix('cancelled '))
        except CaptureFailed as e:
            return self._end(goal_handle, result, E.CAPTURE_FAILED, str(e))
        joints, flange, boards = views.joints, views.flange, views.boards
        covariances, skipped = views.covariances, views.skipped
        result.views_used, result.views_skipped = len(boards), len(skipped)
        if len(boards) < 3:
            return self._end(goal_handle, result, E.TOO_FEW_POINTS,
                             f'only {len(boards)} of {count} views showed the board (at least '
                             f'3 needed); {len(skipped)} skipped: check the user frame, the '
                             'lighting and landmark_detector')
        solved = solve_hand_eye(flange, boards, covariances=covariances)
        if not solved:
            return self._end(goal_handle, result, solved.code, solved.message)
        if goal_handle.is_cancel_requested:
            return self._cancelled(goal_handle, result, f'after all {count} views')
        record = self._record(solved, joints, flange, boards, covariances, skipped, count,
                              through)
        gate = _gate_problem(solved, covariances)
        if gate:
            record['gate_problem'] = gate
        try:
            self._store.save_and_activate(record)   # with a gate problem: kept, rejected
        except (OSError, ValueError) as e:
            return self._end(goal_handle, result, E.STORAGE_FAILED,
                             f'could not store the hand-eye calibration: {e}')
        result.calibration_id = record['id']
        result.t_flange_optical = convert.matrix_to_transform(
            solved.T_flange_optical, '', '').transform
        result.residual_mm, result.residual_mrad = solved.residual_mm, solved.residual_mrad
        result.covariance = [float(v) for v in solved.covariance.ravel()]
        if gate:
            return self._end(goal_handle, result, E.SOLVER_FAILED, (
                f'{record["id"]} rejected, stored as rejected and not made active (the active '
                f'hand-eye is unchanged): {gate}'))
        self._publish(record)
        nominal = frames.transform_error(solved.T_flange_optical,
                                         self._cell.camera.T_flange_optical)
        return self._end(goal_handle, result, E.SUCCESS, (
            f'{record["id"]}: {len(boards)} views used, {len(skipped)} skipped '
            f'({views.unpaired} unpaired); residual RMS '
            f'{solved.residual_mm:.4f} mm / {solved.residual_mrad:.4f} mrad; '
            f'{nominal[0] * 1e3:.3f} mm / {nominal[1] * 1e3:.3f} mrad from the nominal '
            f'hand-eye; {time.monotonic() - t_start:.1f} s'
            + (f'; {prerequisites}' if prerequisites else '')))

    def _record(self, solved, joints, flange, boards, covariances, skipped, planned,
                through: dict[str, str]) -> dict:
        return HandEyeRecord(
            id=record_id('hand_eye'), stamp_ns=now_ns(self), method='park+least_squares',
            kinematics=through['kinematics'], measured_through=through,
            flange_frame=self._p('flange_frame'),
            camera_frame=self._cell.camera.frame_id, cell=self._results_cell.name,
            inputs=HandEyeInputs(joints=joints, T_base_flange=flange, T_optical_board=boards,
                                 board_covariances=covariances, skipped=skipped,
                                 planned_views=planned),
            result=HandEyeResult(T_flange_optical=solved.T_flange_optical,
                                 T_base_board=solved.T_base_board,
                                 initial_T_flange_optical=solved.initial,
                                 residual_mm=solved.residual_mm,
                                 residual_mrad=solved.residual_mrad,
                                 residuals_mm=solved.residuals_mm,
                                 residuals_mrad=solved.residuals_mrad,
                                 covariance=solved.covariance,
                                 views_used=len(boards))).to_dict()

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
