"""The mark topics: what the nodes publish so a recording can be checked again later.

Each has a message of its own (msg_defs/msg), reliable, depth 100; this module owns their
names, their encoders and their decoders (test/test_facts.py keeps the names here).

Capture marks on ``cobot_calib/captures`` (CAPTURES, cobot_calib_msgs/CaptureMark): one per
capture a node took, published by user_frame_solver (a landmark view, ros.landmark_views) and
kinematic_identifier (a sphere or tracker pose). ``header.stamp`` = the ROS time of the capture
(for a landmark view: the time after which landmarks count), ``target`` = what was captured
(point name, sphere name, ``landmark_<id>``), ``joint_names`` / ``position_rad`` = the
captured joints, ``std_rad`` = their standard deviation. The teach sample bag
(bags/make_sample_bags.py) writes the same marks.

Probe-average marks on ``cobot_calib/probe_averages`` (PROBE_AVERAGES,
cobot_calib_msgs/ProbeAverageMark): one per probe/average proximity_sensor served.
``header.stamp`` = the window start t0 (node clock), ``header.frame_id`` = 'probe', then the
window's ``duration_s`` and the answer's fields (``error_code``, ``distance_m``, ``std_m``,
counts, ``reading_status``, the range [m]); ``reading_offsets_ns`` = the header stamps of the
readings the window held, in the order they arrived, as nanoseconds after t0.

Bags recorded before these messages (issue 39) carry sensor_msgs/JointState on both topics,
nine numbers packed into ``position`` and the stamps into ``velocity``; bags.mark_converter
turns those into these messages as a bag is read (LEGACY_FIELDS is that packing).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cobot_calib_ros.ros.time import header_ns, ns_to_stamp

CAPTURES = 'cobot_calib/captures'               # as the nodes publish it (relative)
CAPTURES_TOPIC = '/' + CAPTURES                 # as a bag of the un-namespaced suite has it
CAPTURE_TYPE = 'cobot_calib_msgs/msg/CaptureMark'
PROBE_AVERAGES = 'cobot_calib/probe_averages'
PROBE_AVERAGES_TOPIC = '/' + PROBE_AVERAGES
AVERAGE_TYPE = 'cobot_calib_msgs/msg/ProbeAverageMark'
# the JointState packing of the probe-average marks in bags recorded before issue 39: name =
# these, position = their values (bags.mark_converter reads it)
LEGACY_FIELDS = ('duration', 'distance', 'std', 'sample_count', 'rejected_count', 'error_code',
                 'reading_status', 'min_range', 'max_range')


def capture_mark(target: str, joint_names: Sequence[str], position: Sequence[float],
                 std: Sequence[float], stamp_ns: int):
    """The CAPTURES message of one capture (see the module doc)."""
    from cobot_calib_msgs.msg import CaptureMark
    msg = CaptureMark(target=target, joint_names=list(joint_names),
                      position_rad=[float(v) for v in position],
                      std_rad=[float(v) for v in std])
    msg.header.stamp = ns_to_stamp(stamp_ns)
    return msg


def captured_joints(msg, order: Sequence[str]) -> list[float]:
    """A capture mark's joints [rad] in ``order``; KeyError naming a joint it lacks."""
    joints = dict(zip(msg.joint_names, msg.position_rad))
    return [joints[name] for name in order]


def average_mark(t0_ns: int, duration: float, response, window):
    """The PROBE_AVERAGES message of one probe/average: ``response`` (AverageProximity
    response), ``window`` the (stamp [ns], ...) readings it held (see the module doc)."""
    from cobot_calib_msgs.msg import ProbeAverageMark
    mark = ProbeAverageMark(
        duration_s=float(duration), error_code=int(response.error_code),
        distance_m=float(response.distance), std_m=float(response.std),
        sample_count=int(response.sample_count), rejected_count=int(response.rejected_count),
        reading_status=int(response.reading_status), min_range_m=float(response.min_range),
        max_range_m=float(response.max_range),
        reading_offsets_ns=[int(stamp - t0_ns) for stamp, *_ in window])
    mark.header.stamp = ns_to_stamp(t0_ns)
    mark.header.frame_id = 'probe'
    return mark


@dataclass(frozen=True)
class AverageMark:
    """One probe/average proximity_sensor served (a PROBE_AVERAGES message)."""

    t0_ns: int              # window start, the node clock [ns]
    duration: float         # [s]
    distance: float         # [m]
    std: float              # [m]
    sample_count: int
    rejected_count: int
    error_code: int
    reading_status: int
    stamps_ns: tuple[int, ...]   # of the readings the window held, in their live order

    @property
    def ok(self) -> bool:
        return self.error_code == 0          # AverageProximity.Response.SUCCESS


def read_average_mark(msg) -> AverageMark:
    """A PROBE_AVERAGES message (rclpy's or a bag's) as an AverageMark."""
    t0 = header_ns(msg)
    return AverageMark(t0, float(msg.duration_s), float(msg.distance_m), float(msg.std_m),
                       int(msg.sample_count), int(msg.rejected_count), int(msg.error_code),
                       int(msg.reading_status),
                       tuple(t0 + int(v) for v in msg.reading_offsets_ns))
