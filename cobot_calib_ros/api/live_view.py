"""The suite's topics on a Foxglove WebSocket server (foxglove-sdk), for ``cobot-calib view``.

Every topic found on the graph (or the ones asked for) becomes a channel with the ``ros2msg``
schema rosbag2 stores (bags.interfaces.full_text) and ``cdr`` messages passed through as
received (a raw subscription: nothing is decoded), so Foxglove or Lichtblick shows the
markers (ros.markers), /tf_static, user_frame, joint_states ... without a ROS install. Clients
connect through api.ws_protocol_bridge, which accepts both names of the subprotocol.

A topic is subscribed on ROS only while a window subscribes to its channel, so the view alone
does not make mock_camera render. A latched topic (every publisher transient local) is the
exception: it stays subscribed and keeps its last messages, which a window that subscribes
later gets once, as a late ROS subscriber would (_Latched).
"""
from __future__ import annotations

from collections import deque
import queue
import threading
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
LATCHED_KEPT = 8         # last messages kept per latched topic (one per publisher, typically)


class _Latched:
    """A latched topic's last LATCHED_KEPT messages, and the windows subscribed to its channel:
    each window gets each message once, the kept ones when it subscribes, later ones as they
    come.

    foxglove-sdk 0.30.3 routes a channel to a window before it calls on_subscribe, so a message
    logged to all sinks then would reach the window twice (live and kept) and the other windows
    again; each message goes to each window alone (Channel.log's sink_id). The Python API names
    a window by its client id, not its sink id: both come from process-wide counters that move
    together while the process opens no other foxglove sink (an MCAP writer, remote access),
    and this module opens none. (A replay 1 s after on_subscribe, to every sink once the
    channel had one, reached nothing once in a loaded test run.)"""

    def __init__(self) -> None:
        self._channel: foxglove.Channel | None = None
        self._kept: deque[bytes] = deque(maxlen=LATCHED_KEPT)
        self._windows: set[int] = set()
        self._lock = threading.Lock()       # the server's threads and the node's

    def open(self, make: Callable[[], foxglove.Channel]) -> foxglove.Channel:
        """The channel ``make()`` creates (and advertises): a window that subscribes at once
        waits for it here."""
        with self._lock:
            self._channel = make()
        return self._channel

    def add_window(self, client_id: int) -> None:
        with self._lock:
            for data in self._kept:
                self._channel.log(data, log_time=time.time_ns(), sink_id=client_id)
            self._windows.add(client_id)

    def remove_window(self, client_id: int) -> None:
        with self._lock:
            self._windows.discard(client_id)

    def on_message(self, data: bytes) -> None:
        with self._lock:
            self._kept.append(data)
            for client_id in self._windows:
                self._channel.log(data, log_time=time.time_ns(), sink_id=client_id)


class _Subscriptions(ServerListener):
    """The server's (un)subscribe events (its own threads): a latched topic's window is served
    at once (_Latched); every event goes on to the node's thread as (topic, +1 or -1). A
    client that disconnects is unsubscribed from all its channels."""

    def __init__(self, latched: dict[str, _Latched]) -> None:
        self.events: queue.SimpleQueue[tuple[str, int]] = queue.SimpleQueue()
        self._latched = latched

    def on_subscribe(self, client, channel) -> None:
        latched = self._latched.get(channel.topic)
        if latched is not None:
            latched.add_window(client.id)
        self.events.put((channel.topic, 1))

    def on_unsubscribe(self, client, channel) -> None:
        latched = self._latched.get(channel.topic)
        if latched is not None:
            latched.remove_window(client.id)
        self.events.put((channel.topic, -1))


class LiveView(Node):
    """Serves the topics on ``host``:``port`` until the node is destroyed. RuntimeError or
    OSError if it cannot listen there."""

    def __init__(self, host: str, port: int, topics: Iterable[str] = (), *,
                 report: Callable[[str], None] = print, **kwargs) -> None:
        super().__init__('cobot_calib_view', **kwargs)
        self.report = report
        self.wanted = {t if t.startswith('/') else '/' + t for t in topics} or None
        self._latched: dict[str, _Latched] = {}
        self._listener = _Subscriptions(self._latched)
        self.channels: dict[str, foxglove.Channel] = {}
        self._types: dict[str, tuple[type, object]] = {}    # topic: (message class, QoS)
        self._skipped: set[str] = set()
        self.viewers: dict[str, int] = {}       # topic: windows subscribed to its channel
        self.ros_subscriptions: dict[str, object] = {}
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
        qos = subscription_qos(publishers, depth=LATCHED_KEPT)
        self._types[topic] = (msg_class, qos)
        described = foxglove.Schema(name=types[0], encoding='ros2msg', data=schema.encode())

        def channel() -> foxglove.Channel:      # advertised to the windows at once
            return foxglove.Channel(topic, message_encoding='cdr', schema=described)
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
            self._latched[topic] = _Latched()
            self.channels[topic] = self._latched[topic].open(channel)
        else:
            self.channels[topic] = channel()
        if topic in self._latched or self.viewers.get(topic, 0) > 0:
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
        latched = self._latched.get(topic)
        if latched is not None:
            return latched.on_message
        channel = self.channels[topic]
        return lambda data: channel.log(data, log_time=time.time_ns())

    def _serve(self) -> None:
        """Subscribes a topic on ROS while a window subscribes to it (latched ones always)."""
        while True:
            try:
                topic, change = self._listener.events.get_nowait()
            except queue.Empty:
                break
            self.viewers[topic] = self.viewers.get(topic, 0) + change
            if topic in self._latched:
                continue
            if self.viewers[topic] > 0 and topic not in self.ros_subscriptions:
                self._subscribe(topic)
            elif self.viewers[topic] <= 0 and topic in self.ros_subscriptions:
                self.destroy_subscription(self.ros_subscriptions.pop(topic))

    def destroy_node(self):
        self.bridge.stop()
        self.server.stop()
        return super().destroy_node()
