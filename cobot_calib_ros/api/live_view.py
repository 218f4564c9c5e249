"""The suite's topics on a Foxglove WebSocket server (foxglove-sdk), for ``cobot-calib view``.

Every topic found on the graph (or the ones asked for) becomes a channel with the ``ros2msg``
schema rosbag2 stores (bags.interfaces.full_text) and ``cdr`` messages passed through as
received (a raw subscription: nothing is decoded), so Foxglove or Lichtblick shows the
markers (ros.markers), /tf_static, user_frame, joint_states ... without a ROS install. Clients
connect through api.ws_protocol_bridge, which accepts both names of the subprotocol.

A topic is subscribed on ROS only while a window subscribes to its channel, so the view alone
does not make mock_camera render. A latched topic (every publisher transient local) is the
exception: it stays subscribed and keeps its last messages, which a window that subscribes
later gets once, as a late ROS subscriber would.
"""
from __future__ import annotations

from collections import deque
import queue
import time
from typing import Callable, Iterable

import foxglove
from foxglove.websocket import ServerListener
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy

from cobot_calib_ros.api.ws_protocol_bridge import ProtocolBridge
from cobot_calib_ros.bags.interfaces import full_text
from cobot_calib_ros.ros.graph import new_topics, subscription_qos

SCAN_PERIOD = 1.0        # [s] between looks for new topics
DISCOVERY_WAIT = 5.0     # [s] at most, for the topics on the graph before the server listens
DISCOVERY_QUIET = 1.5    # [s] of no new topic: discovery is taken as done
SERVE_PERIOD = 0.05      # [s] between looks at the windows' (un)subscriptions
# [s] after a window subscribes, its latched messages are sent, once the channel has a
# subscriber at all: the server tells of a subscription before it routes the channel's
# messages to it (foxglove-sdk 0.30.3 calls on_subscribe, then subscribes the client in its
# context; has_sinks() tells when that happened for the first window, not for a second one).
# 0.3 s, then 1 s: with either, a second window got nothing once (test_live_view, 1 run in ~10;
# cause not found)
REPLAY_AFTER = 1.0
LATCHED_KEPT = 8         # last messages kept per latched topic (one per publisher, typically)


class _Subscriptions(ServerListener):
    """Hands the server's (un)subscribe events (its own thread) to the node's thread as
    (topic, +1 or -1); a client that disconnects is unsubscribed from all its channels."""

    def __init__(self) -> None:
        self.events: queue.SimpleQueue[tuple[str, int]] = queue.SimpleQueue()

    def on_subscribe(self, client, channel) -> None:
        self.events.put((channel.topic, 1))

    def on_unsubscribe(self, client, channel) -> None:
        self.events.put((channel.topic, -1))


class LiveView(Node):
    """Serves the topics on ``host``:``port`` until the node is destroyed. RuntimeError or
    OSError if it cannot listen there."""

    def __init__(self, host: str, port: int, topics: Iterable[str] = (), *,
                 report: Callable[[str], None] = print, **kwargs) -> None:
        super().__init__('cobot_calib_view', **kwargs)
        self.report = report
        self.wanted = {t if t.startswith('/') else '/' + t for t in topics} or None
        self._listener = _Subscriptions()
        self.channels: dict[str, foxglove.Channel] = {}
        self._types: dict[str, tuple[type, object]] = {}    # topic: (message class, QoS)
        # topic: (sequence number, message, whether a window was routed when it came)
        self._latched: dict[str, deque[tuple[int, bytes, bool]]] = {}
        self._sequence = 0
        self._skipped: set[str] = set()
        self.viewers: dict[str, int] = {}       # topic: windows subscribed to its channel
        self.ros_subscriptions: dict[str, object] = {}
        # replays: (monotonic time, topic, sequence number of the last message kept before)
        self._due: list[tuple[float, str, int]] = []
        self._discover()
        self.server = foxglove.start_server(name='cobot_calib_ros', host='127.0.0.1', port=0,
                                            server_listener=self._listener)
        try:
            self.bridge = ProtocolBridge(host, port, self.server.port)
        except OSError:
            self.server.stop()
            raise
        self.create_timer(SCAN_PERIOD, self._scan)
        self.create_timer(SERVE_PERIOD, self._serve)

    def _discover(self) -> None:
        """The channels of the topics on the graph now, before the server listens: a window
        that subscribes to a channel advertised a moment ago can be told it is unknown (seen
        with foxglove-sdk 0.30.3), so the suite's topics are there before anyone connects.
        Until every wanted topic is found, or the topic list held still for DISCOVERY_QUIET s,
        at most DISCOVERY_WAIT s."""
        deadline, quiet_since, seen = time.monotonic() + DISCOVERY_WAIT, time.monotonic(), 0
        while time.monotonic() < deadline:
            self._scan()
            if self.wanted is not None and self.wanted <= set(self.channels) | self._skipped:
                return
            found = len(self.channels) + len(self._skipped)
            if found != seen:
                seen, quiet_since = found, time.monotonic()
            elif self.wanted is None and time.monotonic() - quiet_since > DISCOVERY_QUIET:
                return
            time.sleep(0.1)

    @property
    def port(self) -> int:
        return self.bridge.port

    def _scan(self) -> None:
        for topic in new_topics(self, self.channels, self._skipped, self.wanted):
            self._add(topic)

    def _add(self, topic: str) -> None:
        from cobot_calib_ros.ros.types import import_type
        publishers = self.get_publishers_info_by_topic(topic)
        types = sorted({p.topic_type for p in publishers})
        if len(types) != 1:
            if len(types) > 1:
                self._skip(topic, f'published with several types ({", ".join(types)})')
            return
        try:
            msg_class, schema = import_type(types[0]), full_text(types[0])
        except Exception as e:  # noqa: BLE001 - an unknown type or definition: skip, say so
            self._skip(topic, str(e))
            return
        self.channels[topic] = foxglove.Channel(
            topic, message_encoding='cdr',
            schema=foxglove.Schema(name=types[0], encoding='ros2msg', data=schema.encode()))
        qos = subscription_qos(publishers, depth=LATCHED_KEPT)
        self._types[topic] = (msg_class, qos)
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
            self._latched[topic] = deque(maxlen=LATCHED_KEPT)
            self._subscribe(topic)
        elif self.viewers.get(topic, 0) > 0:
            self._subscribe(topic)
        self.report(f'streaming {topic} ({types[0]})')

    def _skip(self, topic: str, why: str) -> None:
        self._skipped.add(topic)
        self.report(f'not streaming {topic}: {why}')

    def _subscribe(self, topic: str) -> None:
        msg_class, qos = self._types[topic]
        self.ros_subscriptions[topic] = self.create_subscription(
            msg_class, topic, self._forward(topic), qos, raw=True)

    def _forward(self, topic: str):
        channel, kept = self.channels[topic], self._latched.get(topic)

        def on_message(data: bytes) -> None:
            reached_a_window = channel.has_sinks()
            channel.log(data, log_time=time.time_ns())
            if kept is not None:
                self._sequence += 1
                kept.append((self._sequence, data, reached_a_window))
        return on_message

    def _serve(self) -> None:
        """Subscribes a topic on ROS while a window subscribes to it (latched ones always),
        and sends a latched topic's last messages to a window that subscribes to it."""
        while True:
            try:
                topic, change = self._listener.events.get_nowait()
            except queue.Empty:
                break
            self.viewers[topic] = self.viewers.get(topic, 0) + change
            if topic in self._latched:
                if change > 0:
                    self._due.append((time.monotonic() + REPLAY_AFTER, topic, self._sequence))
            elif self.viewers[topic] > 0 and topic not in self.ros_subscriptions:
                self._subscribe(topic)
            elif self.viewers[topic] <= 0 and topic in self.ros_subscriptions:
                self.destroy_subscription(self.ros_subscriptions.pop(topic))
        now, sent = time.monotonic(), set()
        for entry in [d for d in self._due if d[0] <= now]:
            _, topic, before = entry
            if self.viewers[topic] <= 0:            # the window left before: nobody to send to
                self._due.remove(entry)
            elif self.channels[topic].has_sinks():
                self._due.remove(entry)
                if topic not in sent:               # windows that came together: once
                    sent.add(topic)
                    self._replay(topic, before)

    def _replay(self, topic: str, before: int) -> None:
        """The latched messages a new window has not had: those kept before it subscribed,
        and those that came after while no window was routed (their live send reached
        nobody). One that came after with a window routed went to it live: sending it again
        showed it twice (a latched message arriving late, on a loaded machine)."""
        for sequence, data, reached_a_window in self._latched.get(topic, ()):
            if sequence <= before or not reached_a_window:
                self.channels[topic].log(data, log_time=time.time_ns())

    def destroy_node(self):
        self.bridge.stop()
        self.server.stop()
        return super().destroy_node()
