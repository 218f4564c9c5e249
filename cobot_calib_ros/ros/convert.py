"""The only bridge between ROS messages and numpy arrays (cf. cv_bridge)."""
from __future__ import annotations

from geometry_msgs.msg import Point, Pose, TransformStamped
import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.sensors.probe import ProbeAverage
from cobot_calib_ros.ros import results

Array = NDArray[np.float64]


def points_to_array(points) -> Array:
    """geometry_msgs/Point[] -> (N, 3) [m]."""
    return np.array([[p.x, p.y, p.z] for p in points], dtype=float).reshape(-1, 3)


def array_to_points(array) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in np.asarray(array)]


def matrix_to_pose(T: Array) -> Pose:
    position, q = frames.to_pose(T)
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    o = pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    return pose


def pose_to_matrix(pose: Pose) -> Array:
    p, o = pose.position, pose.orientation
    return frames.from_pose([p.x, p.y, p.z], [o.x, o.y, o.z, o.w])


def matrix_to_transform(T: Array, parent: str, child: str, stamp=None) -> TransformStamped:
    msg = TransformStamped()
    msg.header.frame_id = parent
    msg.child_frame_id = child
    if stamp is not None:
        msg.header.stamp = stamp
    position, q = frames.to_pose(T)
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in position)
    r.x, r.y, r.z, r.w = (float(v) for v in q)
    return msg


def transform_to_matrix(msg: TransformStamped) -> Array:
    t, r = msg.transform.translation, msg.transform.rotation
    return frames.from_pose([t.x, t.y, t.z], [r.x, r.y, r.z, r.w])


def fill_average(response, result: ProbeAverage):
    """probe/average's response fields from core.sensors.probe.average's result (all but
    min_range and max_range; distance and std stay 0 unless SUCCESS)."""
    results.answer(response, result.code, result.message)
    response.sample_count, response.rejected_count = result.sample_count, result.rejected_count
    if result.code == ErrorCode.OUT_OF_RANGE:
        response.reading_status = int(result.status)
    if result:
        response.distance, response.std = result.distance, result.std
    return response
