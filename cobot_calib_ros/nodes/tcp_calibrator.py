"""tcp_calibrator: the tool centre point, from touches of one fixed point of the cell.

Action ``calibrate_tcp`` (cobot_calib_msgs/action/CalibrateTcp): plans ``orientations``
approaches of the fixed point (core.tcp.touches.plan_touches: the first with the tool pointing
down the active user frame's z, or the base's, the others tilted by ``tilt`` about horizontal
axes spread round the point) and the elongator touches of the orientation method; takes them
with core.tcp.touches.take_touches over RobotCalls (on the mock, mock_robot/hand_guide guides
the real tool in each orientation; on a real cell the operator guides the arm and confirms each
touch on ``tcp_calibrator/confirm_touch``), capturing the joints over ``hold`` and taking the
flange pose through the ACTIVE kinematics (the ``kinematics`` parameter: latest, nominal or an
id). Then core.tcp.solve_tcp: the position by SVD with the rank test (approaches too alike:
TOO_ALIKE, named), the robust refinement, the orientation from the elongator points.

The result is stored per tool (``<data_dir>`` repository, kind tcp, store.records.TcpRecord)
and made the tool's active TCP only if it passes core.tcp.gate_problem (its residual explained
by ``touch_sigma``, a plausible tool length, near the cell's tool_offset for the cell's own
tool); otherwise it is kept as rejected and the goal ends with REJECTED saying why. A cancel is
honoured between touches (nothing stored). Feedback after every touch: its index and the RMS
tip residual of the approaches so far (from the fourth).

Parameters: cell_file, layout, data_dir (read at start-up: nodes.job_node.JobNode);
hold_duration [s], touch_sigma [m], kinematics.
"""
from __future__ import annotations

import math
import time

from cobot_calib_msgs.action import CalibrateTcp
import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.errors import ErrorCode as E
from cobot_calib_ros.core.provenance import missing_prerequisites
from cobot_calib_ros.core.robot_port import CaptureFailed, MoveFailed, Stopped
from cobot_calib_ros.core.tcp import GateLimits, gate_problem, solve_position, TooAlike
from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.tcp.touches import (checked_plan, DEFAULT_APPROACHES,
                                              DEFAULT_ELONGATION, DEFAULT_TILT, plan_touches,
                                              solve_touches, take_touches, TcpTouches,
                                              Unreachable)
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.ros import convert, spin
from cobot_calib_ros.ros.diagnostics import OK
from cobot_calib_ros.ros.params import declare
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns
from cobot_calib_ros.store.records import TcpRecord

Action = CalibrateTcp
METHODS = {Action.Goal.ORIENTATION_NONE: 'none', Action.Goal.ORIENTATION_Z: 'z',
           Action.Goal.ORIENTATION_ZX: 'zx'}


class TcpCalibrator(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('tcp_calibrator', job='a TCP calibration',
                         cell_help='Cell YAML (path or name): robot, tool_offset, the fixed '
                         'points', data_help='Results repository (kind tcp)', **kwargs)
        self._declare_parameters()
        self._robot = RobotCalls(self._answers, operator=self.get_name())
        self._health.watch(capture_retries=lambda: self._robot.capture_retries)
        self._server = ActionServer(
            self, Action, 'calibrate_tcp', execute_callback=self._on_goal,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        history = self._repository().tcp
        active = history.active(self._cell.tool_frame)
        for warning in history.warnings:
            self.get_logger().warning(warning)
        self._health.set(OK, 'idle', active_id=active['id'] if active else '')
        self.get_logger().info(f'TCP calibrations in {history.directory}')

    def _declare_parameters(self) -> None:
        declare(self, 'hold_duration', 0.2, 'Joints are averaged over this hold at every '
                'touch [s]', 0.005, 10.0)
        declare(self, 'touch_sigma', 5e-5, 'Tip noise per axis of a touch (the operator\'s '
                'centring and the arm) the gate allows for [m]', 1e-6, 1e-2)
        declare(self, 'kinematics', 'latest', 'Kinematics of the flange poses: latest (the '
                'active calibration, else nominal), nominal, or a calibration id')

    def _on_goal(self, goal_handle):
        return self._exclusive(goal_handle, self._run, Action.Result)

    def _chain(self):
        """The active kinematics ending at the flange, and its label (id or nominal)."""
        rig = self._rig(self._p('kinematics'))
        return rig.chain('flange'), rig.active.kinematics_label

    def _user_frame_or_none(self) -> np.ndarray | None:
        """The active user frame (T_base_user), None without one."""
        try:
            return self._rig(self._p('kinematics')).T_base_user()
        except (KeyError, ValueError):
            return None

    def _reachable(self, plan, point: str, tilt: float, T_base_user):
        """core.tcp.touches.checked_plan through the active kinematics and the cell tool's
        active TCP (else its nominal tool_offset), the point where the active user frame puts
        it (unknown without one)."""
        chain = self._rig(self._p('kinematics')).chain('tcp')
        p = None if T_base_user is None else frames.apply(
            T_base_user, self._cell.marker(point).nominal_top)
        return checked_plan(plan, chain, self._cell.home, tilt, p)

    def _run(self, goal_handle):
        goal, result = goal_handle.request, Action.Result()
        tool = goal.tool or self._cell.tool_frame
        point = goal.point_name or next(iter(self._cell.point_names), '')
        count = int(goal.orientations) or DEFAULT_APPROACHES
        tilt = float(goal.tilt) or DEFAULT_TILT
        elongation = float(goal.elongation) or DEFAULT_ELONGATION
        hold = float(goal.hold) or self._p('hold_duration')
        result.tool = tool
        try:
            if not point:
                self._cell.require('the TCP calibration (no point_name)', 'layouts')
            if point not in self._cell.point_names:
                raise ValueError(f'unknown point {point!r}; the cell has '
                                 f'{self._cell.point_names}')
            if goal.orientation not in METHODS:
                raise ValueError(f'orientation {goal.orientation}: use ORIENTATION_NONE (0), '
                                 'ORIENTATION_Z (1) or ORIENTATION_ZX (2)')
            if not 0.0 < hold <= 10.0:
                raise ValueError(f'hold {hold} s: give 0..10 s (0 = the parameter)')
            T_base_user = self._user_frame_or_none()
            plan = plan_touches(point, count, tilt, tool_down_orientation(
                np.eye(4) if T_base_user is None else T_base_user, 'z'),
                METHODS[goal.orientation], elongation)
            plan, locate = self._reachable(plan, point, tilt, T_base_user)
            chain, kinematics_used = self._chain()
        except TooAlike as e:
            return self._end(goal_handle, result, E.DEGENERATE_POINTS, f'planned {e}')
        except Unreachable as e:
            return self._end(goal_handle, result, E.MOTION_FAILED,
                             f'planned touches of {point}: {e}')
        except (KeyError, ValueError) as e:
            return self._end(goal_handle, result, E.INVALID_INPUT,
                             str(e).strip("'"))
        total = len(plan.steps())
        prerequisites = missing_prerequisites(f'the TCP of {tool} is',
                                              {'kinematics': kinematics_used})
        if prerequisites:
            self.get_logger().warning(prerequisites)
        self._health.set(OK, f'calibrating the TCP of {tool}: {total} touches of {point}')
        t_start = time.monotonic()
        feedback = Action.Feedback(total=total)

        def on_touch(i: int, touches: TcpTouches) -> None:
            feedback.touch_index = i
            feedback.residual_mm = _rms_so_far(touches)
            goal_handle.publish_feedback(feedback)

        try:
            touches = take_touches(plan, self._robot, chain, hold,
                                   cancelled=lambda: goal_handle.is_cancel_requested,
                                   on_touch=on_touch, locate=locate)
        except TooAlike as e:
            return self._end(goal_handle, result, E.DEGENERATE_POINTS,
                             f'planned from the first touch: {e}; nothing stored')
        except Unreachable as e:
            return self._end(goal_handle, result, E.MOTION_FAILED,
                             f'planned from where the first touch found {point}: {e}; nothing '
                             'stored')
        except Stopped as e:
            return self._end(goal_handle, result, E.CANCELED,
                             f'{e}; nothing stored')
        except MoveFailed as e:
            return self._end(goal_handle, result, E.MOTION_FAILED, str(e))
        except CaptureFailed as e:
            return self._end(goal_handle, result, E.CAPTURE_FAILED, str(e))
        try:
            solution = solve_touches(plan, touches, self._p('touch_sigma'))
        except TooAlike as e:
            return self._end(goal_handle, result, E.DEGENERATE_POINTS, str(e))
        except (ValueError, np.linalg.LinAlgError) as e:
            return self._end(goal_handle, result, E.SOLVER_FAILED, str(e))
        nominal = self._cell.tool_offset if tool == self._cell.tool_frame else None
        gate = gate_problem(solution, GateLimits(touch_sigma=self._p('touch_sigma')), nominal)
        record = TcpRecord.from_solution(
            solution, tool, point, touches.labels, touches.joints, touches.flange,
            now_ns(self), kinematics_used, tilt,
            elongation if plan.elongators else 0.0, gate)
        try:
            activation = self._repository().tcp.save_and_activate(record)
        except (OSError, ValueError) as e:
            return self._end(goal_handle, result, E.STORAGE_FAILED,
                             f'could not store the TCP calibration: {e}')
        position = solution.position
        result.calibration_id, result.active = record.id, bool(activation)
        result.t_flange_tcp = convert.matrix_to_transform(solution.T_flange_tcp, '',
                                                          '').transform
        result.fixed_point.x, result.fixed_point.y, result.fixed_point.z = (
            float(v) for v in position.c)
        result.mean_residual_mm = position.mean_residual_mm
        result.max_residual_mm = position.max_residual_mm
        result.condition = position.condition
        result.orientations_used = len(position.residuals)
        if gate:
            return self._end(goal_handle, result, E.IMPLAUSIBLE_FIT, (
                f'{record.id} rejected, stored as rejected and not made active (the active TCP '
                f'of {tool} is unchanged): {gate}'))
        x, y, z = position.t * 1e3
        angles = ', '.join(f'{math.degrees(a):.3f}'
                           for a in rpy_from_matrix(solution.R_flange_tcp))
        return self._end(goal_handle, result, E.SUCCESS, (
            f'{record.id}: TCP of {tool} x {x:.3f} y {y:.3f} z {z:.3f} mm, rpy ({angles}) deg '
            f'({solution.method}); {len(position.residuals)} approaches, residual mean '
            f'{position.mean_residual_mm:.3f} mm, max {position.max_residual_mm:.3f} mm; '
            f'{time.monotonic() - t_start:.1f} s' + (f'; {prerequisites}' if prerequisites
                                                    else '')))


def _rms_so_far(touches: TcpTouches) -> float:
    """RMS tip distance of the approaches so far [mm] (0 before four, or while too alike)."""
    if touches.approaches < 4:
        return 0.0
    try:
        position = solve_position(np.array(touches.flange[:touches.approaches]))
    except ValueError:
        return 0.0
    return float(np.sqrt(np.mean(position.distances ** 2)) * 1e3)


def main(args=None) -> None:
    spin.run(TcpCalibrator, args, threads=2)


if __name__ == '__main__':
    main()
