"""mock_robot: stands in for the Sawyer / iiwa arm driver, its proximity probe and the cell.

A thin shell over sim.robot.SimRobot (the one simulated robot): publishes joint_states and
probe/voltage stamped with the node clock (use_sim_time works; joint_states go out a few at a
time, PUBLISH_WAKES_HZ, their stamps evenly spaced up to now), serves move_to like a driver
would, and what only a simulation can answer: get_ground_truth, and mock_robot/hand_guide (the
simulated operator hand-guiding the tool onto a cell point, HandGuide.srv).

/diagnostics (1 Hz): ``published`` joint_states, ``publish_rate_hz`` and
``publish_gap_max_ms`` over the last second, ``stamp_gaps_missing`` (the publisher's own
stalls, counted as a subscriber counts missing stamps), ``mark_stamp_s`` with
``published_before_mark`` (messages stamped before that whole second: a subscriber's count
before the same second gives the exact loss, see core.sensors.joint_buffer.StampMarks),
``probe_published``, ``probe_dropped`` (readings lost to a stall longer than PROBE_BACKLOG),
``moving``, the cell, robot and layout. WARN when joint_states run below
90 % of their rate, ERROR when the publishing thread has stopped.

``robot_interface``: ``move_to`` (default) serves the suite's own MoveTo action, as above;
``driver`` stands in for a ros2_control arm instead: it offers what a real driver offers,
joint_states and control_msgs/FollowJointTrajectory on
``joint_trajectory_controller/follow_joint_trajectory`` (as ros2_control's mock hardware under a
joint_trajectory_controller), plus ``compliant_trajectory_controller/follow_joint_trajectory``
(the same under impedance control: a coupling near a sphere self-centres), and no move_to:
``robot_adapter`` serves move_to then. The simulated operator (hand_guide), the laser tracker and
get_ground_truth stay: they are the cell, not the driver. ``driver_fault`` makes the driver
misbehave for tests: ``reject`` every trajectory goal, ``abort`` half-way
(PATH_TOLERANCE_VIOLATED), ``ring`` (joint_states oscillate after every move: never settles).
"""
from __future__ import annotations

import math
import threading
import time

from cobot_calib_msgs.action import MoveTo
from control_msgs.action import FollowJointTrajectory
from cobot_calib_msgs.msg import ProbeVoltage
from cobot_calib_msgs.srv import GetGroundTruth, HandGuide, MeasurePosition
from geometry_msgs.msg import Pose
import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState

from cobot_calib_ros import paths
from cobot_calib_ros.core.driver import move_seconds
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.robot_port import Approach, elongator_problem
from cobot_calib_ros.core.sensors.joint_buffer import StampGaps, StampMarks
from cobot_calib_ros.core.sensors.sample_clock import SampleClock
from cobot_calib_ros.ros import convert, qos, results, spin
from cobot_calib_ros.ros.joint_state_bytes import JointStateBytes
from cobot_calib_ros.ros.probe_voltage_bytes import ProbeVoltageBytes
from cobot_calib_ros.ros.robot_calls import MOVE_RESULT_KEEP
from cobot_calib_ros.ros.diagnostics import Diagnostics, ERROR, OK, RateMeter, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.time import ns_to_s, NS_PER_S, s_to_ns, stamp_to_ns
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

FEEDBACK_PERIOD = 0.02  # [s] of wall time between motion steps
# a motion's feedback after every this many steps (10 Hz) and after its last: every job node's
# move_to client takes each feedback message of every move (and drops what is not its own)
FEEDBACK_EVERY_STEPS = 5
INTERFACES = ('move_to', 'driver')
DRIVER_FAULTS = ('', 'reject', 'abort', 'ring')
TRAJECTORY_ACTION = 'joint_trajectory_controller/follow_joint_trajectory'
COMPLIANT_ACTION = 'compliant_trajectory_controller/follow_joint_trajectory'
RING_AMPLITUDE = 2e-3   # [rad] of the first joint's oscillation under driver_fault ring
RING_HZ = 8.0           # [Hz]
# joint_states are published this many times a second at most, each time the messages stamped
# since the previous (a 1 kHz stream: 10 per wake, the newest stamped now): one wake per message
# cost ~15 % of a core in the publishing thread, nearly all of it Python and numpy overhead;
# 100 against 250 wakes: mock_robot 5.8-8.9 % against 8.2-9.7 % of a core in an idle ur10e_close
# suite (four pairs, side by side), its readers a little less too
PUBLISH_WAKES_HZ = 100.0
CATCH_UP_NS = 100_000_000   # [ns] a later tick fills its gap evenly (a stall shows as gaps)
SLOW_RATE_FRACTION = 0.9  # [1] of the nominal joint_states rate: below it, WARN
# [s] of probe readings the simulated probe buffers while the publisher is starved: they are
# published late, in a burst, each stamped with the time it was taken (core.sensors.sample_clock)
PROBE_BACKLOG = 3.0      # proximity_sensor.STALL_TIMEOUT: a window waits that long for them


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

    def alive(self) -> bool:
        return self._thread.is_alive()

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
            if remaining > 0:
                # no busy wait for the last fraction of a period (it cost ~25 % of a core at
                # 1 kHz): sleep() wakes ~0.05-0.1 ms late, and the absolute deadlines keep
                # the rate exact over time
                time.sleep(remaining)


_SHUTTING_DOWN = Failure(ErrorCode.CANCELED, 'the mock robot is shutting down (Ctrl-C or '
                         'SIGTERM); the arm stopped where it was')


class MockRobot(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('mock_robot', **kwargs)
        self._declare_parameters()
        self._sim = load_simulation(paths.cell_file(self._param('cell_file')),
                                    self._param('layout') or None)
        self._robot = SimRobot(self._sim)
        scale = self._param('time_scale')
        self._time_scale = self._sim.time_scale if scale < 0 else scale
        self._moving = False
        self._motion_s = 0.0     # simulated duration of the latest move [s]
        rate = self._param('publish_rate_hz') or self._sim.joint_states_hz
        probe_rate = self._param('probe_rate_hz') or self._sim.probe_hz
        self._probe_clock = SampleClock(s_to_ns(1.0 / probe_rate), s_to_ns(PROBE_BACKLOG))
        self._rate = rate
        self._marks = StampMarks()          # joint_states published, by stamp second
        self._gaps = StampGaps(rate)
        self._probe_published = 0
        self._rate_meter = RateMeter()
        self._joint_states = JointStateBytes(list(self._robot.model.joint_names))
        self._probe_bytes = ProbeVoltageBytes('probe')
        self._js_pub = self.create_publisher(JointState, 'joint_states', qos.JOINT_STATES)
        self._probe_pub = self.create_publisher(ProbeVoltage, 'probe/voltage',
                                                qos.PROBE_READINGS)
        self._ringing = False      # driver_fault ring, after a move until the next or a reset
        self.add_post_set_parameters_callback(self._fault_changed)
        if self._param('robot_interface') == 'driver':
            self._trajectory_servers = [ActionServer(
                self, FollowJointTrajectory, name,
                execute_callback=lambda handle, comply=comply: self._follow(handle, comply),
                goal_callback=self._accept_trajectory,
                cancel_callback=lambda _: CancelResponse.ACCEPT,
                callback_group=MutuallyExclusiveCallbackGroup(), result_timeout=MOVE_RESULT_KEEP)
                for name, comply in ((TRAJECTORY_ACTION, False), (COMPLIANT_ACTION, True))]
        else:
            self._action = ActionServer(
                self, MoveTo, 'move_to', execute_callback=self._execute_move,
                goal_callback=self._accept_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
                callback_group=MutuallyExclusiveCallbackGroup(), result_timeout=MOVE_RESULT_KEEP)
        self.create_service(GetGroundTruth, 'get_ground_truth', self._on_ground_truth,
                            callback_group=ReentrantCallbackGroup())
        self.create_service(MeasurePosition, 'laser_tracker/measure', self._on_laser,
                            callback_group=ReentrantCallbackGroup())
        self._motion_lock = threading.Lock()      # one motion at a time: move_to or hand_guide
        self.create_service(HandGuide, '~/hand_guide', self._on_hand_guide,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self._per_wake = max(1, round(rate / PUBLISH_WAKES_HZ))
        self._last_stamp_ns: int | None = None
        self._loop = PacedLoop(rate / self._per_wake, self._publish_tick, self.context.ok)
        cell = self._sim.cell
        self._diagnostics = Diagnostics(self, hardware_id=cell.robot, update=self._diagnose)
        self._loop.start()
        self.get_logger().info(
            f'{cell.robot} cell "{cell.name}" layout {cell.layout}: joint_states at '
            f'{rate:.0f} Hz, probe at {probe_rate:.0f} Hz, time scale '
            f'{self._time_scale}')

    # -- set-up ---------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        read_once(self, 'cell_file', paths.DEFAULT_CELL,
                  'Cell scenario YAML (cell: and simulation:): a path or a name in config/cells')
        read_once(self, 'layout', '',
                  'Marker layout of the cell (close, wide, ...); empty = the cell default')
        read_once(self, 'publish_rate_hz', 0.0,
                  'joint_states rate [Hz]; 0 = the cell file value', 0.0, 5000.0)
        read_once(self, 'probe_rate_hz', 0.0,
                  'probe/voltage rate [Hz]; 0 = the cell file value', 0.0, 5000.0)
        declare(self, 'time_scale', -1.0,
                'Simulated motion time = real time * time_scale [1]; <0 = cell value')
        declare(self, 'joint_velocity', 1.0, 'Joint velocity at speed_scale 1 [rad/s]',
                0.01, 10.0)
        read_once(self, 'robot_interface', 'move_to',
                  'move_to: serve the suite\'s MoveTo; driver: joint_states and '
                  'FollowJointTrajectory only, as a ros2_control arm (robot_adapter serves move_to)')
        if self._param('robot_interface') not in INTERFACES:
            raise SystemExit(f'mock_robot: robot_interface {self._param("robot_interface")!r}; '
                             f'use one of {", ".join(INTERFACES)}')
        declare(self, 'driver_fault', '', 'driver mode, for tests: reject (every trajectory '
                'goal), abort (half-way, PATH_TOLERANCE_VIOLATED), ring (never settles); '
                'empty = none')

    def _param(self, name: str):
        return self.get_parameter(name).value

    # -- sensors (the paced thread) -------------------------------------------------------
    @property
    def published(self) -> int:
        """joint_states messages published so far."""
        return self._marks.count

    def _publish_tick(self) -> None:
        """The joint_states stamped since the previous tick, evenly spaced up to now (ROS time:
        a sim clock at any rate), then the probe readings due."""
        now_ns = self.get_clock().now().nanoseconds
        count, last = self._per_wake, self._last_stamp_ns
        if last is None or not 0 <= now_ns - last <= CATCH_UP_NS:    # first, or a clock jump
            last = now_ns - count * s_to_ns(1.0 / self._rate)
        self._last_stamp_ns = now_ns
        stamps_ns = [last + (now_ns - last) * (i + 1) // count for i in range(count)]
        readings = self._robot.joint_readings(count)
        if self._ringing:
            readings[:, 0] += RING_AMPLITUDE * np.sin(2 * np.pi * RING_HZ
                                                      * np.array(stamps_ns) * 1e-9)
        for stamp_ns, data in zip(stamps_ns, self._joint_states.pack_many(stamps_ns, readings)):
            self._js_pub.publish(data)
            self._marks.add(stamp_ns // NS_PER_S)
            self._gaps.add(ns_to_s(stamp_ns))
        for stamp_ns in self._probe_clock.due(now_ns):
            self._probe_pub.publish(self._probe_bytes.pack(stamp_ns, self._robot.probe_voltage()))
            self._probe_published += 1

    def _diagnose(self) -> None:
        """The /diagnostics status, just before each publication."""
        published = self._marks.count
        rate = self._rate_meter.rate_hz(published)
        level, message = OK, f'publishing joint_states at {rate:.0f} Hz'
        if not self._loop.alive():
            level, message = ERROR, 'the joint_states thread has stopped'
        elif published and rate < SLOW_RATE_FRACTION * self._rate:
            level, message = WARN, (f'joint_states at {rate:.0f} Hz, below '
                                    f'{SLOW_RATE_FRACTION:.0%} of {self._rate:.0f} Hz')
        mark_s, before_mark = self._marks.mark
        cell = self._sim.cell
        self._diagnostics.set(
            level, message, published=published, publish_rate_hz=f'{rate:.1f}',
            publish_gap_max_ms=f'{self._gaps.take_max_gap() * 1e3:.3f}',
            stamp_gaps_missing=self._gaps.missing, mark_stamp_s=mark_s,
            published_before_mark=before_mark, probe_published=self._probe_published,
            probe_dropped=self._probe_clock.dropped,
            moving=self._moving, cell=cell.name, robot=cell.robot, layout=cell.layout)

    # -- motion ---------------------------------------------------------------------------
    def _accept_goal(self, goal) -> GoalResponse:
        return GoalResponse.REJECT if self._moving else GoalResponse.ACCEPT

    def _target_joints(self, goal) -> np.ndarray | Failure:
        if goal.target_type == MoveTo.Goal.TARGET_JOINTS:
            return self._robot.plan_joints(goal.positions)
        if goal.target_type == MoveTo.Goal.TARGET_POSE:
            return self._robot.plan_pose(convert.pose_to_matrix(goal.pose))
        return Failure(ErrorCode.INVALID_INPUT, f'unknown target_type {goal.target_type}; '
                       'use TARGET_JOINTS or TARGET_POSE (a touch: mock_robot/hand_guide)')

    def _on_hand_guide(self, request, response):
        """The simulated operator guides the tool onto ``point_name`` (at the default speed),
        in ``orientation`` when ``oriented``; with ``elongator_axis`` 'z' (or 'x') onto the
        elongator point ``elongation`` [m] along that axis of the true tool."""
        q_target = self._touch_target(request)
        if isinstance(q_target, Failure):
            results.fill(response, 'HandGuide', q_target)
            return response
        if not self._motion_lock.acquire(blocking=False):
            return results.answer(response, ErrorCode.BUSY, 'the robot is moving (move_to); '
                                  'touch again when it stops')
        self._moving, self._ringing = True, False
        try:
            self._interpolate(lambda: False, None, q_target, 1.0)
        except spin.Stopping:
            results.fill(response, 'HandGuide', _SHUTTING_DOWN)
            return response
        finally:
            self._moving = False
            self._motion_lock.release()
        response.positions, response.duration = self._robot.q.tolist(), self._motion_s
        return results.answer(response, ErrorCode.SUCCESS,
                              f'the operator guided the tool onto {request.point_name}')

    def _touch_target(self, request) -> np.ndarray | Failure:
        name, axis, distance = request.point_name, request.elongator_axis, request.elongation
        problem = elongator_problem(axis, distance)
        if problem is not None:
            return problem
        if not request.oriented:
            if axis:
                return Failure(ErrorCode.INVALID_INPUT, f'the elongator point of {name} needs '
                               'the tool orientation (oriented: true)')
            return self._robot.plan_touch(name)
        q = request.orientation
        norm = math.sqrt(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2)
        if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            return Failure(ErrorCode.INVALID_INPUT, f'orientation is not a unit quaternion '
                           f'(|q| = {norm:.6g}); give x y z w of the tool in the base frame')
        R = convert.pose_to_matrix(Pose(orientation=q))[:3, :3]
        return self._robot.plan_touch(name, approach=Approach(R, axis, distance))

    def _execute_move(self, goal_handle):
        goal = goal_handle.request
        q_target = self._target_joints(goal)
        if isinstance(q_target, Failure):
            self.get_logger().warning(f'move_to refused: {q_target.message}')
            return self._end_move(goal_handle, q_target)
        if not self._motion_lock.acquire(blocking=False):
            return self._end_move(goal_handle, Failure(ErrorCode.MOTION_FAILED,
                                                       'robot busy (a touch)'))
        self._moving = True
        try:
            ended = self._interpolate(lambda: goal_handle.is_cancel_requested,
                                      goal_handle.publish_feedback, q_target,
                                      goal.speed_scale or 1.0)
            if goal.compliant and not ended:
                ended = self._comply(q_target)
        except spin.Stopping:
            ended = _SHUTTING_DOWN
        finally:
            self._moving = False
            self._motion_lock.release()
        return self._end_move(goal_handle, ended if isinstance(ended, Failure) else None,
                              self._robot.q, canceled=ended is True)

    def _end_move(self, goal_handle, failure: Failure | None, q: np.ndarray | None = None,
                  canceled: bool = False):
        """MoveTo's end: aborted with ``failure``, canceled, or reached (at joints ``q``)."""
        result = MoveTo.Result()
        if q is not None:
            result.positions = q.tolist()
        if failure is not None:
            goal_handle.abort()
            return results.fill(result, 'MoveTo', failure)
        if canceled:
            goal_handle.canceled()
            return results.answer(result, ErrorCode.CANCELED, 'canceled')
        goal_handle.succeed()
        results.answer(result, ErrorCode.SUCCESS, 'reached')
        result.duration = self._motion_s
        return result

    def _interpolate(self, cancel_requested, publish_feedback, q_target: np.ndarray,
                     speed_scale: float) -> bool:
        """Move along a joint-space line (feedback after each step unless
        ``publish_feedback`` is None); returns True when canceled."""
        q_start = self._robot.q
        self._motion_s = float(move_seconds(q_start, q_target, self._param('joint_velocity'),
                                            speed_scale))                     # simulated
        feedback = MoveTo.Feedback()

        def step(q, progress):
            if publish_feedback is not None:
                feedback.progress, feedback.positions = progress, q.tolist()
                publish_feedback(feedback)
        if self._travel(cancel_requested, step, q_start, q_target, self._motion_s):
            return True
        self._robot.settle(q_target)
        return False

    def _travel(self, cancel_requested, step, q_start: np.ndarray, q_target: np.ndarray,
                seconds: float, stop_at: float = 1.0) -> bool:
        """Along a joint-space line in ``seconds`` of simulated time (smooth start and stop),
        ``step(q, progress)`` after every FEEDBACK_EVERY_STEPS steps and the last; stops at
        ``stop_at`` of the way (the arm is left there). True when canceled (the arm comes to
        rest where it is). Raises spin.Stopping
        when the node shuts down (Ctrl-C): the arm rests where it is and the caller ends its
        goal within spin.STOP_GRACE, before the action server is destroyed."""
        duration = seconds * self._time_scale
        steps = max(1, int(duration / FEEDBACK_PERIOD))
        for k in range(1, steps + 1):
            if cancel_requested():
                self._robot.settle(self._robot.q)
                return True
            s = k / steps
            s = s * s * (3.0 - 2.0 * s)  # smooth start and stop
            q = q_start + s * (q_target - q_start)
            self._robot.set_joints(q)
            if k % FEEDBACK_EVERY_STEPS == 0 or k == steps:
                step(q, k / steps)
            try:
                spin.pause(duration / steps)
            except spin.Stopping:
                self._robot.settle(q)
                raise
            if k / steps >= stop_at:
                break
        return False

    # -- driver mode: FollowJointTrajectory, as a joint_trajectory_controller ---------------
    def _fault_changed(self, params) -> None:
        if any(p.name == 'driver_fault' for p in params):
            self._ringing = False

    def _accept_trajectory(self, goal) -> GoalResponse:
        if self._param('driver_fault') == 'reject' or self._moving:
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _trajectory_points(self, trajectory) -> list[tuple[np.ndarray, float]] | tuple[int, str]:
        """[(joints in the model's order [rad], time from start [s])], or (error_code, why)."""
        R = FollowJointTrajectory.Result
        names = list(self._robot.model.joint_names)
        if sorted(trajectory.joint_names) != sorted(names):
            return R.INVALID_JOINTS, (f'the controller\'s joints are {names}, the goal has '
                                      f'{list(trajectory.joint_names)}')
        if not trajectory.points:
            return R.INVALID_GOAL, 'the trajectory has no points'
        order = [list(trajectory.joint_names).index(n) for n in names]
        points, last = [], 0.0
        for i, point in enumerate(trajectory.points):
            t = ns_to_s(stamp_to_ns(point.time_from_start))
            if len(point.positions) != len(names) or t < last:
                return R.INVALID_GOAL, (f'point {i}: {len(names)} positions at a time from '
                                        'start after the previous point\'s expected')
            q = self._robot.plan_joints(np.asarray(point.positions)[order])
            if isinstance(q, Failure):
                return R.INVALID_GOAL, f'point {i}: {q.message}'
            points.append((q, t))
            last = t
        return points

    def _follow(self, goal_handle, comply: bool):
        """Execute a joint trajectory point by point, each segment in its time (simulated,
        times time_scale); as a joint_trajectory_controller answers, with driver_fault."""
        R = FollowJointTrajectory.Result
        points = self._trajectory_points(goal_handle.request.trajectory)
        if isinstance(points, tuple):
            code, text = points
        elif not self._motion_lock.acquire(blocking=False):
            code, text = R.INVALID_GOAL, 'robot busy (a touch)'
        else:
            self._moving, self._ringing = True, False
            try:
                code, text = self._run_trajectory(goal_handle, points, comply)
            except spin.Stopping:
                code, text = R.PATH_TOLERANCE_VIOLATED, _SHUTTING_DOWN.message
            finally:
                self._moving = False
                self._motion_lock.release()
        result = R(error_string=text)
        if code is None:
            goal_handle.canceled()
            return result
        result.error_code = code
        goal_handle.succeed() if code == R.SUCCESSFUL else goal_handle.abort()
        return result

    def _run_trajectory(self, goal_handle, points, comply: bool) -> tuple[int | None, str]:
        """The trajectory's motion: (FollowJointTrajectory error code, error string); code
        None when the goal was canceled."""
        R = FollowJointTrajectory.Result
        fault = self._param('driver_fault')
        feedback = FollowJointTrajectory.Feedback(joint_names=list(self._robot.model.joint_names))

        def step(q, _progress):
            feedback.desired.positions = feedback.actual.positions = q.tolist()
            goal_handle.publish_feedback(feedback)
        before = 0.0
        for i, (q, t) in enumerate(points):
            stop_at = 0.5 if fault == 'abort' and i == len(points) - 1 else 1.0
            if self._travel(lambda: goal_handle.is_cancel_requested, step, self._robot.q, q,
                            t - before, stop_at):
                return None, 'canceled'
            before = t
        if fault == 'abort':
            self._robot.settle(self._robot.q)
            return R.PATH_TOLERANCE_VIOLATED, (f'{self._robot.model.joint_names[0]} beyond its '
                                               'path tolerance (driver_fault abort)')
        self._robot.settle(points[-1][0])
        complied = self._comply(points[-1][0]) if comply else None
        if isinstance(complied, Failure):
            return R.GOAL_TOLERANCE_VIOLATED, complied.message
        self._ringing = fault == 'ring'
        return R.SUCCESSFUL, ''

    def _comply(self, q_target: np.ndarray) -> bool | Failure:
        """Impedance control at the target: a coupling near a sphere self-centres on it (the
        arm yields; no repeatability noise, the sphere holds the tool)."""
        q = self._robot.plan_compliant(q_target)
        if isinstance(q, Failure):
            return q
        self._robot.set_joints(q)
        return False

    def _on_laser(self, request, response):
        try:
            p = self._robot.laser_measurement()
        except ValueError as e:
            return results.answer(response, ErrorCode.NOT_AVAILABLE, str(e))
        response.point.header.stamp = self.get_clock().now().to_msg()
        response.point.header.frame_id = 'laser_tracker'
        response.point.point.x, response.point.point.y, response.point.point.z = map(float, p)
        response.sigma = self._sim.spheres.tracker.sigma
        return results.answer(response, ErrorCode.SUCCESS, 'measured')

    # -- ground truth ---------------------------------------------------------------------
    def _on_ground_truth(self, request, response):
        world, cell = self._sim.world, self._sim.cell
        response.robot = cell.robot
        response.user_frame = convert.matrix_to_transform(
            world.T_base_user, cell.base_frame, cell.user_frame)
        response.point_names = world.point_names
        response.points_base = convert.array_to_points(world.true_points_base())
        response.points_user = convert.array_to_points(cell.nominal_points_user())
        response.parameter_names = list(self._robot.model.parameter_names)
        response.nominal_parameters = self._robot.model.nominal.tolist()
        response.true_parameters = self._robot.true_parameters.tolist()
        response.repeatability_sigma = self._sim.layout_repeatability_sigma()
        response.touch_sigma = self._sim.noise.touch_sigma
        response.t_flange_tool_true = convert.matrix_to_transform(
            self._sim.T_flange_tool_true, 'flange', cell.tool_frame)
        if self._sim.camera is not None:
            response.t_flange_optical_true = convert.matrix_to_transform(
                self._sim.camera.T_flange_optical, 'flange', cell.camera.frame_id)
        return response

    def destroy_node(self):
        self._loop.stop()
        return super().destroy_node()


def main(args=None) -> None:
    spin.run(MockRobot, args, threads=3)


if __name__ == '__main__':
    main()
