"""Old bags' marks as today's messages: the converter every bag is read through (bags.reader).

Until issue 39 the capture and probe-average marks (ros.marks) were sensor_msgs/JointState
with a packing of their own: a capture's target in ``header.frame_id``, its joints in
``name``/``position`` and their standard deviation in ``effort``; a probe average's nine
numbers in ``position`` under the names ros.marks.LEGACY_FIELDS and the readings' stamps, ns
after the window start, in ``velocity``. A bag that has JointState on CAPTURES_TOPIC or
PROBE_AVERAGES_TOPIC is shown with the mark's own type there (TopicInfo.converted_from says
what was recorded), and each of its messages on those topics is decoded, moved field by field
into the mark and serialized again (CDR), so the players, the replay checks and the sphere
loader see one type whatever the bag's age. Nothing else of a bag is touched.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cobot_calib_ros.ros.marks import (AVERAGE_TYPE, CAPTURE_TYPE, CAPTURES_TOPIC,
                                       LEGACY_FIELDS, PROBE_AVERAGES_TOPIC)

LEGACY_TYPE = 'sensor_msgs/msg/JointState'
MARK_TYPES = {CAPTURES_TOPIC: CAPTURE_TYPE, PROBE_AVERAGES_TOPIC: AVERAGE_TYPE}


def legacy_topics(topics: dict) -> dict[str, str]:
    """{topic: the mark type it converts to} of a bag's topics (TopicInfo by name) that hold
    marks recorded as JointState."""
    return {name: MARK_TYPES[name] for name, info in topics.items()
            if name in MARK_TYPES and info.type == LEGACY_TYPE}


def converter(store, topic: str) -> Callable[[bytes], bytes]:
    """The function turning one recorded JointState mark of ``topic`` (CDR) into the mark's
    own message (CDR); ``store``: a rosbags typestore with cobot_calib_msgs in it."""
    build = _capture if topic == CAPTURES_TOPIC else _average
    msgtype = MARK_TYPES[topic]

    def convert(rawdata: bytes) -> bytes:
        old = store.deserialize_cdr(rawdata, LEGACY_TYPE)
        return bytes(store.serialize_cdr(build(store, old), msgtype))
    return convert


def _header(store, old, frame_id: str):
    Header = store.types['std_msgs/msg/Header']
    return Header(stamp=old.header.stamp, frame_id=frame_id)


def _capture(store, old):
    return store.types[CAPTURE_TYPE](
        header=_header(store, old, ''), target=old.header.frame_id,
        joint_names=list(old.name), position_rad=np.asarray(old.position, dtype=np.float64),
        std_rad=np.asarray(old.effort, dtype=np.float64))


def _average(store, old):
    values = dict(zip(old.name, old.position))
    missing = [name for name in LEGACY_FIELDS if name not in values]
    if missing:
        raise ValueError(f'a {PROBE_AVERAGES_TOPIC} JointState mark without {missing[0]!r} '
                         f'(names: {list(old.name)})')
    return store.types[AVERAGE_TYPE](
        header=_header(store, old, old.header.frame_id), duration_s=float(values['duration']),
        error_code=int(values['error_code']), distance_m=float(values['distance']),
        std_m=float(values['std']), sample_count=int(values['sample_count']),
        rejected_count=int(values['rejected_count']),
        reading_status=int(values['reading_status']),
        min_range_m=float(values['min_range']), max_range_m=float(values['max_range']),
        reading_offsets_ns=np.array([round(v) for v in old.velocity], dtype=np.int64))


def convert_bag(source, out, compression: str | None = 'zstd') -> int:
    """Write ``source`` again at ``out`` with its marks as today's messages (every other topic,
    message and stamp as recorded; the recorded publish stamp is not kept, the receive stamp
    stands for both); the number of marks converted. BagError as the reader and writer raise
    it."""
    from cobot_calib_ros.bags.reader import open_bag
    from cobot_calib_ros.bags.writer import BagWriter
    with open_bag(source) as bag, BagWriter(out, compression=compression) as writer:
        converted = [name for name, info in bag.topics.items() if info.converted_from]
        for name, info in bag.topics.items():
            writer.add_topic(name, info.type, info.offered_qos, info.type_hash or None,
                             serialization_format=info.serialization_format)
        for message in bag.messages():
            writer.write(message.topic, message.rawdata, message.timestamp_ns)
        return sum(bag.topics[name].count for name in converted)

