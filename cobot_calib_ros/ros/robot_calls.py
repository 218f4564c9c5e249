"""core.robot_port.RobotPort over ROS: move_to, capture_joints, probe/average and
laser_tracker/measure called from a callback that blocks until they answer.

The answers arrive on a spin.Companion, so the caller's own executor stays free. Used by
user_frame_solver (live captures), repeatability_trial (every trial move), hand_eye_calibrator
and kinematic_identifier (data collection). A move that fails raises core.robot_port.MoveFailed,
a capture or measurement CaptureFailed (both RobotCallError, i.e. PortError).

A touch is not a move: the operator guides the tool onto the point and confirms by calling
``<operator>/confirm_touch`` (std_srvs/Trigger; the node's name as ``operator``). On the mock
cell the simulated operator does it: ``mock_robot/hand_guide`` (HandGuide.srv, which only
mock_robot serves) is called instead when it answers.
"""
from __future__ import annotations

from contextlib import contextmanager
import threading
import time

from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.msg import ProximityReading
from cobot_calib_msgs.srv import AverageProximity, CaptureJoints, HandGuide, MeasurePosition
import numpy as np
from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.robot_port import (Approach, Capture, CaptureFailed, MoveFailed,
                                             PortError, RobotStopped)
from cobot_calib_ros.core.sensors.probe import Reading, ReadingStatus
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.convert import matrix_to_pose
from cobot_calib_ros.ros.calls import ASK_AGAIN
from cobot_calib_ros.ros.spin import (absent_after, Companion, pause, ServerLost, Stopping, until,
                                     wait, wait_answer)

SERVER_WAIT = 5.0       # [s] for move_to / capture_joints to be discovered
# [s] a capture_joints or probe/average may take beyond its window (a stalled stream: the
# nodes' STALL_TIMEOUT, 3 s) before it is asked again (ros.spin.wait_answer: a dropped
# answer); sooner, a slow answer's duplicate queued behind it and delayed the next request
WINDOW_GRACE = 5.0
MOVE_TIMEOUT = 120.0    # [s] for one move_to to finish (every caller's bound on a hung move)
# [s] a move server (mock_robot, robot_adapter) keeps a finished move's result (rclpy's
# result_timeout, default 900): longer than the 10 s this client waits for a goal's acceptance,
# after which it asks for the result at once. Every status message of an action lists each goal
# still kept, and every job node's move_to client decodes each one: with 900 s an idle job node
# spent ~6 % of a core on them while a collection ran (~3 % with this and 10 Hz feedback)
MOVE_RESULT_KEEP = 15
# [s] the move_to client is kept after the last call that used it. An action client takes every
# status and feedback message of the server, whoever's goal they are about: with one from start
# to stop, each idle job node spent ~4 % of a core on another node's collection (UR10e
# `identify --planned`, 5 idle job nodes: ~20 % of a core)
MOVE_CLIENT_LINGER = 10.0
TOUCH_TIMEOUT = 600.0   # [s] for the operator to guide the tool onto a point and confirm
HAND_GUIDE = 'mock_robot/hand_guide'
# mock_robot's real tool, [x y z roll pitch yaw] [m, rad]: a parameter, as GetGroundTruth has
# no field for it (simulation only; cobot-calib demo scores its frames with it)
NO_MOVE_TO = ('move_to action server not available (is mock_robot up, or robot_adapter beside '
              'a driver?)')
CAPTURE_ATTEMPTS = 4
CAPTURE_RETRY_PAUSE = 0.2   # [s], times the attempt: lets a starved joint_states stream recover


RobotCallError = PortError     # a move or capture that did not happen (MoveFailed, CaptureFailed)


class RobotCalls:
    """The RobotPort; ``operator``: the node's name, for its ``confirm_touch`` service."""

    CALLS = ('move_to (mock_robot, or robot_adapter for a driver)',    # what absent() names
             'capture_joints (joint_state_monitor)', 'probe/average (proximity_sensor)')

    def __init__(self, answers: Companion, speed_scale: float = 0.0, *,
                 probe_window: float = 0.2, operator: str = '') -> None:
        self._answers = answers
        self.speed_scale = speed_scale    # of every move: 0..1 of the joint velocity limits;
                                          # 0 = mock_robot's default
        self.probe_window = probe_window  # [s] of each probe reading
        self._move_client = None          # while a call needs it, and MOVE_CLIENT_LINGER s after
        self._move_users = 0
        self._move_idle_since = time.monotonic()
        self._move_lock = threading.Lock()
        # a look every LINGER s (the client goes 1-2 LINGER after its last call): each wake of
        # an executor costs ~1-10 ms of Python here, and a 1 s look was a job node's most
        # frequent wake at rest, beside the 1 Hz diagnostics
        answers.node.create_timer(MOVE_CLIENT_LINGER, self._release_move_client,
                                  clock=Clock(clock_type=ClockType.STEADY_TIME))    # wall time
        self.capture_client = answers.node.create_client(CaptureJoints, 'capture_joints')
        self.probe_client = answers.node.create_client(AverageProximity, 'probe/average')
        self._hand_guide = answers.node.create_client(HandGuide, HAND_GUIDE)
        self._simulated_operator: bool | None = None    # known after the first touch
        self._confirmed = threading.Event()
        self.awaiting_operator = threading.Event()     # set while a touch waits for confirm
        self.confirm_service = f'{operator}/confirm_touch' if operator else ''
        if operator:
            answers.node.create_service(Trigger, self.confirm_service, self._on_confirm)
        self._laser_client = None
        self.robot_seconds = 0.0    # robot time of moves (as move_to reports), holds, probes [s]
        self.capture_retries = 0    # holds tried again after NO_DATA (a starved joint_states)
        self.probe_retries = 0      # probe windows read again after NO_DATA (a lost burst)

    def missing(self, timeout: float = SERVER_WAIT) -> str:
        """'' when move_to, capture_joints and probe/average answer, else what is missing."""
        try:
            missing = self.absent(timeout)
        except Stopping as e:
            return str(e)
        return f'not available: {", ".join(missing)}; is the node suite up?' if missing else ''

    def absent(self, timeout: float = SERVER_WAIT) -> list[str]:
        """Which of move_to, capture_joints and probe/average are not on the graph after up to
        ``timeout`` s (one wait for all: as soon as all are there); Stopping."""
        with self._move_to() as move_client:
            return absent_after(dict(zip(self.CALLS, (move_client.server_is_ready,
                                                      self.capture_client.service_is_ready,
                                                      self.probe_client.service_is_ready))),
                                timeout, self._answers.node)

    @contextmanager
    def _move_to(self):
        """The move_to client, made when a call needs it (its server sees it ~0.1 s later on a
        quiet machine, within SERVER_WAIT) and released MOVE_CLIENT_LINGER s after the last
        call (:meth:`_release_move_client`)."""
        with self._move_lock:
            if self._move_client is None:
                self._move_client = ActionClient(self._answers.node, MoveTo, 'move_to')
            self._move_users += 1
            client = self._move_client
        try:
            yield client
        finally:
            with self._move_lock:
                self._move_users -= 1
                self._move_idle_since = time.monotonic()

    def _release_move_client(self) -> None:
        """Destroy the move_to client MOVE_CLIENT_LINGER s after its last use (the answers
        node's executor thread, where its callbacks run)."""
        with self._move_lock:
            if self._move_client is None or self._move_users or \
                    time.monotonic() - self._move_idle_since < MOVE_CLIENT_LINGER:
                return
            client, self._move_client = self._move_client, None
        client.destroy()

    def move(self, goal: MoveTo.Goal) -> MoveTo.Result:
        """Run a move_to goal to its end (MOVE_TIMEOUT); MoveFailed unless it succeeded (the
        node shutting down included)."""
        try:
            with self._move_to() as move_client:
                if not until(move_client.server_is_ready, SERVER_WAIT):
                    raise MoveFailed(NO_MOVE_TO)
                result = self._answers.run_action(move_client, goal, 10.0, MOVE_TIMEOUT)
        except (Stopping, ServerLost) as e:
            raise MoveFailed(f'move_to: {e}')
        except TimeoutError as e:
            raise MoveFailed(f'move_to: {e}; is mock_robot (or robot_adapter) up?')
        if result is None:
            raise MoveFailed('move_to rejected the goal (robot busy)')
        if result.error_code == MoveTo.Result.CANCELED:
            raise RobotStopped(f'move_to: {result.message}')
        if result.error_code != MoveTo.Result.SUCCESS:
            raise MoveFailed(f'move_to: {result.message}')
        self.robot_seconds += result.duration
        return result

    def touch(self, name: str, approach: Approach | None = None) -> None:
        """The tool tip onto cell point ``name`` (``approach``: in that tool orientation, or
        onto an elongator point): the mock's simulated operator when mock_robot/hand_guide
        answers, else the operator, who confirms (TOUCH_TIMEOUT). The robot's move_to must be
        up either way (what it moves next, and a sign of a driver)."""
        try:
            with self._move_to() as move_client:
                if not until(move_client.server_is_ready, SERVER_WAIT):   # no robot at all
                    raise MoveFailed(NO_MOVE_TO)
            if self._simulated_operator is None:
                self._simulated_operator = until(self._hand_guide.service_is_ready,
                                                 SERVER_WAIT)
        except Stopping as e:
            raise MoveFailed(f'touch {name}: {e}')
        if self._simulated_operator:
            return self._hand_guided(name, approach)
        if not self.confirm_service:
            raise MoveFailed(f'touch {name}: no operator to confirm it (the node serves no '
                             'confirm_touch) and no simulated one (mock_robot/hand_guide)')
        self._confirmed.clear()
        full_name = self._answers.node.resolve_service_name(self.confirm_service)
        where = f'the top-face centre of {name}' if approach is None else \
            approach.describe(name) + (' (tool z in the base frame: '
                                       f'{np.round(approach.orientation[:, 2], 3).tolist()})')
        self._answers.node.get_logger().warning(
            f'touch {name}: guide the tool tip onto {where}, hold still, '
            f'then call {full_name} (std_srvs/Trigger)')
        self.awaiting_operator.set()
        try:
            confirmed = until(self._confirmed.is_set, TOUCH_TIMEOUT)
        except Stopping as e:
            raise MoveFailed(f'touch {name}: {e}')
        finally:
            self.awaiting_operator.clear()
        if not confirmed:
            raise MoveFailed(f'touch {name}: not confirmed within {TOUCH_TIMEOUT:.0f} s '
                             f'(call {full_name} once the tool rests on the point)')

    def _hand_guided(self, name: str, approach: Approach | None) -> None:
        request = HandGuide.Request(point_name=name)
        if approach is not None:
            request.oriented = True
            request.orientation = matrix_to_pose(frames.make_transform(
                approach.orientation, np.zeros(3))).orientation
            request.elongator_axis, request.elongation = approach.axis, approach.distance
        try:
            res = wait(self._hand_guide.call_async(request), MOVE_TIMEOUT)
        except TimeoutError as e:
            raise MoveFailed(f'{HAND_GUIDE} {name}: {e}; is mock_robot up?')
        if res.error_code != HandGuide.Response.SUCCESS:
            raise MoveFailed(f'{HAND_GUIDE} {name}: {res.message}')
        self.robot_seconds += res.duration

    def _on_confirm(self, request, response):
        self._confirmed.set()
        response.success, response.message = True, 'touch confirmed'
        return response

    def touch_and_capture(self, name: str, duration: float) -> np.ndarray:
        """Touch cell point ``name``, hold for ``duration`` [s]: the mean joints [rad]."""
        self.touch(name)
        return self.capture(duration).q

    def move_to_pose(self, T_base_tool: np.ndarray) -> np.ndarray:
        """The tool to a (4, 4) pose in base [m] (IK by the controller); the joints reached."""
        result = self.move(MoveTo.Goal(target_type=MoveTo.Goal.TARGET_POSE,
                                       pose=matrix_to_pose(T_base_tool),
                                       speed_scale=self.speed_scale))
        return np.array(result.positions)

    def move_joints(self, q: np.ndarray, *, compliant: bool = False,
                    speed_scale: float | None = None) -> np.ndarray:
        """Move to joints ``q`` [rad] (``compliant``: under impedance control, yielding to
        contact; ``speed_scale``: this move's, default the instance's); the joints reached."""
        result = self.move(MoveTo.Goal(
            target_type=MoveTo.Goal.TARGET_JOINTS, positions=[float(v) for v in q],
            compliant=compliant,
            speed_scale=self.speed_scale if speed_scale is None else speed_scale))
        return np.array(result.positions)

    def capture(self, duration: float) -> Capture:
        """Joints averaged over a hold of ``duration`` [s].

        A hold with too few samples (NO_DATA: a busy machine starved the 1 kHz joint_states
        for a moment) is tried again, up to CAPTURE_ATTEMPTS times, after a growing pause;
        every such retry counts in ``capture_retries`` (the nodes show it on /diagnostics and
        in their results, so a stalling stream shows)."""
        try:
            if not until(self.capture_client.service_is_ready, SERVER_WAIT):
                raise CaptureFailed('capture_joints not available (is joint_state_monitor '
                                    'up?)')
            req = CaptureJoints.Request(duration=duration)
            for attempt in range(1, CAPTURE_ATTEMPTS + 1):
                try:
                    res = wait_answer(lambda: self.capture_client.call_async(req),
                                      req.duration + 2 * WINDOW_GRACE,
                                      req.duration + WINDOW_GRACE,
                                      self.capture_client.remove_pending_request)
                except Stopping:
                    raise
                except TimeoutError as e:
                    raise CaptureFailed(f'capture_joints: {e}; is joint_state_monitor up?')
                if res.error_code != CaptureJoints.Response.NO_DATA \
                        or attempt == CAPTURE_ATTEMPTS:
                    break
                self.capture_retries += 1
                self._answers.node.get_logger().warning(
                    f'capture_joints: {res.message}; trying again ({attempt}/'
                    f'{CAPTURE_ATTEMPTS})')
                pause(CAPTURE_RETRY_PAUSE * attempt)
        except Stopping as e:
            raise CaptureFailed(f'capture_joints: {e}')
        if res.error_code != CaptureJoints.Response.SUCCESS:
            raise CaptureFailed(f'capture_joints: {res.message}')
        self.robot_seconds += req.duration
        return Capture(np.array(res.position, dtype=float), np.array(res.std, dtype=float),
                       int(res.sample_count))

    def measure_position(self) -> np.ndarray:
        """(3,) the tool position measured by the laser tracker, in its frame [m]."""
        if self._laser_client is None:
            self._laser_client = self._answers.node.create_client(MeasurePosition,
                                                                  'laser_tracker/measure')
        try:
            if not until(self._laser_client.service_is_ready, SERVER_WAIT):
                raise CaptureFailed('laser_tracker/measure not available (no tracker driver '
                                    'up?)')
            res = wait_answer(lambda: self._laser_client.call_async(MeasurePosition.Request()),
                              10.0, ASK_AGAIN, self._laser_client.remove_pending_request)
        except TimeoutError as e:        # Stopping too
            raise CaptureFailed(f'laser_tracker/measure: {e}')
        if res.error_code != MeasurePosition.Response.SUCCESS:
            raise CaptureFailed(f'laser_tracker/measure: {res.message}')
        p = res.point.point
        return np.array([p.x, p.y, p.z])

    def probe(self) -> Reading:
        """One probe/average of ``probe_window``; a window without readings (a lost burst)
        is tried once more, four times as long."""
        self.robot_seconds += self.probe_window
        res = self._average(self.probe_window)
        if res.error_code == AverageProximity.Response.NO_DATA:
            self.probe_retries += 1
            res = self._average(4 * self.probe_window)
        if res.error_code == AverageProximity.Response.SUCCESS:
            return Reading(res.distance, ReadingStatus.OK)
        if res.error_code == AverageProximity.Response.OUT_OF_RANGE and res.reading_status in (
                ProximityReading.STATUS_BELOW_RANGE, ProximityReading.STATUS_ABOVE_RANGE):
            return Reading(float('nan'), ReadingStatus(res.reading_status))
        raise CaptureFailed(f'probe/average: {res.message}')

    def retries(self) -> dict[str, int]:
        """The retries so far: capture_joints holds after NO_DATA, probe re-reads after
        NO_DATA (what a stalling joint_states or probe stream costs)."""
        return {'capture_joints': self.capture_retries, 'probe_average': self.probe_retries}

    def probe_range(self) -> tuple[float, float]:
        """(min, max) [m]: the probe's range from proximity_sensor's calibration table."""
        res = self._average(self.probe_window)
        if res.error_code == AverageProximity.Response.BAD_REQUEST or \
                not 0.0 <= res.min_range < res.max_range:
            raise CaptureFailed(f'proximity_sensor gave no probe range ({res.message}); check '
                                'its calibration table')
        return res.min_range, res.max_range

    def _average(self, window: float):
        req = AverageProximity.Request(duration=window)
        try:
            return wait_answer(lambda: self.probe_client.call_async(req),
                               window + 2 * WINDOW_GRACE, window + WINDOW_GRACE,
                               self.probe_client.remove_pending_request)
        except TimeoutError as e:
            raise CaptureFailed(f'probe/average: {e}; is the node suite up?')
