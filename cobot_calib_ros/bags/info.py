"""The text ``ros2 bag info`` prints, for a bag open in reader.Bag.

Layout as Jazzy's rosbag2_py format_bag_meta_data: a blank line, then ``Files``, ``Bag size``
(every file in the bag directory, KiB/MiB with one decimal), ``Storage id``, ``ROS Distro``
(``unknown`` when metadata has none), ``Duration`` (``s.nnnnnnnnn s``), ``Start``/``End`` in local
time with the epoch seconds, ``Messages`` (without service events), one line per topic
(``Topic: | Type: | Count: | Serialization Format:``, aligned under the first at column 19),
then ``Service:`` and ``Service information:`` for service event topics.

``verbose`` adds, under each topic, its type hash and the QoS its publishers offered (not in
``ros2 bag info``, which shows services in detail instead); ``topic_names`` prints the topic
names alone (``ros2 bag info -t``).
"""
from __future__ import annotations

import time

from rosbags.interfaces import Qos

from cobot_calib_ros.bags.metadata import duration_ns
from cobot_calib_ros.bags.reader import Bag, TopicInfo
from cobot_calib_ros.ros.time import split_ns

INDENT = 19            # "Topic information: " (the longest label) is 19 wide
TIME_MAX = 2**63 - 1


def format_info(bag: Bag, verbose: bool = False) -> str:
    """What ``ros2 bag info BAG`` prints (print() adds the final newline)."""
    duration = bag.duration_ns
    services = [t for t in bag.topics.values() if is_service_event_topic(t.name, t.type)]
    topics = [t for t in bag.topics.values() if t not in services]
    pad = ' ' * INDENT
    lines = ['']
    files = bag.relative_files or ['']
    lines.append(f'Files:             {files[0]}')
    lines += [pad + f for f in files[1:]]
    lines += [f'Bag size:          {format_file_size(bag.size_bytes)}',
              f'Storage id:        {bag.storage_id}',
              f'ROS Distro:        {bag.ros_distro or "unknown"}',
              f'Duration:          {_seconds(duration)}s',
              f'Start:             {_time_point(bag.start_ns)}',
              f'End:               {_time_point(bag.start_ns, duration)}',
              f'Messages:          {bag.message_count - sum(t.count for t in services)}']
    topic_lines = []
    for info in topics:
        topic_lines.append(f'Topic: {info.name} | Type: {info.type} | Count: {info.count} | '
                           f'Serialization Format: {info.serialization_format}')
        if verbose:
            topic_lines += ['  ' + line for line in _details(info)]
    lines.append('Topic information: ' + (topic_lines[0] if topic_lines else ''))
    lines += [pad + line for line in topic_lines[1:]]
    lines.append(f'Service:           {len(services)}')
    service_lines = [f'Service: {service_name(t.name)} | Type: {service_type(t.type)} | '
                     f'Event Count: {t.count} | Serialization Format: {t.serialization_format}'
                     for t in services]
    lines.append('Service information: ' + (service_lines[0] if service_lines else ''))
    lines += [' ' * (INDENT + 2) + line for line in service_lines[1:]]
    return '\n'.join(lines)


def _time_point(start_ns: int | None, after_ns: int = 0) -> str:
    """A bag's start (or start + after_ns); an empty bag has none (rosbag2 writes the largest
    time, which ros2 bag info shows as Apr 11 2262): '(no messages)'."""
    if start_ns is None or start_ns == TIME_MAX:
        return '(no messages)'
    return format_time_point(start_ns + after_ns)


def format_topic_names(bag: Bag) -> str:
    """``ros2 bag info -t``: the topic names, service event topics left out."""
    return '\n'.join(t.name for t in bag.topics.values()
                     if not is_service_event_topic(t.name, t.type))


def _details(info: TopicInfo) -> list[str]:
    lines = [f'Type hash: {info.type_hash or "(none)"}']
    if info.converted_from:
        lines.append(f'Recorded as: {info.converted_from} (read through bags.mark_converter)')
    if not info.offered_qos:
        lines.append('Offered QoS: (not recorded)')
    for i, profile in enumerate(info.offered_qos):
        label = 'Offered QoS: ' if i == 0 else '             '
        lines.append(label + format_qos(profile))
    return lines


def format_qos(profile: Qos) -> str:
    """One offered profile on one line: the policies a replay uses, then finite durations."""
    parts = [f'reliability: {profile.reliability.name.lower()}',
             f'durability: {profile.durability.name.lower()}',
             f'history: {profile.history.name.lower()}', f'depth: {profile.depth}']
    for name, value in (('deadline', profile.deadline), ('lifespan', profile.lifespan),
                        ('liveliness_lease_duration', profile.liveliness_lease_duration)):
        ns = duration_ns(value)
        parts.append(f'{name}: ' + ('infinite' if ns is None else f'{_seconds(ns)}s'))
    parts.append(f'liveliness: {profile.liveliness.name.lower()}')
    return ', '.join(parts)


def is_service_event_topic(name: str, msgtype: str) -> bool:
    """rosbag2_cpp::is_service_event_topic."""
    return ('/srv/' in msgtype and msgtype.endswith('_Event')
            and name.endswith('/_service_event'))


def service_name(topic: str) -> str:
    return topic[:-len('/_service_event')]


def service_type(msgtype: str) -> str:
    return msgtype[:-len('_Event')]


def _seconds(ns: int) -> str:
    sec, frac = split_ns(ns)
    return f'{sec}.{frac:09d}'


def format_time_point(ns: int) -> str:
    """``%b %e %Y %H:%M:%S.nnnnnnnnn (s.nnnnnnnnn)`` in local time, as rosbag2 prints it."""
    sec, frac = split_ns(ns)
    try:
        local = time.localtime(sec)
        date = time.strftime('%b %e %Y', local)
        clock = time.strftime('%H:%M:%S', local)
    except (OverflowError, OSError, ValueError):
        date, clock = '?', '?'
    return f'{date} {clock}.{frac:09d} ({sec}.{frac:09d})'


def format_file_size(size: int) -> str:
    """rosbag2's format_file_size: B, KiB, MiB, GiB, TiB; one decimal above bytes."""
    value = float(size)
    units = ('B', 'KiB', 'MiB', 'GiB', 'TiB')
    index = 0
    while value >= 1024 and index < 4:
        value /= 1024
        index += 1
    return f'{value:.0f} {units[index]}' if index == 0 else f'{value:.1f} {units[index]}'
