"""robot_adapter: the suite's ``move_to`` over a ros2_control arm.

Serves ``move_to`` (cobot_calib_msgs/action/MoveTo), the one motion interface the calibration
nodes use (ros.robot_calls.RobotCalls), by sending a control_msgs/FollowJointTrajectory goal to
the arm's joint_trajectory_controller, then waiting on ``joint_states`` until the arm has
settled (core.driver.SettleWatch) before it answers, so no capture starts on a ringing arm:
- a joint target goes as is; a pose target (the cell's TCP in the base frame) is solved on the
  ``kinematics`` model (core.rig): the active kinematic calibration of the cell's robot, read
  at each pose goal (nominal while it has none), ``nominal``, or a calibration id; seeded at
  the current joints (a ros2_control arm takes joints: the suite's IK is the controller's);
- one trajectory point at max |dq| / (max_joint_velocity * velocity_scaling * speed_scale);
- a compliant move goes to the preset's ``compliant_action`` (refused where there is none);
- a cancel of move_to is forwarded to the controller;
- every FollowJointTrajectory error code, a rejected goal and an arm that never settles answer
  one clear message (core.driver) through the one failure type (core.errors, ros/results).
The driver comes from a preset in config/driver_presets.yaml (``driver``: mock, ur, lbr, franka).
``joint_states`` is taken raw and decoded only when needed (the latest message, and every
message while settling), so the 1 kHz stream costs little.
"""
from __future__ import annotations

import threading
import time

from cobot_calib_msgs.action import MoveTo
from control_msgs.action import FollowJointTrajectory
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint
import yaml

from cobot_calib_ros import paths
from cobot_calib_ros.core import driver, kinematics, rig
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.rig import Rig
from cobot_calib_ros.nodes.job_node import read_cell_setup
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.store.rigs import rig_of
from cobot_calib_ros.ros import convert, qos, results, spin
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import MOVE_RESULT_KEEP
from cobot_calib_ros.ros.time import header_ns, ns_to_s, s_to_ns, split_ns

ACCEPT_TIMEOUT = 10.0   # [s] for the controller to accept or reject a trajectory goal
RESULT_MARGIN = 60.0    # [s] past the trajectory's end before a move is given up
SERVER_WAIT = 5.0       # [s] for the controller's action server to be discovered
POLL = 0.01             # [s] between looks at a cancel request while waiting
CANCELED = Failure(ErrorCode.CANCELED, 'canceled')   # a move_to goal canceled by its client


class RobotAdapter(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('robot_adapter', **kwargs)
        self._setup = read_cell_setup(
            self, cell_help='Cell YAML (robot model, tool, home): a path or a name in '
            'config/cells', data_help='Results root (the active kinematic calibration)')
        read_once(self, 'driver', 'mock', 'Driver preset: a name in presets_file')
        read_once(self, 'presets_file', '',
                  'Driver presets YAML; empty = config/driver_presets.yaml')
        declare(self, 'kinematics', 'latest', 'Model pose targets are solved on: latest (the '
                'active kinematic calibration of the cell\'s robot, nominal if none), nominal, '
                'or a kinematic calibration id')
        self._preset = self._load_preset()
        cell = self._setup.cell
        self._cell, self._home, self._model = cell, cell.home, self._setup.model
        self._model_names = tuple(self._model.joint_names)
        self._chain = Rig(cell, model=self._model).nominal_chain()     # the joint limits
        self._names = self._preset.joint_names or self._model_names
        self._answers = spin.Companion(self, 'driver')
        self._latest: bytes | None = None        # the last joint_states, raw
        self._order = None     # (message joint names, index of each model joint in them)
        self._watch: driver.SettleWatch | None = None   # set while settling
        self._lock = threading.Lock()
        self._answers.node.create_subscription(JointState, 'joint_states', self._on_joints,
                                               qos.JOINT_STATES, raw=True)
        self._trajectory_clients = {
            name: ActionClient(self._answers.node, FollowJointTrajectory, name)
            for name in {self._preset.action, self._preset.compliant_action} if name}
        self._busy = False
        ActionServer(self, MoveTo, 'move_to', execute_callback=self._execute,
                     goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
                     callback_group=MutuallyExclusiveCallbackGroup(),
                     result_timeout=MOVE_RESULT_KEEP)
        self.get_logger().info(
            f'driver {self._preset.name}: move_to -> {self._preset.action} '
            f'({", ".join(self._names)}), settled below {self._preset.settle_speed} rad/s over '
            f'{self._preset.settle_window} s')

    def _load_preset(self) -> driver.DriverPreset:
        given = self.get_parameter('presets_file').value
        path = paths.config_dir() / 'driver_presets.yaml' if not given else paths.Path(given)
        try:
            presets = driver.parse_presets(yaml.safe_load(path.read_text()))
        except (OSError, yaml.YAMLError) as e:
            raise SystemExit(f'robot_adapter: cannot read the driver presets {path}: {e}')
        if isinstance(presets, Failure):
            raise SystemExit(f'robot_adapter: {path}: {presets.message}')
        name = self.get_parameter('driver').value
        if name not in presets:
            raise SystemExit(f'robot_adapter: no driver preset {name!r} in {path}; known: '
                             f'{", ".join(presets)}')
        return presets[name]

    # -- joint_states (companion thread) --------------------------------------------------
    def _on_joints(self, raw: bytes) -> None:
        self._latest = raw
        watch = self._watch
        if watch is not None:
            t, q = self._decode(raw)
            if not isinstance(q, Failure):
                with self._lock:
                    watch.add(t, q)

    def _decode(self, raw: bytes) -> tuple[float, np.ndarray | Failure | None]:
        """(stamp [s], joints in the model's order [rad]) of a raw joint_states message."""
        msg = deserialize_message(raw, JointState)
        if self._order is None or self._order[0] != msg.name:
            order = driver.joint_order(self._preset.joint_names, self._model_names,
                                       list(msg.name))
            if isinstance(order, Failure):
                return 0.0, order
            self._order = (list(msg.name), order)
        return ns_to_s(header_ns(msg)), np.asarray(msg.position)[self._order[1]]

    def _current(self) -> np.ndarray | Failure:
        if self._latest is None:
            return Failure(ErrorCode.NO_DATA, 'no joint_states from the driver yet; is the '
                           'joint_state_broadcaster running (and in this namespace)?')
        return self._decode(self._latest)[1]

    # -- move_to ----------------------------------------------------------------------------
    def _accept(self, _goal) -> GoalResponse:
        return GoalResponse.REJECT if self._busy else GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        self._busy = True
        result = MoveTo.Result()
        try:
            outcome = self._move(goal_handle)
        except TimeoutError as e:        # spin.Stopping too: the node is shutting down
            outcome = Failure(ErrorCode.MOTION_FAILED, f'{self._preset.action}: {e}')
        finally:
            self._busy = False
        if isinstance(outcome, Failure) and outcome.code == ErrorCode.CANCELED:
            goal_handle.canceled()
            return results.fill(result, 'MoveTo', outcome)
        if isinstance(outcome, Failure):
            goal_handle.abort()
            results.fill(result, 'MoveTo', outcome)
            self.get_logger().warning(f'move_to failed: {outcome.message}')
            return result
        q, seconds = outcome
        goal_handle.succeed()
        results.answer(result, ErrorCode.SUCCESS, 'reached and settled')
        result.positions, result.duration = q.tolist(), seconds
        return result

    def _move(self, goal_handle):
        """(target joints, trajectory seconds), or a Failure (CANCELED when canceled)."""
        goal = goal_handle.request
        q_now = self._current()
        if isinstance(q_now, Failure):
            return q_now
        q_target = self._target(goal, q_now)
        if isinstance(q_target, Failure):
            return q_target
        action = self._preset.compliant_action if goal.compliant else self._preset.action
        if not action:
            return Failure(ErrorCode.NOT_AVAILABLE, f'driver {self._preset.name} has no '
                           'compliant controller (compliant_action in its preset): collect '
                           'spheres with an impedance/admittance trajectory controller')
        seconds = self._preset.move_seconds(q_now, q_target, goal.speed_scale)
        try:
            ended = self._follow(goal_handle, action, q_target, seconds)
            if ended is not None:
                return ended
            settled = self._settle(goal_handle)
            return settled if settled is not None else (q_target, seconds)
        finally:
            self._watch = None             # joint_states are decoded only while settling

    def _target(self, goal, q_now: np.ndarray) -> np.ndarray | Failure:
        chain = self._chain
        if goal.target_type == MoveTo.Goal.TARGET_JOINTS:
            q = np.asarray(goal.positions, dtype=float)
            if q.shape != q_now.shape or not np.all(np.isfinite(q)):
                return Failure(ErrorCode.INVALID_INPUT, f'expected {len(q_now)} finite joint '
                               f'positions [rad], got {q.tolist()}')
            bad = np.flatnonzero((q < chain.lower) | (q > chain.upper))
            if bad.size:
                return Failure(ErrorCode.INVALID_INPUT, 'joint target outside the limits of '
                               f'{[self._model_names[i] for i in bad]}')
            return q
        if goal.target_type == MoveTo.Goal.TARGET_POSE:
            T = convert.pose_to_matrix(goal.pose)
            if not np.all(np.isfinite(T)):
                return Failure(ErrorCode.INVALID_INPUT, 'target pose has NaN or inf')
            chain = self._pose_chain()
            if isinstance(chain, Failure):
                return chain
            solved = rig.solve_target(chain, T, q_now, self._home)
            if not solved:
                return Failure(ErrorCode.MOTION_FAILED,
                               f'no inverse kinematics solution: {solved.message}')
            return solved.q
        return Failure(ErrorCode.INVALID_INPUT, f'unknown target_type {goal.target_type}; use '
                       'TARGET_JOINTS or TARGET_POSE')

    def _pose_chain(self) -> kinematics.Chain | Failure:
        """The TCP chain of the ``kinematics`` parameter's model, from the stored results."""
        choice = self.get_parameter('kinematics').value
        try:
            repo = self._setup.repository()
            the_rig = rig_of(repo, self._cell, choice, self._model)
            chain = the_rig.chain('tcp')
        except (KeyError, ValueError, OSError) as e:
            return Failure(ErrorCode.INVALID_INPUT, f'kinematics {choice!r}: {e}; set the '
                           'kinematics parameter to latest, nominal or a stored kinematic '
                           'calibration id')
        for stale in the_rig.active.stale_used('tcp', False):
            self.get_logger().warning(f'stale: {stale.line()}')
        return chain

    def _follow(self, goal_handle, action: str, q: np.ndarray, seconds: float):
        """Run one trajectory to its end: None when it succeeded, else the Failure (CANCELED
        when canceled)."""
        client = self._trajectory_clients[action]
        if not client.wait_for_server(timeout_sec=SERVER_WAIT):
            return Failure(ErrorCode.NOT_AVAILABLE, f'no {action} action server; is the driver '
                           f'up and its trajectory controller active (driver {self._preset.name})?')
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(self._names)
        goal.trajectory.points = [JointTrajectoryPoint(
            positions=q.tolist(), velocities=[0.0] * len(q), time_from_start=_duration(seconds))]
        goal.goal_time_tolerance = _duration(self._preset.goal_time_tolerance)
        sent = self._answers.send_goal(client, goal, ACCEPT_TIMEOUT)
        if sent is None:
            return driver.rejected(action)
        handle, done = sent
        deadline = time.monotonic() + seconds + self._preset.goal_time_tolerance + RESULT_MARGIN
        canceling = False
        while True:
            try:
                answer = spin.wait(done, POLL)
                break
            except spin.Stopping:            # the node is shutting down: stop the arm too
                self._answers.submit(handle.cancel_goal_async)
                raise
            except TimeoutError:
                pass
            if goal_handle.is_cancel_requested and not canceling:
                self._answers.submit(handle.cancel_goal_async)    # forwarded
                canceling = True
            if time.monotonic() > deadline:
                self._answers.submit(handle.cancel_goal_async)
                return Failure(ErrorCode.MOTION_FAILED, f'{action} did not end the move within '
                               f'{seconds + RESULT_MARGIN:.0f} s; the goal was canceled')
        if canceling:
            return CANCELED
        code = answer.result.error_code
        if code != FollowJointTrajectory.Result.SUCCESSFUL:
            return driver.trajectory_failure(action, code, answer.result.error_string)
        if answer.status != GoalStatus.STATUS_SUCCEEDED:
            return driver.aborted_without_code(action, _status_name(answer.status))
        return None

    def _settle(self, goal_handle):
        """None once the arm is at rest (SettleWatch over readings taken after the trajectory
        ended: at least one whole window of them), else the Failure (CANCELED when canceled)."""
        with self._lock:       # the readings from the trajectory's end on
            self._watch = driver.SettleWatch(self._preset.settle_speed,
                                             self._preset.settle_window)
        started = time.monotonic()
        while time.monotonic() - started < self._preset.settle_timeout:
            if goal_handle.is_cancel_requested:
                return CANCELED
            with self._lock:
                if self._watch.settled():
                    return None
            spin.pause(POLL)
        with self._lock:
            return driver.not_settled(self._watch, self._names, self._preset.settle_timeout)

    def destroy_node(self):
        self._answers.destroy()
        return super().destroy_node()


def _duration(seconds: float) -> Duration:
    sec, nanosec = split_ns(s_to_ns(seconds))
    return Duration(sec=sec, nanosec=nanosec)


def _status_name(status: int) -> str:
    return {GoalStatus.STATUS_ABORTED: 'aborted', GoalStatus.STATUS_CANCELED: 'canceled'}.get(
        status, f'with status {status}')


def main(args=None) -> None:
    spin.run(RobotAdapter, args, threads=3)


if __name__ == '__main__':
    main()
