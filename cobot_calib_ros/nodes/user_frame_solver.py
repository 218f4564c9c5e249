"""user_frame_solver: the calibrate_user_frame service, point conversion, durable history.

calibrate_user_frame is served on its own executor thread (a spin.Companion): a live
calibration that visits points blocks only that thread, so user_to_robot, robot_to_user and
list_calibrations keep answering meanwhile.
"""
from __future__ import annotations

import threading
import time

from cobot_calib_msgs.msg import PointResidual, SurfaceModel as SurfaceMsg, UserFrameCalibration
from cobot_calib_msgs.srv import CalibrateUserFrame, ConvertPoints, ListCalibrations
import numpy as np
from rclpy.node import Node

from cobot_calib_ros import paths
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.core.cell import load_cell
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.ros import convert, qos, spin
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCallError, RobotCalls
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.store.calibrations import CalibrationStore

Res = CalibrateUserFrame.Response


def fit_record(fit: user_frame.FrameFit, surface, names: list[str], p_user, p_base,
               frames_: tuple[str, str], stamp_ns: int) -> dict:
    """Everything about one calibration (what is stored and republished); numpy values are
    left as they are: the store writes them as plain lists. ``stamp_ns`` is ROS time; the id
    (a file name) comes from the wall clock so that it stays unique under a paused sim clock."""
    wall_ns = time.time_ns()
    return {
        'id': time.strftime('%Y%m%dT%H%M%S', time.gmtime(wall_ns / 1e9))
        + f'.{wall_ns % 1_000_000_000:09d}Z-{fit.method}',
        'stamp_ns': stamp_ns, 'method': fit.method,
        'base_frame': frames_[0], 'user_frame': frames_[1],
        'inputs': {'point_names': names, 'points_user': p_user, 'points_base': p_base},
        'result': {
            'T_base_user': fit.T_base_user, 'M': fit.M, 'residuals': fit.residuals,
            'rms': fit.rms, 'max_residual': fit.max_residual,
            'condition_number': fit.condition_number, 'collinearity': fit.collinearity,
            'covariance': fit.covariance, 'scale': fit.scale, 'shear': fit.shear,
            'outliers': list(fit.outliers), 'message': fit.message,
            'surface': None if surface is None else {
                'valid': bool(surface), 'powers_x': surface.powers_x,
                'powers_y': surface.powers_y, 'coefficients': surface.coefficients,
                'rms_before': surface.rms_before, 'rms_after': surface.rms_after}}}


def record_to_msg(record: dict) -> UserFrameCalibration:
    r = record['result']
    inputs = record['inputs']
    msg = UserFrameCalibration(id=record['id'], method=record['method'])
    msg.stamp.sec, msg.stamp.nanosec = divmod(int(record['stamp_ns']), 1_000_000_000)
    msg.transform = convert.matrix_to_transform(
        np.array(r['T_base_user']), record['base_frame'], record['user_frame'], msg.stamp)
    msg.matrix = [float(v) for v in np.ravel(r['M'])]
    outliers = set(r['outliers'])
    for i, (name, pu, pb, res) in enumerate(zip(inputs['point_names'], inputs['points_user'],
                                                inputs['points_base'], r['residuals'])):
        [pu_msg], [pb_msg] = convert.array_to_points([pu]), convert.array_to_points([pb])
        pr = PointResidual(name=name, point_user=pu_msg, point_base=pb_msg,
                           residual_norm=float(np.linalg.norm(res)), outlier=i in outliers)
        pr.residual.x, pr.residual.y, pr.residual.z = (float(v) for v in res)
        msg.residuals.append(pr)
    msg.rms_residual, msg.max_residual = float(r['rms']), float(r['max_residual'])
    msg.condition_number, msg.collinearity = float(r['condition_number']), float(r['collinearity'])
    msg.covariance = [float(v) for v in np.ravel(r['covariance'])]
    msg.scale_x, msg.scale_y, msg.scale_z = (float(v) for v in r['scale'])
    msg.shear_xy, msg.shear_xz, msg.shear_yz = (float(v) for v in r['shear'])
    s = r.get('surface')
    if s:
        msg.surface = SurfaceMsg(valid=bool(s['valid']), powers_x=list(s['powers_x']),
                                 powers_y=list(s['powers_y']),
                                 coefficients=[float(c) for c in s['coefficients']],
                                 rms_before=float(s['rms_before']),
                                 rms_after=float(s['rms_after']))
    return msg


def record_surface(record: dict) -> user_frame.SurfaceModel | None:
    s = record['result'].get('surface')
    if not s or not s['valid']:
        return None
    return user_frame.SurfaceModel(tuple(s['powers_x']), tuple(s['powers_y']),
                                   np.array(s['coefficients']), s['rms_before'],
                                   s['rms_after'], True)


class UserFrameSolver(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('user_frame_solver', **kwargs)
        self._declare_parameters()
        self._cell = load_cell(paths.cell_file(self._p('cell_file')))
        model = kinematics.model_by_name(self._cell.robot)
        self._chain = model.chain(tool=self._cell.tool_offset)   # the nominal model
        self._store = CalibrationStore(paths.data_dir(self._p('data_dir')))
        self._store_lock = threading.Lock()     # the calibrator thread writes, this one reads
        # a live calibration blocks in its service callback while the robot moves and
        # captures: it runs on the calibrator's thread, the answers it waits for arrive on
        # the clients' thread, and this node's own services stay free
        self._answers = spin.Companion(self, 'clients')
        self._calibrator = spin.Companion(self, 'calibrator')
        self._robot = RobotCalls(self._answers)
        self._pub = self.create_publisher(UserFrameCalibration, 'user_frame', qos.LATCHED)
        self._calibrator.node.create_service(CalibrateUserFrame, 'calibrate_user_frame',
                                             self._on_calibrate)
        self.create_service(ConvertPoints, 'user_to_robot', self._on_user_to_robot)
        self.create_service(ConvertPoints, 'robot_to_user', self._on_robot_to_user)
        self.create_service(ListCalibrations, 'list_calibrations', self._on_list)
        self._republish_latest()

    def destroy_node(self):
        self._calibrator.destroy()
        self._answers.destroy()
        return super().destroy_node()

    def _declare_parameters(self) -> None:
        read_once(self, 'cell_file', 'sawyer_close',
                  'Cell YAML (path or name): named points and the nominal tool offset')
        declare(self, 'base_frame', 'base_link', 'Robot base frame id')
        declare(self, 'user_frame', 'user_frame', 'User (work surface) frame id')
        read_once(self, 'data_dir', '', 'Where calibrations are stored; empty = '
                  '$COBOT_CALIB_DATA or ~/.ros/cobot_calib')
        declare(self, 'capture_duration', 0.5, 'Hold window of each live capture [s]',
                0.01, 10.0)
        declare(self, 'robust_threshold', 5.0e-4,
                'Residual above which the robust method rejects a point [m]', 1e-6, 0.1)

    def _p(self, name: str):
        return self.get_parameter(name).value

    def _republish_latest(self) -> None:
        latest = self._store.latest()
        for warning in self._store.warnings:
            self.get_logger().warning(warning)
        if latest is not None:
            self._pub.publish(record_to_msg(latest))
            self.get_logger().info(f'republished calibration {latest["id"]}')

    # -- calibrate ------------------------------------------------------------------------
    def _on_calibrate(self, request, response):
        frames_ = (request.base_frame or self._p('base_frame'),
                   request.user_frame or self._p('user_frame'))
        try:
            names, p_user, p_base = self._points(request)
        except _RequestError as e:
            return self._refuse(response, e.code, str(e))
        opts = {'threshold': self._p('robust_threshold')} if request.method == 'robust' else {}
        fit = user_frame.calibrate(request.method, p_user, p_base, **opts)
        if not fit:
            return self._refuse(response, fit.code, fit.message)
        surface = (user_frame.fit_surface(p_user, p_base, fit.M)
                   if request.fit_surface else None)
        record = fit_record(fit, surface, names, p_user, p_base, frames_, now_ns(self))
        try:
            with self._store_lock:
                self._store.save(record)
        except OSError as e:
            return self._refuse(response, ErrorCode.STORAGE_FAILED,
                                f'could not store the calibration: {e}; check data_dir')
        response.calibration = record_to_msg(record)
        response.error_code, response.message = Res.SUCCESS, fit.message or 'calibrated'
        self._pub.publish(response.calibration)
        spin.log_info(self.get_logger(), f'{record["id"]}: {len(names)} points, rms '
                      f'{fit.rms * 1e3:.4f} mm, max {fit.max_residual * 1e3:.4f} mm')
        return response

    def _refuse(self, response, code, message: str):
        response.error_code, response.message = int(code), message
        self.get_logger().warning(f'calibrate_user_frame refused: {message}')
        return response

    def _points(self, request) -> tuple[list[str], np.ndarray, np.ndarray]:
        p_user = convert.points_to_array(request.points_user)
        p_base = convert.points_to_array(request.points_base)
        names = list(request.point_names)
        if len(p_user) or len(p_base):
            if names and len(names) != len(p_user):
                raise _RequestError(ErrorCode.INVALID_INPUT, (
                    f'{len(names)} point names for {len(p_user)} points; give one name per '
                    'point or none'))
            return names or [f'P{i + 1}' for i in range(len(p_user))], p_user, p_base
        if not names:
            raise _RequestError(ErrorCode.TOO_FEW_POINTS, (
                'no points: give points_user + points_base, or point_names of the cell to '
                'visit live'))
        self._check_names(names)
        if request.joint_captures:
            joints = self._given_joints(names, request.joint_captures)
        else:
            joints = [self._capture_live(name) for name in names]
        p_user = np.array([self._cell.marker(n).nominal_top for n in names])
        p_base = np.array([kinematics.fk(self._chain, q)[:3, 3] for q in joints])
        return names, p_user, p_base

    def _check_names(self, names: list[str]) -> None:
        unknown = [n for n in names if self._cell.marker(n) is None]
        if unknown:
            raise _RequestError(ErrorCode.UNKNOWN_POINT, (
                f'unknown point(s) {unknown}; the cell defines {self._cell.point_names}'))

    def _capture_live(self, name: str) -> np.ndarray:
        try:
            return self._robot.touch_and_capture(name, self._p('capture_duration'), 60.0)
        except RobotCallError as e:
            raise _RequestError(ErrorCode.CAPTURE_FAILED, f'capture at {name} failed: {e}')

    def _given_joints(self, names: list[str], captures) -> list[np.ndarray]:
        """Joint captures in the model's joint order [rad], one per named point."""
        if len(captures) != len(names):
            raise _RequestError(ErrorCode.INVALID_INPUT, (
                f'{len(captures)} joint captures for {len(names)} point names; give one '
                'capture per name'))
        order = list(self._chain.joint_names)
        joints = []
        for name, capture in zip(names, captures):
            positions = dict(zip(capture.name, capture.position))
            missing = [j for j in order if j not in positions]
            q = np.array([positions.get(j, np.nan) for j in order], dtype=float)
            if missing or not np.all(np.isfinite(q)):
                raise _RequestError(ErrorCode.INVALID_INPUT, (
                    f'joint capture for {name}: needs finite positions [rad] for '
                    f'{order}; missing or not finite: {missing or "NaN/inf values"}'))
            joints.append(q)
        return joints

    # -- conversion and history -----------------------------------------------------------
    def _convert(self, request, response, to_base: bool):
        try:
            with self._store_lock:
                record = (self._store.get(request.calibration_id) if request.calibration_id
                          else self._store.latest())
        except ValueError as e:        # not a possible calibration id
            response.error_code = ConvertPoints.Response.INVALID_INPUT
            response.message = f'calibration_id {request.calibration_id!r}: {e}'
            return response
        if record is None:
            response.error_code = ConvertPoints.Response.NO_CALIBRATION
            response.message = (f'no calibration {request.calibration_id!r}' if
                                request.calibration_id else
                                'no calibration yet: call calibrate_user_frame first')
            return response
        points = convert.points_to_array(request.points)
        if not np.all(np.isfinite(points)):
            response.error_code = ConvertPoints.Response.INVALID_INPUT
            response.message = 'points contain NaN or inf'
            return response
        M = np.array(record['result']['M'])
        surface = record_surface(record) if request.apply_surface else None
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
        response.calibrations = [record_to_msg(r) for r in history]
        return response


class _RequestError(ValueError):
    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


def main(args=None) -> None:
    spin.run(UserFrameSolver, args)


if __name__ == '__main__':
    main()
