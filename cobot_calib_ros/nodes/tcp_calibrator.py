"""tcp_calibrator: the tool centre point, from touches of one fixed point of the cell.

Action ``calibrate_tcp`` (cobot_calib_msgs/action/CalibrateTcp): plans ``orientations``
approaches of the fixed point (core.tcp.touches.plan_touches: the first with the tool pointing
down the active user frame's z, or the base's, the others tilted by ``tilt`` about horizontal
axes spread round the point) and the elongator touches of the orientation method; the goal
is one call of api.tcp.calibrate_and_store (the procedure core.tcp.procedure.calibrate_tcp,
the gate, the record and its activation). It takes the touches over RobotCalls (on the
mock, mock_robot/hand_guide guides the real tool in each orientation; on a real cell the
operator guides the arm and confirms each touch on ``tcp_calibrator/confirm_touch``), capturing the joints over ``hold`` and taking the
flange pose through the ACTIVE kinematics (the ``kinematics`` parameter: latest, nominal or an
id). Then core.tcp.solve_tcp: the position by SVD with the rank test (approaches too alike:
TOO_ALIKE, named), the robust refinement, the orientation from the elongator points.

The result is stored per tool (``<data_dir>`` repository, kind tcp, store.records.TcpRecord)
and made the tool's active TCP only if it passes core.tcp.gate_problem (its residual explained
by ``touch_sigma``, a plausible tool length, near the cell's T_flange_tool for the cell's own
tool); otherwise it is kept as rejected and the goal ends with REJECTED saying why. A cancel is
honoured between touches (nothing stored). Feedback after every touch: its index and the RMS
tip residual of the approaches so far (from the fourth).

Parameters: cell_file, layout, data_dir (read at start-up: nodes.job_node.JobNode);
hold_duration [s], touch_sigma [m], kinematics.
"""
from __future__ import annotations

from cobot_calib_msgs.action import CalibrateTcp
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.api.tcp import calibrate_and_store, TcpOutcome
from cobot_calib_ros.core.errors import ErrorCode as E
from cobot_calib_ros.core.tcp.procedure import TcpRequest
from cobot_calib_ros.core.tcp.touches import (DEFAULT_APPROACHES, DEFAULT_ELONGATION,
                                              DEFAULT_TILT)
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.ros import convert, spin
from cobot_calib_ros.ros.diagnostics import OK
from cobot_calib_ros.ros.params import declare
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns

Action = CalibrateTcp
METHODS = {Action.Goal.ORIENTATION_NONE: 'none', Action.Goal.ORIENTATION_Z: 'z',
           Action.Goal.ORIENTATION_ZX: 'zx'}


class TcpCalibrator(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('tcp_calibrator', job='a TCP calibration',
                         cell_help='Cell YAML (path or name): robot, T_flange_tool, the fixed '
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

    def _request(self, goal) -> TcpRequest:
        """The goal with its defaults (0 / '': the cell's first point, the parameters')."""
        return TcpRequest(
            point=goal.point_name or next(iter(self._cell.point_names), ''),
            count=int(goal.orientations) or DEFAULT_APPROACHES,
            tilt=float(goal.tilt) or DEFAULT_TILT, method=METHODS.get(goal.orientation, ''),
            elongation=float(goal.elongation) or DEFAULT_ELONGATION,
            hold=float(goal.hold) or self._p('hold_duration'),
            touch_sigma=self._p('touch_sigma'))

    def _run(self, goal_handle):
        goal, result = goal_handle.request, Action.Result()
        result.tool = goal.tool or self._cell.tool_frame
        if goal.orientation not in METHODS:
            return self._end(goal_handle, result, E.INVALID_INPUT,
                             f'orientation {goal.orientation}: use ORIENTATION_NONE (0), '
                             'ORIENTATION_Z (1) or ORIENTATION_ZX (2)')
        try:
            rig = self._rig(self._p('kinematics'))
        except (KeyError, ValueError) as e:
            return self._end(goal_handle, result, E.INVALID_INPUT, str(e).strip("'"))
        feedback = Action.Feedback()

        def on_touch(i: int, total: int, rms_m: float) -> None:
            feedback.touch_index, feedback.total, feedback.residual_mm = i, total, rms_m * 1e3
            goal_handle.publish_feedback(feedback)
        self._health.set(OK, f'calibrating the TCP of {result.tool}')
        outcome = calibrate_and_store(
            self._request(goal), self._robot, rig, self._repository(), result.tool,
            now_ns(self), cancelled=lambda: goal_handle.is_cancel_requested,
            progress=on_touch, warn=self.get_logger().warning)
        if outcome:
            _fill(result, outcome)
        return self._end(goal_handle, result, outcome.code, outcome.message)


def _fill(result, outcome: TcpOutcome) -> None:
    """The result fields of a stored TCP calibration ([m]; the _mm fields in mm)."""
    position = outcome.run.solution.position
    result.calibration_id, result.active = outcome.record.id, outcome.active
    result.t_flange_tool = convert.matrix_to_transform(outcome.run.solution.T_flange_tool, '',
                                                      '').transform
    result.fixed_point.x, result.fixed_point.y, result.fixed_point.z = (
        float(v) for v in position.c)
    result.mean_residual_mm = position.mean_residual_m * 1e3
    result.max_residual_mm = position.max_residual_m * 1e3
    result.condition = position.condition
    result.orientations_used = len(position.residuals)


def main(args=None) -> None:
    spin.run(TcpCalibrator, args, threads=2)


if __name__ == '__main__':
    main()
