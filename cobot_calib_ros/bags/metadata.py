"""rosbag2's metadata.yaml and QoS texts, written the way Jazzy's rosbag2 writes them.

Jazzy writes metadata ``version: 9`` (yaml-cpp block style). There, a topic's
``offered_qos_profiles`` is a YAML list of maps with policy names as strings (``history:
unknown``, ``reliability: reliable``, ...) and "infinite" durations as ``sec: 9223372036,
nsec: 854775807``; up to version 8 it was one quoted string holding the same list with integer
policies. The mcap channel metadata ``offered_qos_profiles`` holds that list as a YAML text (the
version 9 form: rosbag2_storage::serialize_rclcpp_qos_vector).

QoS profiles are rosbags' ``Qos`` named tuples here (what rosbags' readers give back); the
recorder converts rclpy's profiles into them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)

from cobot_calib_ros.ros.time import NS_PER_S

VERSION = 9                      # Jazzy's rosbag2 metadata version
DEFAULT_DISTRO = 'jazzy'
INFINITE = QosTime(9223372036, 854775807)   # RMW_DURATION_INFINITE as rmw_time_t
# "Infinite" as Foxy-era rmw implementations wrote it (rosbag2_storage/qos.cpp)
FOXY_INFINITE = (QosTime(0x7FFFFFFF, 0xFFFFFFFF), QosTime(0x7FFFFFFF, 0x7FFFFFFF),
                 QosTime(9223372036, 854775807))
# custom_data key our writer sets while a recording is open; the final metadata drops it
IN_PROGRESS_KEY = 'cobot_calib_ros.recording'
IN_PROGRESS_VALUE = 'in_progress'


def qos(reliability: str = 'reliable', durability: str = 'volatile', history: str = 'unknown',
        depth: int = 0, deadline: QosTime = INFINITE, lifespan: QosTime = INFINITE,
        liveliness: str = 'automatic', lease: QosTime = INFINITE) -> Qos:
    """A profile as a recorder sees a publisher's offer (history unknown, depth 0)."""
    return Qos(QosHistory[history.upper()], depth, QosReliability[reliability.upper()],
               QosDurability[durability.upper()], deadline, lifespan,
               QosLiveliness[liveliness.upper()], lease, False)


def is_infinite(value: QosTime) -> bool:
    """True for "infinite" durations, however a distribution wrote them (and for zero,
    which rmw reads as "default": no deadline, no lifespan)."""
    return value in FOXY_INFINITE or value.sec >= 0x7FFFFFFF or (value.sec, value.nsec) == (0, 0)


def duration_ns(value: QosTime) -> int | None:
    """A finite, non-zero QoS duration in ns; None for infinite/default."""
    return None if is_infinite(value) else value.sec * NS_PER_S + value.nsec


def _policy(value) -> str:
    return value.name.lower()


def qos_lines(profiles: list[Qos], indent: int) -> list[str]:
    """The profiles as a yaml-cpp block sequence (version 9 names), indented by ``indent``."""
    pad = ' ' * indent
    lines = []
    for p in profiles:
        item = [f'history: {_policy(p.history)}', f'depth: {p.depth}',
                f'reliability: {_policy(p.reliability)}',
                f'durability: {_policy(p.durability)}',
                'deadline:', f'  sec: {p.deadline.sec}', f'  nsec: {p.deadline.nsec}',
                'lifespan:', f'  sec: {p.lifespan.sec}', f'  nsec: {p.lifespan.nsec}',
                f'liveliness: {_policy(p.liveliness)}',
                'liveliness_lease_duration:', f'  sec: {p.liveliness_lease_duration.sec}',
                f'  nsec: {p.liveliness_lease_duration.nsec}',
                'avoid_ros_namespace_conventions: '
                + ('true' if p.avoid_ros_namespace_conventions else 'false')]
        lines.append(f'{pad}- {item[0]}')
        lines.extend(f'{pad}  {line}' for line in item[1:])
    return lines


def qos_text(profiles: list[Qos]) -> str:
    """The mcap channel metadata value: YAML::Dump of the version 9 list (no final newline)."""
    return '\n'.join(qos_lines(profiles, 0)) if profiles else ''


def _scalar(text: str) -> str:
    """A string as yaml-cpp writes it: plain when safe, else double-quoted."""
    if text == '':
        return '""'
    plain_unsafe = (text[0] in '-?:,[]{}#&*!|>\'"%@` ' or text[-1] == ' '
                    or any(c in text for c in ':#\n\t"\\')
                    or text.lower() in ('~', 'null', 'true', 'false', 'yes', 'no', 'on', 'off'))
    if not plain_unsafe:
        try:
            float(text)
        except ValueError:
            return text
    escaped = text.replace('\\', '\\\\').replace('"', '\\"').replace('\n', '\\n')
    return f'"{escaped}"'


@dataclass
class TopicRecord:
    """One topic of metadata.yaml's topics_with_message_count."""

    name: str
    type: str
    offered_qos: list[Qos] = field(default_factory=list)
    type_hash: str = ''
    serialization_format: str = 'cdr'
    count: int = 0


@dataclass
class BagRecord:
    """What metadata.yaml holds (one storage file)."""

    storage_id: str
    file: str
    topics: list[TopicRecord]
    start_ns: int | None = None       # first message [ns]; None for an empty bag
    end_ns: int | None = None         # last message [ns]
    compression_format: str = ''
    compression_mode: str = ''
    ros_distro: str = DEFAULT_DISTRO
    custom_data: dict[str, str] = field(default_factory=dict)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def starting_ns(self) -> int:
        # an empty bag: rosbag2 writes time_point::max()
        return self.start_ns if self.start_ns is not None else 2**63 - 1

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns if self.start_ns is not None else 0


def metadata_yaml(bag: BagRecord, top_level: bool = True) -> str:
    """metadata.yaml, version 9, in the layout yaml-cpp gives Jazzy's rosbag2; without
    ``top_level``, the bare BagMetadata map (what rosbag2 stores in the mcap ``rosbag2``
    metadata record)."""
    lines = ['rosbag2_bagfile_information:',
             f'  version: {VERSION}',
             f'  storage_identifier: {_scalar(bag.storage_id)}',
             '  duration:', f'    nanoseconds: {bag.duration_ns}',
             '  starting_time:', f'    nanoseconds_since_epoch: {bag.starting_ns}',
             f'  message_count: {bag.message_count}']
    if bag.topics:
        lines.append('  topics_with_message_count:')
        for t in bag.topics:
            lines += ['    - topic_metadata:',
                      f'        name: {_scalar(t.name)}',
                      f'        type: {_scalar(t.type)}',
                      f'        serialization_format: {_scalar(t.serialization_format)}']
            if t.offered_qos:
                lines.append('        offered_qos_profiles:')
                lines += qos_lines(t.offered_qos, 10)
            else:
                lines.append('        offered_qos_profiles: []')
            lines += [f'        type_description_hash: {_scalar(t.type_hash)}',
                      f'      message_count: {t.count}']
    else:
        lines.append('  topics_with_message_count: []')
    lines += [f'  compression_format: {_scalar(bag.compression_format)}',
              f'  compression_mode: {_scalar(bag.compression_mode)}',
              '  relative_file_paths:', f'    - {_scalar(bag.file)}',
              '  files:', f'    - path: {_scalar(bag.file)}',
              '      starting_time:', f'        nanoseconds_since_epoch: {bag.starting_ns}',
              '      duration:', f'        nanoseconds: {bag.duration_ns}',
              f'      message_count: {bag.message_count}']
    if bag.custom_data:
        lines.append('  custom_data:')
        lines += [f'    {_scalar(k)}: {_scalar(v)}' for k, v in bag.custom_data.items()]
    else:
        lines.append('  custom_data: ~')
    lines.append(f'  ros_distro: {_scalar(bag.ros_distro)}')
    if not top_level:
        lines = [line[2:] for line in lines[1:]]
    return '\n'.join(lines) + '\n'
