"""user_frame_solver: the calibrate_user_frame service, point conversion, durable history."""
from __future__ import annotations

import time

from cobot_calib_msgs.msg import PointResidual, SurfaceModel as SurfaceMsg, UserFrameCalibration
from cobot_calib_msgs.srv import CalibrateUserFrame, ConvertPoints, ListCalibrations
import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from cobot_calib_ros import paths
from cobot_calib_ros.ros import convert
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.store.calibrations import CalibrationStore
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.params import declare
from cobot_calib_ros.ros.robot_calls import RobotCallError, RobotCalls

Res = CalibrateUserFrame.Response
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def fit_record(fit: user_frame.FrameFit, surface, names: list[str], p_user, p_base,
               frames_: tuple[str, str]) -> dict:
    """Everything about one calibration (what is stored and republished); numpy values are
    left as they are: the store writes them as plain lists."""
    stamp_ns = time.time_ns()
    return {
        'id': time.strftime('%Y%m%dT%H%M%S', time.gmtime(stamp_ns / 1e9))
        + f'.{stamp_ns % 1_000_000_000:09d}Z-{fit.method}',
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
        self._cell = cellmod.load_cell(paths.cell_file(self._p('cell_file')))
        model = kinematics.model_by_name(self._cell.robot)
        self._chain = model.chain(tool=self._cell.tool_offset)   # the nominal model
        self._store = CalibrationStore(paths.data_dir(self._p('data_dir')))
        # a live calibration blocks in its service callback while the robot moves and
        # captures: the answers it waits for arrive on the companion's own executor
        self._answers = spin.Companion(self, 'clients')
        self._robot = RobotCalls(self._answers)
        self._pub = self.create_publisher(UserFrameCalibration, 'user_frame', LATCHED)
        self.create_service(CalibrateUserFrame, 'calibrate_user_frame', self._on_calibrate)
        self.create_service(ConvertPoints, 'user_to_robot', self._on_user_to_robot)
        self.create_service(ConvertPoints, 'robot_to_user', self._on_robot_to_user)
        self.create_service(ListCalibrations, 'list_calibrations', self._on_list)
        self._republish_latest()

    def destroy_node(self):
        self._answers.destroy()
        return super().destroy_node()

    def _declare_parameters(self) -> None:
        declare(self, 'cell_file', 'sawyer_close',
                'Cell YAML (path or name): named points and the nominal tool offset')
        declare(self, 'base_frame', 'base_link', 'Robot base frame id')
        declare(self, 'user_frame', 'user_frame', 'User (work surface) frame id')
        declare(self, 'data_dir', '', 'Where calibrations are stored; empty = '
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
        record = fit_record(fit, surface, names, p_user, p_base, frames_)
        try:
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
        return names, *self._capture_live(names)

    def _capture_live(self, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        unknown = [n for n in names if self._cell.world.marker(n) is None]
        if unknown:
            raise _RequestError(ErrorCode.UNKNOWN_POINT, (
                f'unknown point(s) {unknown}; the cell defines {self._cell.world.point_names}'))
        p_user, p_base = [], []
        for name in names:
            try:
                q = self._robot.touch_and_capture(name, self._p('capture_duration'), 60.0)
            except RobotCallError as e:
                raise _RequestError(ErrorCode.CAPTURE_FAILED, f'capture at {name} failed: {e}')
            p_user.append(self._cell.world.marker(name).nominal_top)
            p_base.append(kinematics.fk(self._chain, q)[:3, 3])
        return np.array(p_user), np.array(p_base)

    # -- conversion and history -----------------------------------------------------------
    def _convert(self, request, response, to_base: bool):
        try:
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
        response.calibrations = [record_to_msg(r) for r in self._store.history(request.max_count)]
        return response


class _RequestError(ValueError):
    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


def main(args=None) -> None:
    spin.run(UserFrameSolver, args)


if __name__ == '__main__':
    main()
