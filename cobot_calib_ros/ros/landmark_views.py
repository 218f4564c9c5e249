"""Landmark user frames measured live over ROS: what core.landmarks.views.measure_frame needs
besides the ports (ros.robot_calls.RobotCalls, ros.landmark_watch.LandmarkWatch).

Used by user_frame_solver (calibrate_user_frame, ``landmark_single`` / ``landmark_multi``) and
by repeatability_trial (a landmark method's frame M_n in every cycle). Each planned view is
visited (move_to), the joints captured (capture_joints), and the first ``landmarks`` message
of an image stamped after the capture (ROS time) gives T_optical_marker;
T_base_marker = FK(captured joints; model chain with the hand-eye as tool) @ T_optical_marker.
:class:`CaptureMarks` publishes each view's capture.

The hand-eye used is the rig's (store.rigs.rig_of: the active one of hand_eye_calibrator when
there is one, else the cell's nominal ``camera: hand_eye``).
"""
from __future__ import annotations

from cobot_calib_msgs.msg import CaptureMark

from cobot_calib_ros.core.robot_port import Capture
from cobot_calib_ros.ros import marks


class CaptureMarks:
    """Publishes each landmark view's capture on ros.marks.CAPTURES, as kinematic_identifier
    publishes its poses: a recorded session (images, camera_info, these marks) can be fitted
    again (bags/README.md). Called as core.landmarks.views.measure_frame's ``on_view``."""

    def __init__(self, node, joint_names) -> None:
        self._joint_names = list(joint_names)
        self._pub = node.create_publisher(CaptureMark, marks.CAPTURES, 100)

    def __call__(self, marker_id: int, capture: Capture, stamp_ns: int) -> None:
        """The view's mark: header.stamp = the time after which landmarks count (ROS time),
        target = 'landmark_<id>' (the marker the view is planned for), the captured joints
        [rad] and their standard deviation."""
        self._pub.publish(marks.capture_mark(f'landmark_{marker_id}', self._joint_names,
                                             capture.q, capture.std, stamp_ns))
