"""One teach session over ROS: the operator touches points, confirms, the joints are captured,
then calibrate_user_frame fits the frame (used by `cobot-calib teach`).

Confirmation is Enter on standard input or a call to the node's ``~/confirm`` service. On the
mock robot (it offers ``get_ground_truth``) the operator's hand guiding is simulated: before
each confirmation the mock is sent a ``move_to`` TOUCH of the point.
"""
from __future__ import annotations

import select
import sys
import time
from typing import Callable

from cobot_calib_ros.ros import interrupts

NODE_NAME = 'cobot_calib_teach'


class TeachError(RuntimeError):
    """The session cannot go on; the message says what to check."""


class TeachSession:
    """One teach run on one rclpy node: confirmations, captures, the final calibration."""

    def __init__(self, node, args, cell, say: Callable[[str], None]) -> None:
        """``node``: spun by its executor (ros.session); ``args``: method, hold [s],
        simulate_touch (auto, yes, no), timeout [s] per confirmation."""
        from cobot_calib_msgs.srv import CalibrateUserFrame, CaptureJoints, GetGroundTruth
        from std_srvs.srv import Trigger
        self.node, self.args, self.cell = node, args, cell
        self.executor = node.executor
        self._confirmed = False
        node.create_service(Trigger, '~/confirm', self._on_confirm)
        self.capture = node.create_client(CaptureJoints, 'capture_joints')
        self.calibrate = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        self.truth = node.create_client(GetGroundTruth, 'get_ground_truth')
        self._stdin_open = True
        self.say = say

    def run(self, names: list[str]):
        """Teach ``names`` in order, then calibrate: (the CalibrateUserFrame response, the
        captures). TeachError when the session cannot go on."""
        from cobot_calib_ros.ros.calls import spin_until
        for client in (self.capture, self.calibrate):
            if not spin_until(self.node, client.service_is_ready, 10.0, self.executor):
                raise TeachError(f'{client.srv_name} is not available; is the suite up '
                                 '(cobot-calib up) on this ROS_DOMAIN_ID?')
        simulate = self._simulate_touch()
        captures = [self._teach_point(name, i, len(names), simulate)
                    for i, name in enumerate(names)]
        return self._calibrate(names, captures), captures

    def _simulate_touch(self) -> bool:
        from cobot_calib_ros.ros.calls import spin_until
        if self.args.simulate_touch != 'auto':
            return self.args.simulate_touch == 'yes'
        return spin_until(self.node, self.truth.service_is_ready, 5.0, self.executor)

    # -- one point ------------------------------------------------------------------------
    def _teach_point(self, name: str, index: int, count: int, simulate: bool):
        x, y, z = self.cell.marker(name).nominal_top * 1e3
        self.say(f'[{index + 1}/{count}] {name}: guide the tool tip onto the top-face centre '
                 f'of marker {name} (user frame x {x:.1f} mm, y {y:.1f} mm, z {z:.1f} mm), '
                 f'hold still, then press Enter (or call /{NODE_NAME}/confirm)')
        if simulate:
            self._simulated_touch(name)
            self.say(f'      (mock robot: the operator\'s hand guided the tool onto {name})')
        self._wait_for_confirmation()
        return self._capture(name)

    def _simulated_touch(self, name: str) -> None:
        from cobot_calib_msgs.srv import HandGuide
        from cobot_calib_ros.ros.calls import call_service, CallError
        client = self.node.create_client(HandGuide, 'mock_robot/hand_guide')
        try:
            result = call_service(self.node, client, HandGuide.Request(point_name=name), 60.0,
                                  self.executor)
        except CallError as e:
            raise TeachError(f'simulated touch of {name}: {e}')
        finally:
            self.node.destroy_client(client)
        if result.error_code != HandGuide.Response.SUCCESS:
            raise TeachError(f'simulated touch of {name}: {result.message}')

    def _on_confirm(self, request, response):
        self._confirmed = True
        response.success, response.message = True, 'confirmed'
        return response

    def _wait_for_confirmation(self) -> None:
        self._confirmed = False
        deadline = time.monotonic() + self.args.timeout
        while not self._confirmed:
            interrupts.check()
            if time.monotonic() > deadline:
                raise TeachError(f'no confirmation within {self.args.timeout:.0f} s')
            self.executor.spin_once(timeout_sec=0.02)
            self._read_enter()

    def _read_enter(self) -> None:
        if not self._stdin_open or not select.select([sys.stdin], [], [], 0.0)[0]:
            return
        line = sys.stdin.readline()
        if line == '':
            self._stdin_open = False
            self.say(f'      (standard input closed: waiting for /{NODE_NAME}/confirm)')
        elif line.strip().lower() in ('q', 'quit'):
            raise TeachError('quit by the operator; nothing was stored')
        else:
            self._confirmed = True

    def _capture(self, name: str):
        from cobot_calib_msgs.srv import CaptureJoints
        from sensor_msgs.msg import JointState
        from cobot_calib_ros.ros.calls import call_service, CallError
        try:
            res = call_service(self.node, self.capture,
                               CaptureJoints.Request(duration=self.args.hold),
                               self.args.hold + 10.0, self.executor)
        except CallError as e:
            raise TeachError(f'capture at {name}: {e}')
        if res.error_code != CaptureJoints.Response.SUCCESS:
            raise TeachError(f'capture at {name}: {res.message}')
        self.say(f'      captured {res.sample_count} samples, largest joint spread '
                 f'{max(res.std) * 1e6:.1f} urad')
        return JointState(name=list(res.name), position=list(res.position))

    # -- the calibration ------------------------------------------------------------------
    def _calibrate(self, names: list[str], captures):
        from cobot_calib_msgs.srv import CalibrateUserFrame
        from cobot_calib_ros.ros.calls import call_service, CallError
        request = CalibrateUserFrame.Request(method=self.args.method, point_names=names,
                                             joint_captures=captures)
        try:
            res = call_service(self.node, self.calibrate, request, 60.0, self.executor)
        except CallError as e:
            raise TeachError(str(e))
        return res
