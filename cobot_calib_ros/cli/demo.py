"""`cobot-calib demo`: five-point user-frame calibration on the mock robot, scored on truth.

Visits P1..P5 live (touch, capture_joints, nominal forward kinematics), then fits the user
frame with every method from the same captured points and sends the robot to each marker
through each frame. The mock's ground truth scores every figure.
"""
from __future__ import annotations

import contextlib
import json
import math
import sys

import numpy as np

from cobot_calib_ros.api import launcher
from cobot_calib_ros.cli.common import say
from cobot_calib_ros.ros import convert
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.paths import cell_file

METHODS = ('three_point', 'five_point_lsq', 'rigid', 'robust')
POINTS = ('P1', 'P2', 'P3', 'P4', 'P5')


@contextlib.contextmanager
def _suite(args):
    """Start the node suite on a private domain unless --attach."""
    if args.attach:
        yield
        return
    with launcher.private_suite(args.cell, say=lambda text: say(args, text)):
        yield


class DemoClient:
    """Service and action calls of the demo (one rclpy node)."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.action import ActionClient
        from cobot_calib_msgs.action import MoveTo
        from cobot_calib_msgs.srv import CalibrateUserFrame, GetGroundTruth
        rclpy.init()
        self.node = rclpy.create_node('cobot_calib_demo')
        self.MoveTo, self.Calibrate = MoveTo, CalibrateUserFrame
        self._truth = self.node.create_client(GetGroundTruth, 'get_ground_truth')
        self._calibrate = self.node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        self._move = ActionClient(self.node, MoveTo, 'move_to')

    def close(self) -> None:
        import rclpy
        self.node.destroy_node()
        rclpy.try_shutdown()

    def ground_truth(self):
        from cobot_calib_ros.api.client import call_service
        return call_service(self.node, self._truth, self._truth.srv_type.Request(), 30.0)

    def calibrate(self, method: str, names=(), p_user=None, p_base=None):
        from cobot_calib_ros.api.client import call_service
        req = self.Calibrate.Request(method=method, point_names=list(names))
        if p_user is not None:
            req.points_user = convert.array_to_points(p_user)
            req.points_base = convert.array_to_points(p_base)
        return call_service(self.node, self._calibrate, req, 120.0)

    def move_to_pose(self, T: np.ndarray):
        from cobot_calib_ros.api.client import run_action
        goal = self.MoveTo.Goal(target_type=self.MoveTo.Goal.TARGET_POSE,
                                pose=convert.matrix_to_pose(T))
        return run_action(self.node, self._move, goal, 60.0)[1]


def _truth_model(truth, cell):
    """The true robot (simulation only): nominal model with the mock's true parameters."""
    model = kinematics.model_by_name(cell.robot)
    return model.chain(np.array(truth.true_parameters), tool=cell.tool_offset)


def _point_errors(client, M, p_user, p_true, true_chain) -> np.ndarray:
    """Send the tool to every marker through the frame M; true error of each arrival [m]."""
    orientation = cellmod.tool_down_orientation(user_frame.nearest_rigid(M))
    errors = []
    for pu, pt in zip(p_user, p_true):
        target = frames.make_transform(orientation, frames.apply(M, pu))
        result = client.move_to_pose(target)
        if result.error_code != client.MoveTo.Result.SUCCESS:
            errors.append(math.nan)
            continue
        reached = kinematics.fk(true_chain, np.array(result.positions))[:3, 3]
        errors.append(float(np.linalg.norm(reached - pt)))
    return np.array(errors)


def _apparent_points(truth, cell, true_chain, p_true) -> np.ndarray:
    """Where the nominal model sees perfectly touched markers [m]: the captures without noise.

    The robot's kinematic errors and the table's unevenness shift every captured point by
    a few tenths of a millimetre, and no user-frame fit can remove that; fitting these
    noise-free points tells that systematic part apart from what the noise does.
    """
    model = kinematics.model_by_name(cell.robot)
    nominal = model.chain(tool=cell.tool_offset)
    R = cellmod.tool_down_orientation(convert.transform_to_matrix(truth.user_frame))
    points = []
    for name, p in zip(POINTS, p_true):
        ik = kinematics.solve_ik_with_restarts(true_chain, frames.make_transform(R, p),
                                               cell.home, cell.home)
        if not ik:
            raise RuntimeError(f'the true robot cannot reach marker {name}: {ik.message}')
        points.append(kinematics.fk(nominal, ik.q)[:3, 3])
    return np.array(points)


def _method_row(client, method, p_user, p_base, T_true, p_true, p_apparent,
                true_chain) -> dict:
    res = client.calibrate(method, POINTS, p_user, p_base)
    if res.error_code != 0:
        return {'name': method, 'error': res.message}
    cal = res.calibration
    T = convert.transform_to_matrix(cal.transform)
    M = np.array(cal.matrix).reshape(4, 4)            # the map the method converts with
    dt, dr = frames.transform_error(T, T_true)
    T_apparent = user_frame.calibrate(method, p_user, p_apparent).T_base_user
    nt, nr = frames.transform_error(T, T_apparent)
    st, sr = frames.transform_error(T_apparent, T_true)
    errors = _point_errors(client, M, p_user, p_true, true_chain)
    return {'name': method, 'frame_error_mm': dt * 1e3, 'frame_error_mrad': dr * 1e3,
            'frame_error_noise_mm': nt * 1e3, 'frame_error_noise_mrad': nr * 1e3,
            'frame_error_systematic_mm': st * 1e3, 'frame_error_systematic_mrad': sr * 1e3,
            'residual_rms_mm': cal.rms_residual * 1e3,
            'point_error_max_mm': float(np.nanmax(errors)) * 1e3,
            'point_error_mm': (errors * 1e3).tolist(),
            'id': cal.id}


def _report(args, result: dict) -> None:
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print('\ncaptured tool points (nominal model) beside the truth, base frame [mm]:')
    for c in result['captured']:
        cap, tru = c['captured_mm'], c['true_mm']
        print(f"  {c['name']}: captured ({cap[0]:9.3f} {cap[1]:9.3f} {cap[2]:8.3f})  true "
              f"({tru[0]:9.3f} {tru[1]:9.3f} {tru[2]:8.3f})  |diff| {c['error_mm']:.3f}")
    print('\nframe error against the true user frame, split into the systematic part (kinematic '
          'errors + table, the\nframe perfect touches would give) and the part due to noise; '
          'point err: robot sent to each marker')
    print(f"{'method':<16}{'frame err':>18}{'systematic':>18}{'noise part':>18}"
          f"{'resid RMS':>11}{'point err max':>15}")
    print(f"{'':<16}{'mm / mrad':>18}{'mm / mrad':>18}{'mm / mrad':>18}{'mm':>11}{'mm':>15}")
    for m in result['methods']:
        if 'error' in m:
            print(f"{m['name']:<16} failed: {m['error']}")
            continue
        print(f"{m['name']:<16}"
              f"{m['frame_error_mm']:9.4f} /{m['frame_error_mrad']:7.4f}"
              f"{m['frame_error_systematic_mm']:9.4f} /{m['frame_error_systematic_mrad']:7.4f}"
              f"{m['frame_error_noise_mm']:9.4f} /{m['frame_error_noise_mrad']:7.4f}"
              f"{m['residual_rms_mm']:11.4f}{m['point_error_max_mm']:15.4f}")
    print(f"\nestimation limit from point noise alone (rigid, 5 points, sigma "
          f"{result['noise_sigma_mm']:.4f} mm): {result['estimation_limit_mm']:.4f} mm, "
          f"{result['estimation_limit_mrad']:.4f} mrad (RMS); a noise part above "
          f"{user_frame.LIMIT_FACTOR:g}x that is suspect")


def _run(args, client: DemoClient) -> dict:
    from cobot_calib_ros.api.client import wait_for_suite
    cell = cellmod.load_cell(cell_file(args.cell))
    wait_for_suite(client.node)
    truth = client.ground_truth()
    T_true = convert.transform_to_matrix(truth.user_frame)
    true_by_name = dict(zip(truth.point_names, convert.points_to_array(truth.points_base)))
    say(args, f'touching {", ".join(POINTS)} and capturing joints ...')
    live = client.calibrate('rigid', POINTS)
    if live.error_code != 0:
        raise RuntimeError(f'live capture failed: {live.message}')
    p_user = np.array([[r.point_user.x, r.point_user.y, r.point_user.z]
                       for r in live.calibration.residuals])
    p_base = np.array([[r.point_base.x, r.point_base.y, r.point_base.z]
                       for r in live.calibration.residuals])
    p_true = np.array([true_by_name[n] for n in POINTS])
    true_chain = _truth_model(truth, cell)
    sigma = math.hypot(truth.touch_sigma, truth.repeatability_sigma)
    limit_t, limit_r = user_frame.estimation_limit(p_user, sigma)
    p_apparent = _apparent_points(truth, cell, true_chain, p_true)
    rows = []
    for method in METHODS:
        say(args, f'{method}: fitting and visiting the five points through the frame ...')
        rows.append(_method_row(client, method, p_user, p_base, T_true, p_true, p_apparent,
                                true_chain))
    captured = [{'name': n, 'captured_mm': (pb * 1e3).tolist(), 'true_mm': (pt * 1e3).tolist(),
                 'error_mm': float(np.linalg.norm(pb - pt) * 1e3)}
                for n, pb, pt in zip(POINTS, p_base, p_true)]
    return {'cell': cell.name, 'robot': cell.robot, 'layout': cell.layout,
            'captured': captured, 'methods': rows,
            'estimation_limit_mm': limit_t * 1e3, 'estimation_limit_mrad': limit_r * 1e3,
            'noise_sigma_mm': sigma * 1e3}


def run(args) -> int:
    from cobot_calib_ros.api.client import CallError
    try:
        with _suite(args):
            client = DemoClient()
            try:
                result = _run(args, client)
            finally:
                client.close()
    except (CallError, RuntimeError) as e:
        print(f'demo failed: {e}', file=sys.stderr)
        return 1
    _report(args, result)
    return 0
