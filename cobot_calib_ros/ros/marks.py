"""The mark topics: what the nodes publish so a recording can be checked again later.

Both are sensor_msgs/JointState, reliable, depth 100; this module owns their names, their
encoders and their decoders (test/test_facts.py keeps the names here).

Capture marks on ``cobot_calib/captures`` (CAPTURES): one per capture a node took, published
by user_frame_solver (a landmark view, ros.landmark_views) and kinematic_identifier (a sphere
or tracker pose). ``header.stamp`` = the ROS time of the capture (for a landmark view: the
time after which landmarks count), ``header.frame_id`` = the target (point name, sphere name,
``landmark_<id>``), ``name``/``position`` = the captured joints [rad], ``effort`` = their
standard deviation [rad], ``velocity`` zeros. The teach sample bag (bags/make_sample_bags.py)
writes the same marks.

Probe-average marks on ``cobot_calib/probe_averages`` (PROBE_AVERAGES): one per probe/average
proximity_sensor served. ``header.stamp`` = the window start t0 (node clock),
``header.frame_id`` = 'probe', ``name`` = AVERAGE_FIELDS and ``position`` their values: the
window's duration [s], then the response's distance and std [m], sample_count,
rejected_count, error_code, reading_status, min_range and max_range [m]; ``velocity`` = the
header stamps of the readings the window held, in the order they arrived, as nanoseconds after
t0 (exact in float64).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cobot_calib_ros.ros.time import header_ns, ns_to_stamp

CAPTURES = 'cobot_calib/captures'               # as the nodes publish it (relative)
CAPTURES_TOPIC = '/' + CAPTURES                 # as a bag of the un-namespaced suite has it
PROBE_AVERAGES = 'cobot_calib/probe_averages'
PROBE_AVERAGES_TOPIC = '/' + PROBE_AVERAGES
AVERAGE_FIELDS = ('duration', 'distance', 'std', 'sample_count', 'rejected_count', 'error_code',
                  'reading_status', 'min_range', 'max_range')


def capture_mark(target: str, joint_names: Sequence[str], position: Sequence[float],
                 std: Sequence[float], stamp_ns: int):
    """The CAPTURES message of one capture (see the module doc)."""
    from sensor_msgs.msg import JointState
    msg = JointState(name=list(joint_names), position=[float(v) for v in position],
                     velocity=[0.0] * len(position), effort=[float(v) for v in std])
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = target
    return msg


def captured_joints(msg, order: Sequence[str]) -> list[float]:
    """A capture mark's joints [rad] in ``order``; KeyError naming a joint it lacks."""
    joints = dict(zip(msg.name, msg.position))
    return [joints[name] for name in order]


def average_mark(t0_ns: int, duration: float, response, window):
    """The PROBE_AVERAGES message of one probe/average: ``response`` (AverageProximity
    response), ``window`` the (stamp [ns], ...) readings it held (see the module doc)."""
    from sensor_msgs.msg import JointState
    mark = JointState(name=list(AVERAGE_FIELDS))
    mark.header.stamp = ns_to_stamp(t0_ns)
    mark.header.frame_id = 'probe'
    mark.position = [float(duration), *(float(getattr(response, f))
                                        for f in AVERAGE_FIELDS[1:])]
    mark.velocity = [float(stamp - t0_ns) for stamp, *_ in window]
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
    """A PROBE_AVERAGES message as an AverageMark; ValueError naming a missing field."""
    values = dict(zip(msg.name, msg.position))
    t0 = header_ns(msg)
    try:
        return AverageMark(t0, float(values['duration']), float(values['distance']),
                           float(values['std']), int(values['sample_count']),
                           int(values['rejected_count']), int(values['error_code']),
                           int(values['reading_status']),
                           tuple(t0 + round(v) for v in msg.velocity))
    except KeyError as exc:
        raise ValueError(f'a {PROBE_AVERAGES_TOPIC} message without {exc.args[0]!r} (names: '
                         f'{list(msg.name)})') from None
