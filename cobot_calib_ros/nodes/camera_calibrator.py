"""camera_calibrator: the wrist camera's intrinsics (K, D) from views of the cell's ChArUco board.

Action ``calibrate_intrinsics`` (cobot_calib_msgs/action/CalibrateIntrinsics):

- ``source: ''`` with ``planned: true``: the arm moves the camera through ``views`` planned views
  (core.landmarks.intrinsics_views: the board over the whole image at many tilts, IK on the
  nominal chain) and each view's first image stamped after the arrival (``wrist_camera/
  image_raw``, ros.image_watch) is searched for the board (core.landmarks.intrinsics_capture);
  feedback after every view: views with the board, the image coverage and what is missing
  (image regions, tilts, judged with the nominal intrinsics). A cancel is honoured before
  every view; nothing is stored then.
- ``source``: a folder of images (the same detection). A bag: ``cobot-calib intrinsics BAG``.
- ``source: ''`` with ``planned: false``: the live topic while the user moves the board (or
  the camera): every image is searched and kept as a view when it differs from the views kept
  (core.landmarks.intrinsics_capture.take_live_views), until ``views`` views or
  ``live_timeout``; the same feedback after every view kept.

The goal is one call of api.intrinsics.calibrate_on_cell (the procedures of core.landmarks.
intrinsics_capture, then api.intrinsics.store_run: the YAML's one writer, the record).
core.landmarks.intrinsics.calibrate_intrinsics fits ``model`` (plumb_bob, rational_polynomial,
equidistant); the camera_info YAML goes to ``<data_dir>/intrinsics/<id>.yaml`` and the record
(store.records.IntrinsicsRecord) to the cell's store, active for the camera only if its gate
passes (else kept as rejected: REJECTED). landmark_detector uses the active intrinsics.

Parameters (read at start-up): cell_file, layout, data_dir, user_frame (as hand_eye_calibrator:
where the board is; empty = the active user-frame calibration), seed; speed_scale [1],
image_timeout [s], live_timeout [s].
"""
from __future__ import annotations

import time

from cobot_calib_msgs.action import CalibrateIntrinsics
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.api.intrinsics import (calibrate_on_cell, DEFAULT_VIEWS,
                                            IntrinsicsOutcome, IntrinsicsRequest)
from cobot_calib_ros.core.landmarks.intrinsics import Coverage
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.image_watch import ImageWatch
from cobot_calib_ros.ros.images import model_to_camera_info
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns

Action = CalibrateIntrinsics


class CameraCalibrator(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('camera_calibrator', job='an intrinsics calibration',
                         cell_help='Cell YAML (path or name): robot, camera (nominal '
                         'intrinsics), board', data_help='Results go to <data_dir>/intrinsics',
                         **kwargs)
        self._declare_parameters()
        self._read_board_frame()
        self._robot = RobotCalls(self._answers)
        self._images = ImageWatch(lambda: now_ns(self), self._answers.node)
        self._server = ActionServer(
            self, Action, 'calibrate_intrinsics', execute_callback=self._on_goal,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        problem = '' if self._cell.camera and self._cell.landmarks and \
            self._cell.landmarks.board else 'the cell has no wrist camera or no board'
        self._health.set(WARN if problem else OK, problem or 'idle')
        self.get_logger().info(f'intrinsics of {self._camera_name()} in {self._root}'
                               + (f'; {problem}' if problem else ''))

    def _declare_parameters(self) -> None:
        read_once(self, 'seed', 0, 'Seed of the view plan [1]', 0, 2 ** 31 - 1)
        declare(self, 'speed_scale', 1.0, 'Fraction of the joint velocity limits [1]',
                0.01, 1.0)
        declare(self, 'image_timeout', 5.0, 'A view without an image after this long [s] '
                'fails the capture', 0.1, 120.0)
        declare(self, 'live_timeout', 300.0, 'Live views (the user moving the board) are '
                'collected for at most this long [s]', 1.0, 3600.0)

    def _camera_name(self) -> str:
        return self._cell.camera.frame_id if self._cell.camera else 'camera'

    def _on_goal(self, goal_handle):
        return self._exclusive(goal_handle, self._run, Action.Result)

    def _run(self, goal_handle):
        goal, result = goal_handle.request, Action.Result()
        request = IntrinsicsRequest(goal.model or 'plumb_bob', int(goal.views) or DEFAULT_VIEWS,
                                    goal.source, goal.planned, self._p('seed'),
                                    self._p('image_timeout'))
        feedback = Action.Feedback(total=request.count)

        def on_view(views: int, total: int, coverage: Coverage) -> None:
            feedback.views, feedback.coverage = views, coverage.fraction
            feedback.missing = coverage.message
            goal_handle.publish_feedback(feedback)
        end = time.monotonic() + self._p('live_timeout')
        self._robot.speed_scale = self._p('speed_scale')
        self._health.set(OK, f'calibrating: {request.count} views')
        try:
            outcome = calibrate_on_cell(
                request, self._cell, self._model, self._robot, self._images,
                T_base_user=self._T_base_user, repo=self._repository(), data_dir=self._root,
                wall_ns=now_ns(self), live_deadline=lambda: time.monotonic() > end,
                cancelled=lambda: goal_handle.is_cancel_requested, progress=on_view)
        finally:
            self._images.release()
        if outcome:
            _fill(result, outcome)
        return self._end(goal_handle, result, outcome.code, outcome.message)


def _fill(result, outcome: IntrinsicsOutcome) -> None:
    """The result fields of stored intrinsics."""
    fit = outcome.run.fit
    result.calibration_id, result.yaml_path = outcome.record.id, outcome.record.result.yaml_path
    result.camera_info = model_to_camera_info(fit.camera, fit.camera.name)
    result.rms_px, result.heldout_rms_px = fit.rms_px, fit.heldout_rms_px
    result.views_used, result.outlier_views = fit.views_used, list(fit.outlier_views)
    result.active = outcome.active


def main(args=None) -> None:
    spin.run(CameraCalibrator, args, threads=2)


if __name__ == '__main__':
    main()
