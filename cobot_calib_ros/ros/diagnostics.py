"""Every node's health on /diagnostics (diagnostic_msgs/DiagnosticArray), once a second.

A node makes one ``Diagnostics`` and keeps its status current with ``set``; the timer stamps
each message with the node clock (use_sim_time works) and publishes the latest status. Counters
that change at a high rate are better read once per message: give ``update``, a function the
timer calls just before it publishes (on the timer's executor thread), which calls ``set``;
or ``watch`` a figure, which every message then reads afresh (e.g. a retry count).

The status is named ``<node>: health`` after the node's fully qualified name without the
leading slash (``iso/proximity_sensor: health``), so the same node in two namespaces gives two
statuses; ``name`` replaces it (a hidden helper node reports for the node it serves).
"""
from __future__ import annotations

import threading
import time
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)
TOPIC = '/diagnostics'


def status_name(node: Node, task: str = 'health') -> str:
    """``<namespace/node>: <task>``, the node's fully qualified name without the first slash."""
    return f'{node.get_fully_qualified_name().lstrip("/")}: {task}'


class Diagnostics:
    def __init__(self, node: Node, hardware_id: str = '', period: float = 1.0,
                 name: str = '', update: Callable[[], None] | None = None) -> None:
        self._node = node
        self._update = update
        self._lock = threading.Lock()
        self._status = DiagnosticStatus(level=OK, name=name or status_name(node),
                                        message='starting', hardware_id=hardware_id)
        self._values: dict[str, str] = {}
        self._watched: dict[str, Callable[[], object]] = {}
        self._pub = node.create_publisher(DiagnosticArray, TOPIC, 10)
        node.create_timer(period, self.publish)

    def set(self, level: bytes | int, message: str, **values) -> None:
        """The node's current state: a level (OK, WARN, ERROR), one line, key figures."""
        with self._lock:
            self._status.level = bytes([level]) if isinstance(level, int) else level
            self._status.message = message
            self._values.update({k: str(v) for k, v in values.items()})

    def watch(self, **figures: Callable[[], object]) -> None:
        """Key figures read at every message (``capture_retries=lambda: calls.capture_retries``),
        whatever the level and message are."""
        with self._lock:
            self._watched.update(figures)

    def publish(self) -> None:
        if self._update is not None:
            try:
                self._update()
            except Exception as exc:  # noqa: BLE001 - must not stop the executor it runs on
                self.set(ERROR, f'diagnostics update failed: {exc!r}')
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        with self._lock:
            self._values.update({k: str(read()) for k, read in self._watched.items()})
            self._status.values = [KeyValue(key=k, value=v) for k, v in self._values.items()]
            msg.status = [self._status]
            self._pub.publish(msg)


class RateMeter:
    """The rate [Hz] of a growing count between two readings (monotonic wall time)."""

    def __init__(self) -> None:
        self._last: tuple[float, int] | None = None

    def rate_hz(self, count: int) -> float:
        """Events per second since the previous call (0.0 on the first)."""
        now = time.monotonic()
        last, self._last = self._last, (now, count)
        if last is None or now <= last[0]:
            return 0.0
        return (count - last[1]) / (now - last[0])
