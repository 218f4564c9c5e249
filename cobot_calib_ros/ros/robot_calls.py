"""move_to, capture_joints and laser_tracker/measure called from a callback that blocks until
they answer.

The answers arrive on a spin.Companion, so the caller's own executor stays free. Used by
user_frame_solver (live captures), repeatability_trial (every trial move) and
kinematic_identifier (data collection).
"""
from __future__ import annotations

import time

from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.srv import CaptureJoints, MeasurePosition
import numpy as np
from rclpy.action import ActionClient

from cobot_calib_ros.ros.spin import Companion, wait

SERVER_WAIT = 5.0       # [s] for move_to / capture_joints to be discovered
MOVE_TIMEOUT = 120.0    # [s] for one move_to to finish (every caller's bound on a hung move)
CAPTURE_ATTEMPTS = 4
CAPTURE_RETRY_PAUSE = 0.2   # [s], times the attempt: lets a starved joint_states stream recover


class RobotCallError(RuntimeError):
    """A move or capture that did not happen; the message says which and what to do."""


class RobotCalls:
    def __init__(self, answers: Companion) -> None:
        self._answers = answers
        self.move_client = ActionClient(answers.node, MoveTo, 'move_to')
        self.capture_client = answers.node.create_client(CaptureJoints, 'capture_joints')
        self._laser_client = None
        self.robot_seconds = 0.0    # robot time of the moves (as move_to reports) and holds [s]
        self.capture_retries = 0    # holds tried again after NO_DATA (a starved joint_states)

    def move(self, goal: MoveTo.Goal, result_timeout: float) -> MoveTo.Result:
        """Run a move_to goal to its end; RobotCallError unless it succeeded."""
        if not self.move_client.wait_for_server(timeout_sec=SERVER_WAIT):
            raise RobotCallError('move_to action server not available (is mock_robot up?)')
        try:
            result = self._answers.run_action(self.move_client, goal, 10.0, result_timeout)
        except TimeoutError as e:
            raise RobotCallError(f'move_to: {e}; is mock_robot up?')
        if result is None:
            raise RobotCallError('move_to rejected the goal (robot busy)')
        if result.error_code != MoveTo.Result.SUCCESS:
            raise RobotCallError(f'move_to: {result.message}')
        self.robot_seconds += result.duration
        return result

    def touch_and_capture(self, name: str, duration: float, result_timeout: float,
                          speed_scale: float = 0.0) -> np.ndarray:
        """Hand-guide the tool onto cell point ``name``, hold, and return the mean joints."""
        self.move(MoveTo.Goal(target_type=MoveTo.Goal.TARGET_TOUCH, point_name=name,
                              speed_scale=speed_scale), result_timeout)
        return self.capture(duration).position

    def move_joints(self, q: np.ndarray, result_timeout: float, *, compliant: bool = False,
                    speed_scale: float = 0.0) -> np.ndarray:
        """Move to joints ``q`` [rad] (``compliant``: under impedance control, yielding to
        contact); the joints reached [rad]."""
        result = self.move(MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS,
                                       positions=[float(v) for v in q], compliant=compliant,
                                       speed_scale=speed_scale), result_timeout)
        return np.array(result.positions)

    def capture(self, duration: float) -> CaptureJoints.Response:
        """Joints averaged over a hold of ``duration`` [s] (``position``, ``std`` [rad]).

        A hold with too few samples (NO_DATA: a busy machine starved the 1 kHz joint_states
        for a moment) is tried again, up to CAPTURE_ATTEMPTS times, after a growing pause;
        every such retry counts in ``capture_retries`` (the nodes show it on /diagnostics and
        in their results, so a stalling stream shows)."""
        if not self.capture_client.wait_for_service(timeout_sec=SERVER_WAIT):
            raise RobotCallError('capture_joints not available (is joint_state_monitor up?)')
        req = CaptureJoints.Request(duration=duration)
        for attempt in range(1, CAPTURE_ATTEMPTS + 1):
            try:
                res = wait(self.capture_client.call_async(req), req.duration + 10.0)
            except TimeoutError as e:
                raise RobotCallError(f'capture_joints: {e}; is joint_state_monitor up?')
            if res.error_code != CaptureJoints.Response.NO_DATA or attempt == CAPTURE_ATTEMPTS:
                break
            self.capture_retries += 1
            self._answers.node.get_logger().warning(
                f'capture_joints: {res.message}; trying again ({attempt}/{CAPTURE_ATTEMPTS})')
            time.sleep(CAPTURE_RETRY_PAUSE * attempt)
        if res.error_code != CaptureJoints.Response.SUCCESS:
            raise RobotCallError(f'capture_joints: {res.message}')
        self.robot_seconds += req.duration
        res.position = np.array(res.position)
        return res

    def measure_position(self) -> np.ndarray:
        """(3,) the tool position measured by the laser tracker, in its frame [m]."""
        if self._laser_client is None:
            self._laser_client = self._answers.node.create_client(MeasurePosition,
                                                                  'laser_tracker/measure')
        if not self._laser_client.wait_for_service(timeout_sec=SERVER_WAIT):
            raise RobotCallError('laser_tracker/measure not available (no tracker driver up?)')
        try:
            res = wait(self._laser_client.call_async(MeasurePosition.Request()), 10.0)
        except TimeoutError as e:
            raise RobotCallError(f'laser_tracker/measure: {e}')
        if res.error_code != MeasurePosition.Response.SUCCESS:
            raise RobotCallError(f'laser_tracker/measure: {res.message}')
        p = res.point.point
        return np.array([p.x, p.y, p.z])
