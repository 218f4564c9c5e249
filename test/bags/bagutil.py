"""Messages for the bag tests, serialized as on the wire."""
from __future__ import annotations

from cobot_calib_msgs.msg import PointResidual, UserFrameCalibration
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from cobot_calib_ros.bags import interfaces, metadata


def joint_state(i: int, joints: int = 7) -> JointState:
    """A full JointState (no empty sequences: rclpy pads those with stray bytes, see
    test_writer's note) numbered by ``i`` in its stamp and positions."""
    msg = JointState(name=[f'right_j{k}' for k in range(joints)],
                     position=[i * 0.001 + k for k in range(joints)],
                     velocity=[0.5 * k for k in range(joints)],
                     effort=[-1.0 * k for k in range(joints)])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(1_000_000_000 + i, 1000)
    msg.header.frame_id = 'base'
    return msg


def user_frame() -> UserFrameCalibration:
    msg = UserFrameCalibration(id='20261122T120000Z-rigid', method='rigid')
    msg.transform.header.frame_id = 'base'
    msg.transform.child_frame_id = 'user_frame'
    msg.transform.transform.translation.x = 0.35
    msg.transform.transform.rotation.w = 1.0
    msg.matrix = [float(i == j) for i in range(4) for j in range(4)]
    msg.residuals = [PointResidual(name=f'P{k}') for k in range(1, 4)]
    msg.rms_residual = 8.6e-5
    return msg


def cdr(msg) -> bytes:
    """The message as Fast DDS sends it: CDR with zeroed padding. (rclpy's serialize_message
    leaves the alignment padding uninitialised, and adds stray bytes after a message that ends
    in empty sequences, so its output differs from call to call.)"""
    msgtype = type(msg).__module__.split('.')[0] + '/msg/' + type(msg).__name__
    raw = serialize_message(msg)
    return _STORE.serialize_cdr(_STORE.deserialize_cdr(raw, msgtype), msgtype)


_STORE = interfaces.typestore()


RELIABLE = metadata.qos()
LATCHED = metadata.qos(durability='transient_local')
