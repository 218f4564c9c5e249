"""bag_recorder: record topics into a rosbag2 bag (writer.BagWriter), as ``ros2 bag record``.

Given topics, or all topics (``all_topics``; hidden ones, with a name part starting with ``_``
such as action and service-event topics, only with ``include_hidden``). The graph is scanned
every SCAN_PERIOD (faster while the recording starts), so topics whose first publisher shows up
later are recorded from then on. Each topic is subscribed raw (serialized bytes, never
deserialised) with a QoS every publisher can match (best effort if any offers it, transient
local only if all do: ros.graph.subscription_qos) and keep-last DEPTH; the bag stores the QoS
each publisher offered and the type hash the graph reports.

Timestamps as Jazzy's recorder takes them: receive time from the middleware (the node clock
with use_sim_time), send time from the publisher's source timestamp. Under the EventsExecutor
(COBOT_CALIB_EXECUTOR=events), whose rclpy 7.1.6 build cannot call back with the message info,
the receive time is taken in the callback and the send time is not known (set equal).

Closing: ``destroy_node`` (Ctrl-C and SIGTERM under ros.spin.run, or the end of ``duration``)
finishes the bag: mcap summary and the final metadata.yaml. Until then the writer hands closed
chunks to the OS at least once a second, so a crash loses at most that much.

As its own process (``main``; ``ros2 run cobot_calib_ros bag_recorder --ros-args -p
output:=DIR -p topics:='[/joint_states]'``, also ``.venv/lib/cobot_calib_ros/bag_recorder``)
it takes the parameters ``output``, ``topics``, ``all_topics``, ``include_hidden``,
``compression`` and ``duration`` (read at start-up, described in ``ros2 param describe``).
Built from Python (``cobot-calib record``) the arguments are the values, and the parameters
show them.
"""
from __future__ import annotations

import sys
import time
from typing import Callable, Iterable

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)

from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.writer import BagWriter
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.graph import new_topics
from cobot_calib_ros.ros.params import read_once
from cobot_calib_ros.ros.time import NS_PER_S

NODE_NAME = 'bag_recorder'
DEPTH = 1000                  # keep-last depth of each subscription (1 kHz bursts)
SCAN_PERIOD = 1.0             # [s] between graph scans ...
STARTUP_SCAN_PERIOD = 0.25    # [s] ... and during the first STARTUP_SCANS_S
STARTUP_SCANS_S = 3.0


def bag_qos(profile) -> Qos:
    """rclpy's QoSProfile (as the graph reports a publisher's) as the bag stores it."""
    def duration(value) -> QosTime:
        return QosTime(*divmod(value.nanoseconds, NS_PER_S))
    return Qos(QosHistory(int(profile.history)), profile.depth,
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               duration(profile.deadline), duration(profile.lifespan),
               QosLiveliness(int(profile.liveliness)),
               duration(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def declare_strings(node: Node, name: str, value, description: str) -> list[str]:
    """A read-only string-array parameter that may start empty (rclpy types an empty list
    default as a byte array); its value, [] when not set."""
    descriptor = ParameterDescriptor(
        description=f'{description} (read at start-up; restart the node to change it)',
        type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True)
    param = node.declare_parameter(name, list(value) if value else Parameter.Type.STRING_ARRAY,
                                   descriptor)
    return list(param.value or [])


class BagRecorder(Node):
    """Records into a new bag directory ``output``; see the module doc. Without ``output``
    every setting comes from the node's parameters."""

    def __init__(self, output: str | None = None, topics: Iterable[str] | None = None, *,
                 all_topics: bool = False, include_hidden: bool = False,
                 compression: str | None = None, depth: int = DEPTH,
                 duration: float | None = None, report: Callable[[str], None] | None = None,
                 node_name: str = NODE_NAME, **node_kwargs) -> None:
        super().__init__(node_name, start_parameter_services=output is None, **node_kwargs)
        self.report = report or self.get_logger().info
        given = self._declare_parameters(output, topics, all_topics, include_hidden,
                                         compression, duration)
        if output is None:
            output, topics, all_topics, include_hidden, compression, duration = given
            if not output:
                raise ValueError('parameter output: give the bag directory to create '
                                 '(-p output:=DIR)')
        wanted = [t if t.startswith('/') else '/' + t for t in topics or ()]
        if not wanted and not all_topics:
            raise ValueError('give topics to record, or all_topics')
        self.wanted = None if all_topics else set(wanted)
        self.include_hidden = include_hidden
        self.depth = depth
        self.writer = BagWriter(output, compression=compression)
        self.subscriptions_by_topic: dict = {}
        self._skipped: set[str] = set()
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self._without_info = spin.executor_kind() == 'events'
        self._started = self.get_clock().now()
        self._ticks = 0
        self._started_steady = time.monotonic()
        self._warned = False
        self._closed = False
        steady = Clock(clock_type=ClockType.STEADY_TIME)    # also under use_sim_time
        self._scan_timer = self.create_timer(STARTUP_SCAN_PERIOD, self._tick, clock=steady)
        if duration:
            self._stop_timer = self.create_timer(duration, self._end_of_duration, clock=steady)
        self._scan()

    def _declare_parameters(self, output, topics, all_topics, include_hidden, compression,
                            duration) -> tuple:
        """Declare the parameters (the arguments as defaults); their values, in order."""
        values = (
            read_once(self, 'output', output or '',
                      'The bag directory to create (must not exist)'),
            declare_strings(self, 'topics', topics,
                            'Topics to record; empty: all_topics must be true'),
            read_once(self, 'all_topics', bool(all_topics),
                      'Record every topic, also those that appear later'),
            read_once(self, 'include_hidden', bool(include_hidden),
                      'With all_topics: also hidden topics (a name part starting with _)'),
            read_once(self, 'compression', compression or 'none',
                      'mcap chunk compression: zstd or none'),
            read_once(self, 'duration', float(duration or 0.0),
                      'Stop after this long [s] of wall time; 0 = until shut down', 0.0, 1e9))
        compress = values[4]
        if compress not in ('none', 'zstd'):
            raise ValueError(f'parameter compression: {compress!r}; use zstd or none')
        return (*values[:4], None if compress == 'none' else compress, values[5] or None)

    # -- discovery ------------------------------------------------------------------------------

    def _tick(self) -> None:
        self._ticks += 1
        startup = self._ticks * STARTUP_SCAN_PERIOD < STARTUP_SCANS_S
        if startup or self._ticks % round(SCAN_PERIOD / STARTUP_SCAN_PERIOD) == 0:
            self._scan()
            self.writer.flush()
        if self._ticks == round(STARTUP_SCANS_S / STARTUP_SCAN_PERIOD):
            self._warn_unpublished()

    def _warn_unpublished(self) -> None:
        """Once discovery has settled, or at the end of a shorter recording: name the wanted
        topics that nothing publishes (a typo, a node that is not up); they are still recorded
        if a publisher appears later."""
        if self._warned:
            return
        self._warned = True
        missing = sorted((self.wanted or set()) - set(self.subscriptions_by_topic)
                         - self._skipped)
        if missing:
            elapsed = time.monotonic() - self._started_steady
            self.report(f'warning: nothing publishes {", ".join(missing)} (after '
                        f'{min(elapsed, STARTUP_SCANS_S):.2g} s); recorded only if a publisher '
                        'appears (see `cobot-calib list`)')

    def _scan(self) -> None:
        for name in new_topics(self, self.subscriptions_by_topic, self._skipped, self.wanted,
                               self.include_hidden):
            self._subscribe(name)

    def _subscribe(self, topic: str) -> None:
        from cobot_calib_ros.ros.types import import_type
        from cobot_calib_ros.ros.graph import subscription_qos
        publishers = self.get_publishers_info_by_topic(topic)
        if not publishers:
            return                              # no publisher yet: the type is not settled
        types = sorted({p.topic_type for p in publishers})
        if len(types) > 1:
            self._skip(topic, f'published with several types ({", ".join(types)})')
            return
        try:
            msg_class = import_type(types[0])
        except ValueError as exc:
            self._skip(topic, str(exc))
            return
        hashes = {str(p.topic_type_hash) for p in publishers} - {'INVALID'}
        self.writer.add_topic(topic, types[0], [bag_qos(p.qos_profile) for p in publishers],
                              type_hash=hashes.pop() if len(hashes) == 1 else None)
        self.subscriptions_by_topic[topic] = self.create_subscription(
            msg_class, topic, self._callback(topic),
            subscription_qos(publishers, depth=self.depth), raw=True)
        self.report(f'recording {topic} ({types[0]})')

    def _skip(self, topic: str, why: str) -> None:
        self._skipped.add(topic)
        self.report(f'not recording {topic}: {why}')

    def _callback(self, topic: str):
        write = self.writer.write
        if self._without_info:
            # rclpy 7.1.6's EventsExecutor fails on callbacks that take the message info
            # (SystemError "null argument to internal routine"): receive time from the clock
            # here, send time unknown (written as the receive time)
            now = self.get_clock().now if self._sim_time else None

            def on_message(data: bytes) -> None:
                stamp = now().nanoseconds if now is not None else time.time_ns()
                write(topic, data, stamp, stamp)
        elif self._sim_time:
            clock = self.get_clock()

            def on_message(data: bytes, info: dict) -> None:
                write(topic, data, clock.now().nanoseconds, info['source_timestamp'])
        else:
            def on_message(data: bytes, info: dict) -> None:
                write(topic, data, info['received_timestamp'], info['source_timestamp'])
        return on_message

    # -- the end --------------------------------------------------------------------------------

    def _end_of_duration(self) -> None:
        self._stop_timer.cancel()
        self.context.try_shutdown()

    def close(self) -> None:
        """Finish the bag (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._warn_unpublished()        # a recording shorter than discovery's settling
        for topic, sub in list(self.subscriptions_by_topic.items()):
            self._drain(topic, sub)
            try:
                self.destroy_subscription(sub)
            except Exception:  # noqa: BLE001 - the context is already down: nothing to stop
                pass
        self.writer.close()
        topics = self.writer.topics
        self.report(f'bag {self.writer.path}: {self.writer.message_count} messages on '
                    f'{len(topics)} topics')

    def _drain(self, topic: str, sub) -> None:
        """Write what the middleware delivered but no executor took yet (Ctrl-C comes at any
        moment; acknowledged messages sit in the reader's history)."""
        write = self.writer.write
        try:
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
                    if taken is None:
                        return
                    data, info = taken
                    stamp = (self.get_clock().now().nanoseconds if self._sim_time
                             else info.get('received_timestamp') or time.time_ns())
                    write(topic, data, stamp, info.get('source_timestamp') or stamp)
        except Exception:  # noqa: BLE001 - a destroyed handle or context: nothing to take
            return

    def destroy_node(self) -> None:
        try:
            self.close()
        finally:
            super().destroy_node()


def main(args=None) -> None:
    """``ros2 run cobot_calib_ros bag_recorder --ros-args -p output:=DIR -p topics:=[...]``."""
    try:
        spin.run(BagRecorder, args)
    except (BagError, ValueError) as exc:
        print(f'bag_recorder: {exc}', file=sys.stderr)
        sys.exit(1)


if __name__ == '__main__':
    main()
