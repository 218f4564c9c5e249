"""Static transforms on /tf_static, as tf2_ros.StaticTransformBroadcaster sends them.

tf2_ros is not on PyPI; tf2_msgs is built by the project where ROS does not provide it
(interfaces/tf2_msgs). What tf2 listeners, rviz2 and rosbag2 expect (ros2/geometry2, jazzy):
- topic ``/tf_static`` (absolute: the node namespace does not apply), type tf2_msgs/msg/TFMessage;
- QoS ``StaticBroadcasterQoS`` (tf2_ros/include/tf2_ros/qos.hpp): ``rclcpp::QoS(1)``
  + ``transient_local()``, i.e. keep last 1, reliable, transient local. A late subscriber (tf2
  listeners subscribe with transient local, depth 100) gets the last message published;
- every message carries the whole set: the latest transform of each child frame, in the order the
  child frames were first sent; sending a child frame again replaces its transform
  (tf2_ros/src/static_transform_broadcaster.cpp). tf2_ros_py's Jazzy Python broadcaster keeps the
  first transform of a child frame instead and drops the update; this follows the C++ one.
"""
from __future__ import annotations

from collections.abc import Iterable
import copy
import math
import threading

from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

TOPIC = '/tf_static'

# tf2_ros::StaticBroadcasterQoS: depth 1, reliable, transient local.
QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                 reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)

# tf2's BufferCore ignores a transform whose |q|^2 is off 1 by this much
# (QUATERNION_NORMALIZATION_TOLERANCE in tf2/src/buffer_core.cpp).
QUATERNION_TOLERANCE = 10e-3


class StaticBroadcaster:
    """Latches static transforms on /tf_static for ``node`` (tf2_ros.StaticTransformBroadcaster).

    ``send`` may be called from any thread; each call publishes the whole set once.
    """

    def __init__(self, node: Node, qos: QoSProfile | None = None) -> None:
        self.publisher = node.create_publisher(TFMessage, TOPIC, qos if qos is not None else QOS)
        self._by_child: dict[str, TransformStamped] = {}
        self._lock = threading.Lock()

    def send(self, transforms: TransformStamped | Iterable[TransformStamped]) -> None:
        """Add or replace (by child_frame_id) ``transforms`` and publish the whole set.

        The transforms are copied. ValueError, with nothing kept or published, if one would be
        ignored by tf2 listeners (an empty frame id, a child frame equal to its parent, a
        non-finite value, a quaternion whose squared norm is off 1 by 0.01 or more): once
        latched, a bad transform would reach every late subscriber.
        """
        batch = [transforms] if isinstance(transforms, TransformStamped) else list(transforms)
        for t in batch:
            _check(t)
        with self._lock:
            for t in batch:
                self._by_child[t.child_frame_id] = copy.deepcopy(t)
            self.publisher.publish(TFMessage(transforms=list(self._by_child.values())))

    @property
    def transforms(self) -> list[TransformStamped]:
        """Copies of the transforms last published, in the order their child frames came."""
        with self._lock:
            return [copy.deepcopy(t) for t in self._by_child.values()]


def _check(t: TransformStamped) -> None:
    """What tf2's BufferCore::setTransform ignores (buffer_core.cpp), so never latch it."""
    if not isinstance(t, TransformStamped):
        raise TypeError(f'expected geometry_msgs/msg/TransformStamped, got {type(t).__name__}')
    parent, child = t.header.frame_id, t.child_frame_id
    what = f'static transform {parent!r} -> {child!r}'
    if not parent.lstrip('/') or not child.lstrip('/'):
        raise ValueError(f'{what}: empty frame id')
    if parent.lstrip('/') == child.lstrip('/'):
        raise ValueError(f'{what}: child frame is its own parent')
    tr, q = t.transform.translation, t.transform.rotation
    values = (tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f'{what}: non-finite value in {values}')
    if abs(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w - 1.0) >= QUATERNION_TOLERANCE:
        raise ValueError(f'{what}: rotation ({q.x}, {q.y}, {q.z}, {q.w}) is not a unit quaternion')
