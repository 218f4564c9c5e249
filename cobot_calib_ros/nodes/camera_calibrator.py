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

from cobot_calib_ros.core.errors import ErrorCode as E, Refusal
from cobot_calib_ros.core.landmarks.camera import camera_info_yaml
from cobot_calib_ros.core.landmarks.intrinsics import (calibrate_intrinsics, image_coverage,
                                                       MODELS, solve_view_pose)
from cobot_calib_ros.core.landmarks.intrinsics_capture import (take_intrinsics_views,
                                                                take_live_views)
from cobot_calib_ros.core.landmarks.intrinsics_views import detect_views, intrinsics_views
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.core.robot_port import CaptureFailed, Stopped
from cobot_calib_ros.loaders.images import folder_images
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.image_watch import ImageWatch
from cobot_calib_ros.ros.images import model_to_camera_info
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.store.files import atomic_write_text, ensure_dir
from cobot_calib_ros.store.records import IntrinsicsRecord

Action = CalibrateIntrinsics
DEFAULT_VIEWS = 20


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
        model = goal.model or 'plumb_bob'
        count = int(goal.views) or DEFAULT_VIEWS
        if model not in MODELS or not 4 <= count <= 200:
            return self._end(goal_handle, result, E.INVALID_INPUT,
                             f'model must be one of {", ".join(MODELS)} (got {model!r}) and '
                             f'views 4..200 (0 = {DEFAULT_VIEWS}), got {goal.views}')
        if self._cell.camera is None or self._cell.landmarks is None or \
                not self._cell.landmarks.board:
            return self._end(goal_handle, result, E.INVALID_INPUT,
                             f'cell {self._cell.name!r} has no wrist camera or no board; add '
                             'camera: and landmarks: board: to the cell file')
        spec = BoardSpec.parse(self._cell.landmarks.board)
        try:
            if goal.source:
                views, skipped, size = self._from_folder(goal.source, spec)
            elif goal.planned:
                views, skipped, size = self._planned(goal_handle, count, spec)
            else:
                views, skipped, size = self._live(goal_handle, count, spec)
        except Refusal as e:
            return self._end(goal_handle, result, e.failure.code, str(e))
        except ValueError as e:
            return self._end(goal_handle, result, E.INVALID_INPUT, str(e))
        except Stopped as e:
            return self._end(goal_handle, result, E.CANCELED, f'{e}; nothing stored')
        except CaptureFailed as e:
            return self._end(goal_handle, result, E.CAPTURE_FAILED, str(e))
        try:
            fit = calibrate_intrinsics(views, size, model, name=self._camera_name())
        except Refusal as e:
            return self._end(goal_handle, result, e.failure.code,
                             f'{e} ({len(skipped)} views skipped)')
        return self._store(goal_handle, result, fit, spec, views, goal.source or 'live')

    def _from_folder(self, source: str, spec: BoardSpec):
        from pathlib import Path
        if not Path(source).is_dir():
            raise ValueError(f'source {source!r} is not a folder of images (a bag: run '
                             '`cobot-calib intrinsics BAG`)')
        views, skipped, size = detect_views(folder_images(source), spec)
        if size is None:
            raise ValueError(f'{source}: no images')
        return views, skipped, size

    def _feedback(self, goal_handle, count: int):
        """on_view of the captures: views, coverage and what is missing (judged with the
        nominal intrinsics) as the action's feedback."""
        nominal = self._cell.camera.camera_model()
        feedback = Action.Feedback(total=count)

        def on_view(_, views, skipped) -> None:
            poses = {v.name: solve_view_pose(nominal, v) for v in views}
            coverage = image_coverage(views, poses, (nominal.width, nominal.height))
            feedback.views, feedback.coverage = len(views), coverage.fraction
            feedback.missing = coverage.message
            goal_handle.publish_feedback(feedback)
        return on_view

    def _planned(self, goal_handle, count: int, spec: BoardSpec):
        plan = intrinsics_views(self._cell, self._model, count, self._p('seed'),
                                T_base_user=self._T_base_user())
        self._robot.speed_scale = self._p('speed_scale')
        self._health.set(OK, f'calibrating: {count} planned views')
        try:
            return take_intrinsics_views(plan, self._robot, self._images, spec,
                                         cancelled=lambda: goal_handle.is_cancel_requested,
                                         on_view=self._feedback(goal_handle, count),
                                         image_timeout=self._p('image_timeout'))
        finally:
            self._images.release()

    def _live(self, goal_handle, count: int, spec: BoardSpec):
        end = time.monotonic() + self._p('live_timeout')
        self._health.set(OK, f'calibrating: {count} live views')
        try:
            return take_live_views(self._images, spec, count,
                                   deadline=lambda: time.monotonic() > end,
                                   cancelled=lambda: goal_handle.is_cancel_requested,
                                   on_view=self._feedback(goal_handle, count),
                                   image_timeout=self._p('image_timeout'))
        finally:
            self._images.release()

    def _store(self, goal_handle, result, fit, spec, views, source: str):
        record = IntrinsicsRecord.from_fit(fit, camera=fit.camera.name, source=source,
                                           board=str(spec), views=[v.name for v in views],
                                           wall_ns=now_ns(self))
        folder = self._root / 'intrinsics'
        try:
            ensure_dir(folder)
            path = folder / f'{record.id}.yaml'
            atomic_write_text(path, camera_info_yaml(fit.camera))
            record.result.yaml_path = str(path)
            outcome = self._repository().intrinsics.save_and_activate(record)
        except (OSError, ValueError) as e:
            return self._end(goal_handle, result, E.STORAGE_FAILED,
                             f'could not store the intrinsics: {e}')
        result.calibration_id, result.yaml_path = record.id, record.result.yaml_path
        result.camera_info = model_to_camera_info(fit.camera, fit.camera.name)
        result.rms_px, result.heldout_rms_px = fit.rms_px, fit.heldout_rms_px
        result.views_used, result.outlier_views = fit.views_used, list(fit.outlier_views)
        result.active = bool(outcome)
        K = fit.camera.K
        summary = (f'{record.id}: fx {K[0, 0]:.3f} fy {K[1, 1]:.3f} cx {K[0, 2]:.3f} '
                   f'cy {K[1, 2]:.3f} px, rms {fit.rms_px:.4f} px, held out '
                   f'{fit.heldout_rms_px:.4f} px, {fit.views_used} views')
        if not outcome:
            return self._end(goal_handle, result, E.IMPLAUSIBLE_FIT,
                             f'{summary}; stored as rejected, not active: {outcome.reason}')
        return self._end(goal_handle, result, E.SUCCESS, f'{summary}; active')


def main(args=None) -> None:
    spin.run(CameraCalibrator, args, threads=2)


if __name__ == '__main__':
    main()
