"""JointState bytes written from a template are exactly what rclpy serializes."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from cobot_calib_ros.ros.joint_state_bytes import JointStateBytes, zero_padding
from cobot_calib_ros.ros.time import ns_to_stamp

SAWYER = [f'right_j{i}' for i in range(7)]


@pytest.mark.parametrize('names', [SAWYER, ['a'], ['joint_a1', 'j', 'joint_long_name_3']])
def test_packed_bytes_equal_rclpy_serialization(names):
    wire = JointStateBytes(names)
    positions = np.linspace(-2.5, 3.1, len(names))
    stamp_ns = 1_795_769_848_189_515_202
    expected = JointState(name=names, position=positions.tolist())
    expected.header.stamp = ns_to_stamp(stamp_ns)
    packed = wire.pack(stamp_ns, positions)
    # padding is unset memory in rclpy's serialization: every other byte must match, whatever
    # the buffer held before (messages of other sizes are serialized in between)
    for junk in range(60):
        serialize_message(JointState(name=['x' * junk] * (junk % 5), position=[junk] * junk))
        serialized = serialize_message(expected)
        assert packed == zero_padding(serialized, names)
        assert wire.unpack(serialized) == (stamp_ns, tuple(positions.tolist()))
    back = deserialize_message(packed, JointState)
    assert back.header.stamp.sec == 1_795_769_848 and back.header.stamp.nanosec == 189_515_202
    assert list(back.name) == names and list(back.position) == positions.tolist()


def test_each_pack_is_its_own_message():
    wire = JointStateBytes(SAWYER)
    first = wire.pack(1, np.zeros(7))
    wire.pack(2, np.ones(7))
    assert list(deserialize_message(first, JointState).position) == [0.0] * 7


def test_pack_many_packs_each_row_with_its_stamp():
    wire = JointStateBytes(SAWYER)
    rows = np.arange(21.0).reshape(3, 7) / 10.0
    stamps = [5, 1_000_000_007, 2_000_000_009]
    assert wire.pack_many(stamps, rows) == [wire.pack(t, q) for t, q in zip(stamps, rows)]
    assert [wire.unpack(data) for data in wire.pack_many(stamps, rows)] == [
        (t, tuple(q.tolist())) for t, q in zip(stamps, rows)]
    with pytest.raises(ValueError, match=r'\(3, 7\) positions for 2 stamps of 7 joints'):
        wire.pack_many(stamps[:2], rows)


def test_a_wrong_number_of_positions_is_refused():
    with pytest.raises(ValueError, match='6 positions for 7 joints'):
        JointStateBytes(SAWYER).pack(0, np.zeros(6))


def test_unpack_reads_what_pack_wrote_and_refuses_any_other_layout():
    wire = JointStateBytes(SAWYER)
    positions = np.linspace(-1.0, 1.0, 7)
    stamp_ns, got = wire.unpack(wire.pack(1_795_769_848_000_000_123, positions))
    assert stamp_ns == 1_795_769_848_000_000_123 and got == tuple(positions.tolist())
    others = [JointState(name=SAWYER, position=positions.tolist()),
              JointState(name=SAWYER[::-1], position=positions.tolist()),      # other order
              JointState(name=SAWYER[:6], position=positions[:6].tolist()),
              JointState(name=SAWYER, position=positions.tolist(), velocity=[0.0] * 7)]
    others[0].header.frame_id = 'base'
    for msg in others:
        assert wire.unpack(serialize_message(msg)) is None
