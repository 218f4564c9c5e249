"""ProbeVoltage bytes written from a template are what rclpy deserializes."""
import math

from cobot_calib_msgs.msg import ProbeVoltage
import pytest
from rclpy.serialization import deserialize_message

from cobot_calib_ros.ros.probe_voltage_bytes import ProbeVoltageBytes

STAMP_NS = 1_795_769_848_189_515_202


def _read(data: bytes) -> tuple[str, int, int, float]:
    msg = deserialize_message(data, ProbeVoltage)
    return msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec, msg.voltage


@pytest.mark.parametrize('frame_id', ['probe', '', 'p', 'abc', 'a_longer_frame_id_name'])
@pytest.mark.parametrize('voltage', [-5.25, 0.0, math.inf])
def test_packed_bytes_are_the_message_rclpy_reads(frame_id, voltage):
    packed = ProbeVoltageBytes(frame_id).pack(STAMP_NS, voltage)
    assert _read(packed) == (frame_id, 1_795_769_848, 189_515_202, voltage)


def test_a_nan_voltage_goes_out_as_nan():
    assert math.isnan(_read(ProbeVoltageBytes('probe').pack(1, math.nan))[3])


def test_each_pack_is_its_own_message():
    wire = ProbeVoltageBytes('probe')
    first = wire.pack(1, -1.0)
    wire.pack(2_000_000_003, -2.0)
    assert _read(first) == ('probe', 0, 1, -1.0)
