"""Marks as messages (issue 39 item 4): the capture and probe-average marks are
cobot_calib_msgs/CaptureMark and ProbeAverageMark; bags recorded before carry them as
sensor_msgs/JointState and are read through bags.mark_converter. The sample bags under bags/
are such old bags: their marks are compared here with an independent decoding of the raw
JointState (rosbags' own reader, not ours), and a copy written with today's messages
(mark_converter.convert_bag) passes the same `replay --check` as the original."""
from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader

from cobot_calib_ros.bags import mark_converter
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.ros import marks
from cobot_calib_ros.ros.time import header_ns

BAGS = Path(__file__).resolve().parents[2] / 'bags'
TIMEOUT = 180.0


def recorded(bag: Path, topic: str) -> list:
    """The topic's messages as recorded (JointState), decoded by rosbags' AnyReader."""
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        assert {c.msgtype for c in connections} == {mark_converter.LEGACY_TYPE}
        return [reader.deserialize(raw, c.msgtype)
                for c, _, raw in reader.messages(connections=connections)]


def converted(bag: Path, topic: str) -> list:
    with open_bag(bag) as opened:
        info = opened.topics[topic]
        assert (info.type, info.converted_from) == (mark_converter.MARK_TYPES[topic],
                                                    mark_converter.LEGACY_TYPE)
        return [opened.deserialize(m.rawdata, m.msgtype) for m in opened.messages([topic])]


@pytest.mark.parametrize('name', ['five_point_close', 'iiwa_spheres', 'landmark_multi_close'])
def test_old_capture_marks_read_as_capture_marks(name):
    old = recorded(BAGS / name, marks.CAPTURES_TOPIC)
    new = converted(BAGS / name, marks.CAPTURES_TOPIC)
    assert len(new) == len(old) > 0
    for o, n in zip(old, new):
        assert n.target == o.header.frame_id and n.header.frame_id == ''
        assert header_ns(n) == header_ns(o)
        assert list(n.joint_names) == list(o.name)
        assert np.array_equal(n.position_rad, o.position)       # to the bit
        assert np.array_equal(n.std_rad, o.effort)


def test_old_probe_average_marks_read_as_probe_average_marks():
    old = recorded(BAGS / 'trial_close', marks.PROBE_AVERAGES_TOPIC)
    new = [marks.read_average_mark(m)
           for m in converted(BAGS / 'trial_close', marks.PROBE_AVERAGES_TOPIC)]
    assert len(new) == len(old) == 46
    for o, n in zip(old, new):
        values = dict(zip(o.name, o.position))
        t0 = header_ns(o)
        assert n == marks.AverageMark(
            t0, values['duration'], values['distance'], values['std'],
            int(values['sample_count']), int(values['rejected_count']),
            int(values['error_code']), int(values['reading_status']),
            tuple(t0 + round(v) for v in o.velocity))
    assert sum(n.ok for n in new) > 0 and sum(not n.ok for n in new) > 0


def test_converted_marks_are_what_rclpy_decodes():
    """The converter's CDR is the wire's: rclpy decodes it as the node's message type."""
    from cobot_calib_msgs.msg import CaptureMark, ProbeAverageMark
    with open_bag(BAGS / 'trial_close') as bag:
        raw = next(bag.messages([marks.PROBE_AVERAGES_TOPIC]))
        mine = marks.read_average_mark(bag.deserialize(raw.rawdata, raw.msgtype))
    assert marks.read_average_mark(deserialize_message(raw.rawdata, ProbeAverageMark)) == mine
    with open_bag(BAGS / 'five_point_close') as bag:
        raw = next(bag.messages([marks.CAPTURES_TOPIC]))
    msg = deserialize_message(raw.rawdata, CaptureMark)
    assert msg.target == 'P1' and len(msg.position_rad) == len(msg.joint_names) == 7


def test_a_malformed_old_mark_is_a_bag_error_naming_the_field(tmp_path):
    from rosbags.typesys import Stores, get_typestore
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.writer import BagWriter
    store = get_typestore(Stores.ROS2_JAZZY)
    JointState = store.types['sensor_msgs/msg/JointState']
    Header, Time = store.types['std_msgs/msg/Header'], store.types['builtin_interfaces/msg/Time']
    old = JointState(header=Header(stamp=Time(sec=1, nanosec=0), frame_id='probe'),
                     name=['duration'], position=np.array([0.02]), velocity=np.array([]),
                     effort=np.array([]))
    with BagWriter(tmp_path / 'bad') as writer:
        writer.add_topic(marks.PROBE_AVERAGES_TOPIC, mark_converter.LEGACY_TYPE)
        writer.write(marks.PROBE_AVERAGES_TOPIC,
                     bytes(store.serialize_cdr(old, mark_converter.LEGACY_TYPE)), 1)
    with open_bag(tmp_path / 'bad') as bag, pytest.raises(BagError, match="'distance'"):
        list(bag.messages())


def replay_check(bag) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'replay',
                           str(bag), '--check'], capture_output=True, text=True, env=env,
                          timeout=TIMEOUT)


@pytest.mark.parametrize('name, passed', [
    ('five_point_close', 'translation differs by'),
    ('trial_close', 'all equal to the live ones'),
    ('iiwa_spheres', 'identified 150 poses'),
])
def test_a_bag_with_todays_marks_passes_the_same_check(tmp_path, name, passed):
    """The sample bag written again with CaptureMark / ProbeAverageMark (as a recording made
    today has them) replays and reproduces its expected result as the old one does
    (test_sample_bags, test_replay_check, test_trial_bag check the originals)."""
    import shutil
    copy = tmp_path / name
    assert mark_converter.convert_bag(BAGS / name, copy) > 0
    for extra in ('expected.yaml', 'expected.json'):
        if (BAGS / name / extra).exists():
            shutil.copy(BAGS / name / extra, copy / extra)
    with open_bag(copy) as bag:
        assert not any(info.converted_from for info in bag.topics.values())
        assert bag.topics[next(iter(set(bag.topics) & set(mark_converter.MARK_TYPES)))].type \
            in mark_converter.MARK_TYPES.values()
    done = replay_check(copy)
    assert done.returncode == 0, done.stdout + done.stderr
    assert passed in done.stdout and 'check passed' in done.stdout, done.stdout
