"""Every node's health on /diagnostics (diagnostic_msgs/DiagnosticArray), once a second.

A node makes one ``Diagnostics`` and keeps its status current with ``set``; the timer stamps
each message with the node clock (use_sim_time works) and publishes the latest status.
"""
from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)


class Diagnostics:
    def __init__(self, node: Node, hardware_id: str = '', period: float = 1.0) -> None:
        self._node = node
        self._lock = threading.Lock()
        self._status = DiagnosticStatus(level=OK, name=f'{node.get_name()}: health',
                                        message='starting', hardware_id=hardware_id)
        self._values: dict[str, str] = {}
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        node.create_timer(period, self.publish)

    def set(self, level: bytes | int, message: str, **values) -> None:
        """The node's current state: a level (OK, WARN, ERROR), one line, key figures."""
        with self._lock:
            self._status.level = bytes([level]) if isinstance(level, int) else level
            self._status.message = message
            self._values.update({k: str(v) for k, v in values.items()})

    def publish(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        with self._lock:
            self._status.values = [KeyValue(key=k, value=v) for k, v in self._values.items()]
            msg.status = [self._status]
            self._pub.publish(msg)
