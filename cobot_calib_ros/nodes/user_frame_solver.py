"""user_frame_solver: the calibrate_user_frame service, point conversion, durable history.

calibrate_user_frame translates the request (SI, the node's parameters) into one call of
api.user_frame.calibrate, the path `cobot-calib user-frame --points` takes too (the procedure
is core.user_frame.procedure's: touches over ros.robot_calls, the FK of captures, fit, gate;
then the record, store and activation), and the answer back; set_active_calibration is
api.user_frame.choose. It is served on its own executor thread (a spin.Companion): a live
calibration that visits points blocks only that thread, so user_to_robot, robot_to_user,
list_calibrations and set_active_calibration keep answering meanwhile.

The active calibration (store.calibrations: chosen with set_active_calibration, else the newest
non-retired one) is what conversions use by default, and what is latched on `user_frame` and,
as base_frame -> user_frame, on /tf_static: on start-up and whenever it changes. Only the
node's own thread publishes (it may replace a publisher to unlatch a retired frame); the
calibrator hands that over with a task on the node's executor.

Landmark methods (issue 11; point_names ignored): ``landmark_single`` and ``landmark_multi``
move the robot to views of the cell's fiducials planned around the active user frame and fit
the frame to what the wrist camera sees (core.landmarks.views.measure_frame over ros.robot_calls
and ros.landmark_watch), with the active hand-eye calibration (nominal if none); the record
names the hand-eye used. Live captures of named points are touched by the operator, who
confirms with ``user_frame_solver/confirm_touch`` (on the mock cell: mock_robot/hand_guide).
"""
from __future__ import annotations

import functools
import threading

from cobot_calib_msgs.msg import UserFrameCalibration
from cobot_calib_msgs.srv import (CalibrateUserFrame, ConvertPoints, ListCalibrations,
                                  SetActiveCalibration)
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from visualization_msgs.msg import MarkerArray

from cobot_calib_ros.api import user_frame as user_frame_api
from cobot_calib_ros.core import frames, user_frame
from cobot_calib_ros.core.cell import check_frame_id
from cobot_calib_ros.core.drift import DriftLimits
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.user_frame.procedure import Gate
from cobot_calib_ros.ros import convert, markers, qos, results, spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, OK, status_name, WARN
from cobot_calib_ros.ros.params import declare
from cobot_calib_ros.ros.landmark_views import CaptureMarks
from cobot_calib_ros.ros.landmark_watch import LandmarkWatch
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.ros.tf_static import StaticBroadcaster
from cobot_calib_ros.ros.user_frame_msg import record_to_msg
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.store.history import user_frame_change
from cobot_calib_ros.store.records import UserFrameRecord

Choice = SetActiveCalibration
FRAME_PARAMETERS = ('base_frame', 'user_frame')
PUBLISH_TIMEOUT = 10.0   # [s] the calibrator waits this long for the node thread to publish


def frames_problem(base: tuple[str, str], user: tuple[str, str]) -> Failure | None:
    """None if the (source, frame id) pairs can be base -> user on /tf_static, else an
    INVALID_INPUT Failure saying why not."""
    for source, frame_id in (base, user):
        why = check_frame_id(frame_id)
        if why is not None:
            return Failure(why.code, f'{source}: {why.message}')
    if base[1] == user[1]:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'{base[0]} and {user[0]} are both {base[1]!r}: the user frame needs a '
                       'frame id of its own')
    return None


class UserFrameSolver(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('user_frame_solver', job='a calibration',
                         cell_help='Cell YAML (path or name): named points and the nominal '
                         'tool offset', layout_help='Marker layout of the named points (close '
                         '| wide); empty = the cell file default',
                         data_help='Where calibrations are stored', **kwargs)
        self._declare_parameters()
        # results are this cell's: its user frames, hand-eye and kinematics (store.cells)
        self._store = self._repository().user_frames
        self._store_lock = threading.Lock()     # the calibrator thread writes, this one reads
        # '<node>: drift': the newest calibration against the one active before it
        self._drift = Diagnostics(self, name=status_name(self, 'drift'))
        self._drift.set(OK, 'no calibration compared yet')
        self._last_refusal = ''
        self._tf_problem = ''                   # why the active calibration is not on /tf_static
        self._latched_id: str | None = None     # the calibration latched now (None: nothing)
        # a live calibration blocks in its service callback while the robot moves and
        # captures: it runs on the calibrator's thread, the answers it waits for arrive on
        # the clients' thread, and this node's own services stay free
        self._calibrator = spin.Companion(self, 'calibrator')
        self._robot = RobotCalls(self._answers, operator=self.get_name())
        self._health.watch(capture_retries=lambda: self._robot.capture_retries)
        self._camera = LandmarkWatch(lambda: now_ns(self), self._answers.node)
        self._marks = CaptureMarks(self._answers.node, self._model.joint_names)
        self._pub = self.create_publisher(UserFrameCalibration, 'user_frame', qos.LATCHED)
        self._markers = self.create_publisher(MarkerArray, markers.TOPIC, markers.QOS)
        self._tf = StaticBroadcaster(self)
        self._calibrator.node.create_service(CalibrateUserFrame, 'calibrate_user_frame',
                                             self._on_calibrate)
        self.create_service(ConvertPoints, 'user_to_robot', self._on_user_to_robot)
        self.create_service(ConvertPoints, 'robot_to_user', self._on_robot_to_user)
        self.create_service(ListCalibrations, 'list_calibrations', self._on_list)
        self.create_service(SetActiveCalibration, 'set_active_calibration', self._on_set_active)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(lambda _: self._update_health())
        self._startup_checks()
        self._publish_active()

    def destroy_node(self):
        self._calibrator.destroy()
        return super().destroy_node()

    def _declare_parameters(self) -> None:
        declare(self, 'base_frame', 'base_link', 'Robot base frame id of new calibrations '
                'whose request gives none (tf2 frame id: letters, digits, _ and /)')
        declare(self, 'user_frame', 'user_frame', 'User (work surface) frame id of new '
                'calibrations whose request gives none (tf2 frame id, not base_frame)')
        declare(self, 'kinematics', 'latest', 'Kinematic model that maps captured joints to '
                'points: latest (the active kinematic calibration of kinematic_identifier, '
                'the nominal model if there is none), nominal, or a kinematic calibration id')
        declare(self, 'capture_duration', 0.5, 'Hold window of each live capture [s]',
                0.01, 10.0)
        declare(self, 'robust_threshold', 5.0e-4,
                'Robust method: never reject a point whose residual is below this [m]; above '
                'it a point is rejected when the others predict it significantly worse than '
                'the noise allows (leverage-aware test)', 0.0, 0.1)
        declare(self, 'max_rms_error', 1.0e-3,
                'Largest RMS residual of a calibration that is accepted; a worse fit (units? '
                'point order?) is refused with IMPLAUSIBLE_FIT, and so is a single residual '
                'above 3 times this [m]', 1e-6, 0.1)
        limits = DriftLimits()
        declare(self, 'drift_k', limits.k, 'Drift: a frame change counts only beyond this many '
                'of its standard errors (from the two calibrations\' shared points) [1]',
                0.0, 100.0)
        for name, value, what in (('drift_warn_m', limits.warn_m, 'WARN [m]'),
                                  ('drift_error_m', limits.error_m, 'ERROR [m]'),
                                  ('drift_warn_rad', limits.warn_rad, 'WARN [rad]'),
                                  ('drift_error_rad', limits.error_rad, 'ERROR [rad]')):
            declare(self, name, value, 'Drift: the frame change (translation or rotation) '
                    f'beyond drift_k standard errors AND this raises {what} on /diagnostics',
                    0.0, 1.0)
        declare(self, 'max_scale_error', 0.01,
                'Tolerance of |scale - 1| of the fitted matrix (five_point_lsq): a scale off 1 by '
                'more than this AND by more than its noise allows (k standard errors, 0.5 % '
                'false refusals) is refused with IMPLAUSIBLE_FIT [1]', 1e-4, 1.0)

    # -- frame ids -------------------------------------------------------------------------
    def _frame_parameters_problem(self) -> Failure | None:
        return frames_problem(*((f'parameter {n}', self._p(n)) for n in FRAME_PARAMETERS))

    def _startup_checks(self) -> None:
        problem = self._frame_parameters_problem()
        if problem is not None:   # given with -p or --params-file: refused per request
            self.get_logger().error(f'{problem.message}; calibrations that do not name their '
                                    'frames are refused until it is set right (ros2 param set)')

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Refuse a base_frame / user_frame that tf2 would not accept, with the reason. Only
        the values being set are checked: a bad one from start-up must not block the fix."""
        new = {p.name: p.value for p in params if p.name in FRAME_PARAMETERS}
        whys = [f'{name}: {why.message}' for name, value in new.items()
                if (why := check_frame_id(value)) is not None]
        merged = {n: new.get(n, self._p(n)) for n in FRAME_PARAMETERS}
        if new and not whys and merged['base_frame'] == merged['user_frame']:
            whys.append(f'base_frame and user_frame would both be {merged["user_frame"]!r}: '
                        'the user frame needs a frame id of its own')
        return SetParametersResult(successful=not whys, reason='; '.join(whys))

    def _request_frames(self, request) -> tuple[str, str]:
        pairs = [(f'request {n}', value) if value else (f'parameter {n}', self._p(n))
                 for n, value in zip(FRAME_PARAMETERS, (request.base_frame, request.user_frame))]
        why = frames_problem(*pairs)
        if why is not None:
            raise Refusal(why)
        return pairs[0][1], pairs[1][1]

    # -- calibrate ------------------------------------------------------------------------
    def _on_calibrate(self, request, response):
        try:
            outcome = user_frame_api.calibrate(
                self._repository(), self._cell, self._request(request), stamp_ns=now_ns(self),
                robot=self._robot, camera=self._camera, model=self._model,
                frames_store=self._store, lock=self._store_lock, on_view=self._marks)
        except Refusal as e:
            outcome = e.failure
        if not outcome:
            return self._refuse(response, outcome)
        if outcome.prerequisites:
            self.get_logger().warning(outcome.prerequisites)
        self._report_drift(outcome.previous, outcome.record)
        response.calibration = record_to_msg(outcome.record)
        results.answer(response, ErrorCode.SUCCESS, outcome.message)
        self._publish_from_another_thread(response.calibration)
        fit = outcome.measured.fit
        spin.log_info(self.get_logger(), f'{outcome.record["id"]}: {len(fit.residuals)} '
                      f'points, rms {fit.rms * 1e3:.4f} mm, max {fit.max_residual * 1e3:.4f} mm')
        return response

    def _request(self, request) -> user_frame_api.Request:
        """The service request in SI, with the node's parameters; Refusal INVALID_INPUT for
        frame ids tf2 would not accept or joint captures that do not fit the names."""
        gate = Gate(self._p('max_rms_error'), self._p('max_scale_error'),
                    self._p('robust_threshold'), request.fit_surface)
        names = list(request.point_names)
        return user_frame_api.Request(
            method=request.method, names=tuple(names),
            p_user=convert.points_to_array(request.points_user),
            p_base=convert.points_to_array(request.points_base),
            joints=self._given_joints(names, request.joint_captures)
            if request.joint_captures else None,
            kinematics=request.kinematics or self._p('kinematics'),
            frames=self._request_frames(request), gate=gate,
            capture_duration=self._p('capture_duration'))

    def _report_drift(self, previous, record) -> None:
        """The drift status: the new frame against the previously active one (store.history:
        beyond drift_k standard errors AND the tolerance: WARN, or ERROR)."""
        if previous is None:
            return
        change = user_frame_change(previous, record, DriftLimits(
            self._p('drift_k'), self._p('drift_warn_m'), self._p('drift_error_m'),
            self._p('drift_warn_rad'), self._p('drift_error_rad')))
        self._drift.set(change.level, change.message, calibration=record['id'],
                        previous=previous['id'], moved_mm=f'{change.translation_m * 1e3:.4f}',
                        sigma_mm=f'{change.sigma_translation_m * 1e3:.4f}',
                        turned_mrad=f'{change.rotation_rad * 1e3:.4f}',
                        sigma_mrad=f'{change.sigma_rotation_rad * 1e3:.4f}')
        if change.level != OK:
            self.get_logger().warning(change.message)

    def _refuse(self, response, failure: Failure):
        results.fill(response, 'CalibrateUserFrame', failure)
        self.get_logger().warning(f'calibrate_user_frame refused: {failure.message}')
        self._last_refusal = f'{ErrorCode(failure.code).name}: {failure.message}'
        self._update_health()
        return response

    def _given_joints(self, names: list[str], captures) -> list[np.ndarray]:
        """Joint captures in the model's joint order [rad], one per named point."""
        if len(captures) != len(names):
            raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
                f'{len(captures)} joint captures for {len(names)} point names; give one '
                'capture per name')))
        order = list(self._model.joint_names)
        joints = []
        for name, capture in zip(names, captures):
            positions = dict(zip(capture.name, capture.position))
            missing = [j for j in order if j not in positions]
            q = np.array([positions.get(j, np.nan) for j in order], dtype=float)
            if missing or not np.all(np.isfinite(q)):
                raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
                    f'joint capture for {name}: needs finite positions [rad] for '
                    f'{order}; missing or not finite: {missing or "NaN/inf values"}')))
            joints.append(q)
        return joints

    # -- the active calibration, latched ---------------------------------------------------
    def _publish_from_another_thread(self, msg: UserFrameCalibration) -> None:
        """Have the node's thread publish the active calibration (``msg``, just built for the
        response); wait until it has, so a caller that subscribes after the response gets
        the new calibration."""
        executor = self.executor
        if executor is None:            # not spinning (built in-process): this thread it is
            return self._publish_active(msg)
        try:
            spin.wait(executor.create_task(functools.partial(self._publish_active, msg)),
                      PUBLISH_TIMEOUT)
        except TimeoutError:
            self.get_logger().warning(f'the node thread did not publish the new calibration '
                                      f'within {PUBLISH_TIMEOUT:.0f} s')

    def _publish_active(self, built: UserFrameCalibration | None = None) -> None:
        """Latch the active calibration on user_frame and /tf_static, or unlatch both when
        there is none; ``built`` is its message when the caller has it already. Runs on the
        node's thread only."""
        with self._store_lock:
            record = self._store.active()
            for warning in self._store.warnings:
                self.get_logger().warning(warning)
            self._store.warnings.clear()
        if record is None:
            self._unlatch()
        elif record['id'] != self._latched_id:
            msg = built if built is not None and built.id == record['id'] \
                else record_to_msg(record)
            self._pub.publish(msg)
            self._markers.publish(markers.user_frame_markers(msg, self._p('max_rms_error')))
            self._send_tf(msg.transform)
            self._latched_id = record['id']
            spin.log_info(self.get_logger(), f'active calibration {record["id"]}: latched '
                          f'on {self._pub.topic_name} and /tf_static')
        self._update_health()

    def _send_tf(self, transform) -> None:
        """The user frame alone on /tf_static: a previous child frame does not stay latched."""
        children = [t.child_frame_id for t in self._tf.transforms]
        if children not in ([], [transform.child_frame_id]):
            self._tf = self._fresh_tf()
        bad_frames = frames_problem(('its base frame', transform.header.frame_id),
                                    ('its user frame', transform.child_frame_id))
        self._tf_problem = '' if bad_frames is None else bad_frames.message   # a health note
        try:
            if not self._tf_problem:
                self._tf.send(transform)
        except ValueError as e:
            self._tf_problem = str(e)
        if self._tf_problem:
            self._tf = self._fresh_tf()
            self._tf_problem = (f'the active calibration is not on /tf_static: '
                                f'{self._tf_problem}; calibrate again or activate another')
            self.get_logger().error(self._tf_problem)

    def _fresh_tf(self) -> StaticBroadcaster:
        """A broadcaster with nothing latched (the old publisher and its latched set go)."""
        self.destroy_publisher(self._tf.publisher)
        return StaticBroadcaster(self)

    def _unlatch(self) -> None:
        if self._latched_id is None:
            return
        self.destroy_publisher(self._pub)
        self._pub = self.create_publisher(UserFrameCalibration, 'user_frame', qos.LATCHED)
        self._tf, self._tf_problem, self._latched_id = self._fresh_tf(), '', None
        self._markers.publish(markers.cleared(markers.USER_FRAME_LAYERS))
        self.get_logger().info('no active calibration: nothing latched on user_frame and '
                               '/tf_static')

    def _update_health(self) -> None:
        with self._store_lock:
            record, ids = self._store.active(), self._store.ids()
            retired = self._store.retired()
        bad_parameters = self._frame_parameters_problem()
        problem = self._tf_problem if bad_parameters is None else bad_parameters.message
        if problem:
            level, message = WARN, problem
        elif record is None:
            level, message = WARN, ('no active calibration: conversions without a '
                                    'calibration_id are refused; call calibrate_user_frame' +
                                    (' or set_active_calibration' if ids else ''))
        else:
            level, message = OK, (f'active calibration {record["id"]}, RMS residual '
                                  f'{record["result"]["rms"] * 1e3:.4f} mm')
        self._health.set(
            level, message, active_id=record['id'] if record else '',
            active_rms_mm=f'{record["result"]["rms"] * 1e3:.4f}' if record else '',
            calibrations_stored=len(ids), calibrations_retired=len(ids & retired),
            last_refusal=self._last_refusal or 'none')

    def _on_set_active(self, request, response):
        chosen = self._choose(request)
        results.answer(response, ErrorCode.SUCCESS if chosen else chosen.code,
                       chosen if chosen else chosen.message)
        if chosen:
            self.get_logger().info(f'set_active_calibration: {response.message}')
            self._publish_active()
        with self._store_lock:
            active = self._store.active()
        if active is not None:
            response.active = record_to_msg(active)
        return response

    def _choose(self, request) -> str | Failure:
        """An ACTIVATE or RETIRE request applied to the store (api.user_frame.choose)."""
        actions = {Choice.Request.ACTIVATE: user_frame_api.ACTIVATE,
                   Choice.Request.RETIRE: user_frame_api.RETIRE}
        if request.action not in actions:
            return Failure(ErrorCode.INVALID_INPUT, (
                f'unknown action {request.action}; use ACTIVATE ({Choice.Request.ACTIVATE}) '
                f'or RETIRE ({Choice.Request.RETIRE})'))
        return user_frame_api.choose(self._store, actions[request.action],
                                     request.calibration_id, self._store_lock)

    # -- conversion and history -----------------------------------------------------------
    def _convert(self, request, response, to_base: bool):
        try:
            with self._store_lock:
                record = (self._store.get(request.calibration_id) if request.calibration_id
                          else self._store.active())
        except Refusal as e:           # another cell's (store.cells)
            return results.answer(response, e.failure.code, f'calibration_id '
                                  f'{request.calibration_id!r}: {e.failure.message}')
        except ValueError as e:        # not a possible calibration id
            response.error_code = results.code('ConvertPoints', ErrorCode.INVALID_INPUT)
            response.message = f'calibration_id {request.calibration_id!r}: {e}'
            return response
        if record is None:
            response.error_code = results.code('ConvertPoints', ErrorCode.NO_CALIBRATION)
            response.message = (f'no calibration {request.calibration_id!r}' if
                                request.calibration_id else
                                'no active calibration: call calibrate_user_frame first (or '
                                'set_active_calibration)')
            return response
        points = convert.points_to_array(request.points)
        if not np.all(np.isfinite(points)):
            response.error_code = results.code('ConvertPoints', ErrorCode.INVALID_INPUT)
            response.message = 'points contain NaN or inf'
            return response
        M = np.array(record['result']['M'])
        surface = (UserFrameRecord.from_dict(record).surface_model() if request.apply_surface
                   else None)
        if to_base:
            out = user_frame.user_to_base(M, points, surface)
        else:   # M may be affine (five_point_lsq): a general inverse, not the rigid one
            out = frames.apply(np.linalg.inv(M), points)
            if surface is not None:
                out[:, 2] -= surface.height(out[:, 0], out[:, 1])
        response.points = convert.array_to_points(out)
        response.message = f'converted with {record["id"]}'
        return response

    def _on_user_to_robot(self, request, response):
        return self._convert(request, response, to_base=True)

    def _on_robot_to_user(self, request, response):
        return self._convert(request, response, to_base=False)

    def _on_list(self, request, response):
        with self._store_lock:
            history = self._store.history(request.max_count)
            active, retired = self._store.active(), self._store.retired()
        response.calibrations = [record_to_msg(r) for r in history]
        response.active_id = active['id'] if active else ''
        response.retired_ids = [r['id'] for r in history if r['id'] in retired]
        return response


def main(args=None) -> None:
    spin.run(UserFrameSolver, args)


if __name__ == '__main__':
    main()
