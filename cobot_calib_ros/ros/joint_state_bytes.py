"""sensor_msgs/JointState as serialized bytes, for 1 kHz streams of the same joints.

rclpy converts every message between C and Python, seven name strings each time: for
mock_robot's 1 kHz joint_states that was about half the cost of a publish, and most of
joint_state_monitor's per-message cost. The names never change, so the message is serialized
once by rclpy and only the stamp and positions are written into (``pack``) or read from
(``unpack``) bytes of that layout; ``Publisher.publish`` takes bytes, a ``raw`` subscription
gives them. Bytes of any other layout (other names, a frame_id, velocities) are for
``rclpy.serialization.deserialize_message``.
"""
from __future__ import annotations

import struct

import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from cobot_calib_ros.ros.time import NS_PER_S, split_ns

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
        self._padding = padding(self.names, len(template))
        self._template = _zeroed(template, self._padding)
        self._positions_end = self._positions_at + 8 * len(self.names)
        self._positions_format = f'<{len(self.names)}d'
        self._between = self._template[_STAMP_OFFSET + _STAMP.size:self._positions_at]
        self._after = self._template[self._positions_end:]

    def pack(self, stamp_ns: int, positions: np.ndarray) -> bytes:
        """The serialized JointState stamped ``stamp_ns`` [ns] with ``positions`` [rad]."""
        if len(positions) != len(self.names):
            raise ValueError(f'{len(positions)} positions for {len(self.names)} joints')
        return self.pack_many([stamp_ns], np.reshape(positions, (1, -1)))[0]

    def pack_many(self, stamps_ns: list[int], positions: np.ndarray) -> list[bytes]:
        """``pack`` for each stamp [ns] and row of ``positions`` [rad], converting the rows
        to bytes at once (a 1 kHz publisher's per-message numpy calls cost more than the rest
        of its work)."""
        positions = np.ascontiguousarray(positions, '<f8')
        if positions.ndim != 2 or positions.shape != (len(stamps_ns), len(self.names)):
            raise ValueError(f'{positions.shape} positions for {len(stamps_ns)} stamps of '
                             f'{len(self.names)} joints')
        raw, size = positions.tobytes(), 8 * len(self.names)
        out = []
        for i, stamp_ns in enumerate(stamps_ns):
            data = bytearray(self._template)
            _STAMP.pack_into(data, _STAMP_OFFSET, *split_ns(stamp_ns))
            data[self._positions_at:self._positions_end] = raw[i * size:(i + 1) * size]
            out.append(bytes(data))
        return out

    def unpack(self, data: bytes) -> tuple[int, tuple[float, ...]] | None:
        """(stamp [ns], positions [rad]) of serialized JointState bytes laid out as ``pack``'s
        (these names, no frame_id, velocity or effort); None for any other message. Padding
        bytes are not compared: another publisher's rclpy leaves them unset."""
        if len(data) != len(self._template):
            return None
        clean = _zeroed(data, self._padding)
        if (clean[:_STAMP_OFFSET] != self._template[:_STAMP_OFFSET]
                or clean[_STAMP_OFFSET + _STAMP.size:self._positions_at] != self._between
                or clean[self._positions_end:] != self._after):
            return None
        sec, nanosec = _STAMP.unpack_from(data, _STAMP_OFFSET)
        return (sec * NS_PER_S + nanosec,
                struct.unpack_from(self._positions_format, data, self._positions_at))


def padding(names: list[str], length: int) -> list[int]:
    """Indices of the bytes rclpy leaves as its buffer had them (unset memory) in a serialized
    JointState of ``names`` (no frame_id, velocity or effort) ``length`` bytes long: the CDR
    alignment gaps, and the bytes after the body (the serialized length rclpy returns is up to
    8 bytes longer). Two serializations of one message can differ there."""
    at, gaps = 0, []                    # offsets in the body, after the encapsulation header

    def align(size: int) -> None:
        nonlocal at
        while at % size:
            gaps.append(at)
            at += 1

    at = 8 + 4 + 1                      # stamp, frame_id length, frame_id's NUL
    for text in [None, *names]:         # the name count, then each name
        align(4)
        at += 4 + (len(text.encode()) + 1 if text is not None else 0)
    align(4)
    at += 4                             # position count
    align(8)
    at += 8 * len(names) + 4 + 4        # positions, velocity and effort counts
    body_end = _STAMP_OFFSET + at
    if length < body_end:
        raise ValueError(f'{length} bytes cannot hold a JointState of {len(names)} names')
    return [_STAMP_OFFSET + gap for gap in gaps] + list(range(body_end, length))


def zero_padding(data: bytes, names: list[str]) -> bytes:
    """``data`` with the bytes of :func:`padding` set to 0."""
    return _zeroed(data, padding(names, len(data)))


def _zeroed(data: bytes, indices: list[int]) -> bytes:
    out = bytearray(data)
    for i in indices:
        out[i] = 0
    return bytes(out)
