"""The demo's client: touch and capture on the mock, calibrate, move, read the truth."""
from __future__ import annotations

import numpy as np

from cobot_calib_ros.ros import convert


class DemoClient:
    """Service and action calls of the demo (one rclpy node, ros.session; close() ends it)."""

    def __init__(self) -> None:
        from cobot_calib_ros.ros.action_client import ActionClient
        from cobot_calib_msgs.action import MoveTo
        from cobot_calib_msgs.srv import (CalibrateUserFrame, CaptureJoints, GetGroundTruth,
                                          HandGuide)
        from cobot_calib_ros.ros.session import session
        self._session = session('cobot_calib_demo')
        self.node, self.executor = self._session.__enter__()
        self.MoveTo, self.Calibrate = MoveTo, CalibrateUserFrame
        self._truth = self.node.create_client(GetGroundTruth, 'get_ground_truth')
        self._capture = self.node.create_client(CaptureJoints, 'capture_joints')
        self._calibrate = self.node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        self._move = ActionClient(self.node, MoveTo, 'move_to')
        self._hand_guide = self.node.create_client(HandGuide, 'mock_robot/hand_guide')

    def close(self) -> None:
        self._session.__exit__(None, None, None)

    def ground_truth(self):
        from cobot_calib_ros.ros.calls import call_service
        return call_service(self.node, self._truth, self._truth.srv_type.Request(), 30.0)

    def calibrate(self, method: str, names=(), p_user=None, p_base=None, captures=(),
                  kinematics: str = ''):
        from cobot_calib_ros.ros.calls import call_service
        req = self.Calibrate.Request(method=method, point_names=list(names),
                                     joint_captures=list(captures), kinematics=kinematics)
        if p_user is not None:
            req.points_user = convert.array_to_points(p_user)
            req.points_base = convert.array_to_points(p_base)
        return call_service(self.node, self._calibrate, req, 120.0)

    def touch_and_capture(self, name: str, hold: float = 0.5):
        """The mock's simulated operator guides the tool onto ``name``; the joints held there
        (JointState)."""
        from sensor_msgs.msg import JointState
        from cobot_calib_ros.ros.calls import call_service
        result = call_service(self.node, self._hand_guide,
                              self._hand_guide.srv_type.Request(point_name=name), 60.0)
        if result.error_code != result.SUCCESS:
            raise RuntimeError(f'touching {name}: {result.message}')
        res = call_service(self.node, self._capture,
                           self._capture.srv_type.Request(duration=hold), 30.0)
        if res.error_code != 0:
            raise RuntimeError(f'capture at {name}: {res.message}')
        return JointState(name=list(res.name), position=list(res.position))

    def move_to_joints(self, q: np.ndarray):
        from cobot_calib_ros.ros.calls import run_action
        goal = self.MoveTo.Goal(target_type=self.MoveTo.Goal.TARGET_JOINTS,
                                positions=[float(v) for v in q])
        return run_action(self.node, self._move, goal, 60.0)[1]
