"""sensor_msgs/JointState as serialized bytes, for a publisher of the same joints at 1 kHz.

rclpy converts every Python message to C before it serializes it; for mock_robot's 1 kHz
joint_states that conversion (seven name strings each time) was about half the cost of a
publish. The names never change, so the message is serialized once by rclpy and only its
stamp and positions are written into a copy of those bytes; ``Publisher.publish`` takes bytes.
"""
from __future__ import annotations

import struct

import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from cobot_calib_ros.ros.time import split_ns

_STAMP = struct.Struct('<iI')           # builtin_interfaces/Time: sec, nanosec
_STAMP_OFFSET = 4                       # after the CDR encapsulation header
_MARKER = 0.123456789012345             # a position value found by its bytes in the template


class JointStateBytes:
    """JointState messages of ``names`` (no frame_id, velocity or effort), as CDR bytes."""

    def __init__(self, names: list[str]) -> None:
        self.names = list(names)
        template = serialize_message(JointState(name=self.names,
                                                position=[_MARKER] * len(self.names)))
        if template[:2] != b'\x00\x01':
            raise ValueError(f'expected little-endian CDR, got header {template[:4].hex()}')
        marker = np.full(len(self.names), _MARKER, '<f8').tobytes()
        self._positions_at = template.find(marker)
        if self._positions_at < 0 or template.find(marker, self._positions_at + 1) >= 0:
            raise ValueError('the positions are not where JointState serialization put them')
        self._template = template

    def pack(self, stamp_ns: int, positions: np.ndarray) -> bytes:
        """The serialized JointState stamped ``stamp_ns`` [ns] with ``positions`` [rad]."""
        if len(positions) != len(self.names):
            raise ValueError(f'{len(positions)} positions for {len(self.names)} joints')
        data = bytearray(self._template)
        _STAMP.pack_into(data, _STAMP_OFFSET, *split_ns(stamp_ns))
        end = self._positions_at + 8 * len(self.names)
        data[self._positions_at:end] = np.asarray(positions, '<f8').tobytes()
        return bytes(data)
