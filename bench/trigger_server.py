"""A bare std_srvs/Trigger server: the reference round trip for the service benches.

Run as its own process (launcher.Suite via benchlib.ScriptSpec); serves `bench_trigger` from a
SingleThreadedExecutor and answers at once, so its round trip is rclpy's floor between processes.
"""
from __future__ import annotations

import sys

from rclpy.node import Node
from std_srvs.srv import Trigger

from cobot_calib_ros.ros import spin


class TriggerServer(Node):
    """Answers every Trigger request with success."""

    def __init__(self) -> None:
        super().__init__('bench_trigger_server')
        self.create_service(Trigger, 'bench_trigger', self._on_trigger)

    def _on_trigger(self, request, response):
        response.success = True
        return response


def main(args: list[str] | None = None) -> None:
    """Spin the server until SIGINT / SIGTERM."""
    spin.run(TriggerServer, args)


if __name__ == '__main__':
    main(sys.argv)
