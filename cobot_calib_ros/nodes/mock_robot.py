"""mock_robot: stands in for the Sawyer / iiwa arm, its proximity probe and the cell.

The controller plans with the nominal kinematic model, as a real controller does; the tool ends
up where the true model puts it, plus unidirectional repeatability noise that the encoders do
not see. joint_states carries commanded positions plus encoder noise.
"""
from __future__ import annotations

import threading
import time

from builtin_interfaces.msg import Time
from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.msg import ProbeVoltage
from cobot_calib_msgs.srv import GetGroundTruth
import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cobot_calib_ros import paths
from cobot_calib_ros.ros import convert
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.params import declare

FEEDBACK_PERIOD = 0.02  # [s] of simulated (scaled) time between feedback messages


def stamp_now() -> Time:
    ns = time.time_ns()
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class PacedLoop:
    """Calls `tick()` at a steady rate from its own thread (rclpy timers cannot hold 1 kHz)."""

    def __init__(self, rate_hz: float, tick, ok) -> None:
        self._period = 1.0 / rate_hz
        self._tick = tick
        self._ok = ok
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name='paced_loop')

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        deadline = time.perf_counter()
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception:
                if self._ok():
                    raise
                return                      # Ctrl-C shut the context down before stop()
            deadline += self._period
            remaining = deadline - time.perf_counter()
            if remaining < -0.1:           # fell far behind (suspended): do not burst
                deadline = time.perf_counter()
                continue
            if remaining > 3e-4:
                time.sleep(remaining - 2.5e-4)
            while time.perf_counter() < deadline:
                pass                        # the last ~0.25 ms: sleep() is too coarse


class MockRobot(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('mock_robot', **kwargs)
        self._declare_parameters()
        self._cell = cellmod.load_cell(paths.cell_file(self._param('cell_file')),
                                       self._param('layout') or None)
        self._setup_kinematics()
        seed = self._cell.seed + 1000
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._q = self._cell.home.copy()
        self._tool_noise = np.zeros(3)
        self._moving = False
        self._update_true_tool()

        rate = self._param('publish_rate_hz') or self._cell.joint_states_hz
        probe_rate = self._param('probe_rate_hz') or self._cell.probe_hz
        self._probe_every = max(1, round(rate / probe_rate))
        self._ticks = 0
        self._joint_msg = JointState(name=list(self._model.joint_names))
        self._probe_msg = ProbeVoltage()
        self._probe_msg.header.frame_id = 'probe'
        self._js_pub = self.create_publisher(
            JointState, 'joint_states',
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self._probe_pub = self.create_publisher(ProbeVoltage, 'probe/voltage',
                                                qos_profile_sensor_data)
        self._action = ActionServer(
            self, MoveTo, 'move_to', execute_callback=self._execute_move,
            goal_callback=self._accept_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(GetGroundTruth, 'get_ground_truth', self._on_ground_truth,
                            callback_group=ReentrantCallbackGroup())
        self._loop = PacedLoop(rate, self._publish_tick, self.context.ok)
        self._loop.start()
        self.get_logger().info(
            f'{self._cell.robot} cell "{self._cell.name}" layout {self._cell.layout}: '
            f'joint_states at {rate:.0f} Hz, probe at {rate / self._probe_every:.0f} Hz, '
            f'time scale {self._time_scale}')

    # -- set-up ---------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        declare(self, 'cell_file', 'sawyer_close',
                'Cell scenario YAML: a path or a name in config/cells')
        declare(self, 'layout', '',
                'Marker layout of the cell (close, wide, ...); empty = the cell default')
        declare(self, 'publish_rate_hz', 0.0,
                'joint_states rate [Hz]; 0 = the cell file value', 0.0, 5000.0)
        declare(self, 'probe_rate_hz', 0.0,
                'probe/voltage rate [Hz]; 0 = the cell file value', 0.0, 5000.0)
        declare(self, 'time_scale', -1.0,
                'Simulated motion time = real time * time_scale [1]; <0 = cell value')
        declare(self, 'joint_velocity', 1.0, 'Joint velocity at speed_scale 1 [rad/s]',
                0.01, 10.0)

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _setup_kinematics(self) -> None:
        self._model = kinematics.model_by_name(self._cell.robot)
        self._true_params = cellmod.true_parameters(
            self._cell, self._model.nominal, self._model.parameter_names)
        tool = self._cell.tool_offset
        self._nominal = self._model.chain(tool=tool)
        self._true = self._model.chain(self._true_params, tool=tool)
        scale = self._param('time_scale')
        self._time_scale = self._cell.time_scale if scale < 0 else scale

    # -- state ----------------------------------------------------------------------------
    def _update_true_tool(self) -> None:
        T = kinematics.fk(self._true, self._q)
        T[:3, 3] += self._tool_noise
        self._T_true_tool = T

    def _publish_tick(self) -> None:
        with self._lock:
            q = self._q.copy()
            T_tool = self._T_true_tool
        noise = self._rng.normal(0.0, self._cell.noise.encoder_sigma, q.shape)
        msg = self._joint_msg
        msg.header.stamp = stamp_now()
        msg.position = (q + noise).tolist()
        self._js_pub.publish(msg)
        self._ticks += 1
        if self._ticks % self._probe_every == 0:
            gap = self._cell.world.probe_gap(T_tool)
            volts = self._cell.probe.to_voltage(gap)
            self._probe_msg.header.stamp = msg.header.stamp
            self._probe_msg.voltage = volts + self._rng.normal(
                0.0, self._cell.noise.probe_voltage_sigma)
            self._probe_pub.publish(self._probe_msg)

    # -- motion ---------------------------------------------------------------------------
    def _accept_goal(self, goal) -> GoalResponse:
        return GoalResponse.REJECT if self._moving else GoalResponse.ACCEPT

    def _target_joints(self, goal) -> tuple[np.ndarray | None, str]:
        """Joint target for a goal, or (None, why not)."""
        if goal.target_type == MoveTo.Goal.TARGET_JOINTS:
            q = np.asarray(goal.positions, dtype=float)
            if q.shape != self._q.shape or not np.all(np.isfinite(q)):
                return None, (f'expected {len(self._q)} finite joint positions [rad], '
                              f'got {list(goal.positions)}')
            return self._within_limits(q)
        if goal.target_type == MoveTo.Goal.TARGET_POSE:
            T = convert.pose_to_matrix(goal.pose)
            return self._solve(self._nominal, T)
        if goal.target_type == MoveTo.Goal.TARGET_TOUCH:
            return self._touch_target(goal.point_name)
        return None, f'unknown target_type {goal.target_type}; use TARGET_JOINTS/POSE/TOUCH'

    def _within_limits(self, q: np.ndarray) -> tuple[np.ndarray | None, str]:
        bad = np.flatnonzero((q < self._nominal.lower) | (q > self._nominal.upper))
        if bad.size:
            names = [self._model.joint_names[i] for i in bad]
            return None, f'joint target outside the limits of {names}'
        return q, ''

    def _solve(self, chain, T: np.ndarray) -> tuple[np.ndarray | None, str]:
        if not np.all(np.isfinite(T)):
            return None, 'target pose has NaN or inf'
        result = kinematics.solve_ik_with_restarts(chain, T, self._q, self._cell.home)
        if not result.success:
            return None, f'no inverse kinematics solution: {result.message}'
        return result.q, ''

    def _touch_target(self, name: str) -> tuple[np.ndarray | None, str]:
        """Simulate the operator hand-guiding the tool tip onto a marker's top centre."""
        marker = self._cell.world.marker(name)
        if marker is None:
            return None, (f'unknown point {name!r}; the cell has '
                          f'{self._cell.world.point_names}')
        world = self._cell.world
        T = np.eye(4)
        T[:3, :3] = cellmod.tool_down_orientation(world.T_base_user)
        T[:3, 3] = frames.apply(world.T_base_user, marker.true_top)
        T[:3, 3] += self._rng.normal(0.0, self._cell.noise.touch_sigma, 3)
        return self._solve(self._true, T)  # the hand puts the real tool there

    def _execute_move(self, goal_handle):
        goal = goal_handle.request
        result = MoveTo.Result()
        q_target, why = self._target_joints(goal)
        if q_target is None:
            goal_handle.abort()
            result.error_code = (MoveTo.Result.UNREACHABLE if 'kinematics' in why
                                 else MoveTo.Result.INVALID_TARGET)
            result.message = why
            self.get_logger().warning(f'move_to refused: {why}')
            return result
        self._moving = True
        try:
            canceled = self._interpolate(goal_handle, q_target, goal.speed_scale or 1.0)
        finally:
            self._moving = False
        result.positions = self._q.tolist()
        if canceled:
            goal_handle.canceled()
            result.error_code, result.message = MoveTo.Result.CANCELED, 'canceled'
            return result
        goal_handle.succeed()
        result.error_code, result.message = MoveTo.Result.SUCCESS, 'reached'
        return result

    def _interpolate(self, goal_handle, q_target: np.ndarray, speed_scale: float) -> bool:
        """Move along a joint-space line; returns True when canceled."""
        q_start = self._q.copy()
        velocity = self._param('joint_velocity') * min(max(speed_scale, 0.01), 1.0)
        duration = float(np.max(np.abs(q_target - q_start))) / velocity * self._time_scale
        steps = max(1, int(duration / (FEEDBACK_PERIOD * max(self._time_scale, 1e-3))))
        feedback = MoveTo.Feedback()
        for k in range(1, steps + 1):
            if goal_handle.is_cancel_requested:
                self._settle(self._q)
                return True
            s = k / steps
            s = s * s * (3.0 - 2.0 * s)  # smooth start and stop
            with self._lock:
                self._q = q_start + s * (q_target - q_start)
                self._tool_noise = np.zeros(3)
                self._update_true_tool()
            feedback.progress = k / steps
            feedback.positions = self._q.tolist()
            goal_handle.publish_feedback(feedback)
            time.sleep(duration / steps)
        self._settle(q_target)
        return False

    def _settle(self, q: np.ndarray) -> None:
        """Come to rest: the tool lands within the robot's unidirectional repeatability."""
        with self._lock:
            self._q = np.asarray(q, dtype=float).copy()
            sigma = cellmod.repeatability_sigma_at(self._cell, self._T_true_tool[:3, 3])
            self._tool_noise = self._rng.normal(0.0, sigma, 3)
            self._update_true_tool()

    # -- ground truth ---------------------------------------------------------------------
    def _on_ground_truth(self, request, response):
        world = self._cell.world
        response.robot = self._cell.robot
        response.user_frame = convert.matrix_to_transform(
            world.T_base_user, self._cell.base_frame, self._cell.user_frame)
        response.point_names = world.point_names
        response.points_base = convert.array_to_points(world.true_points_base())
        response.points_user = convert.array_to_points(world.nominal_points_user())
        response.parameter_names = list(self._model.parameter_names)
        response.nominal_parameters = self._model.nominal.tolist()
        response.true_parameters = self._true_params.tolist()
        response.repeatability_sigma = cellmod.layout_repeatability_sigma(self._cell)
        response.touch_sigma = self._cell.noise.touch_sigma
        return response

    def destroy_node(self):
        self._loop.stop()
        return super().destroy_node()


def main(args=None) -> None:
    spin.run(MockRobot, args, threads=3)


if __name__ == '__main__':
    main()
