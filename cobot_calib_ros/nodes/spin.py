"""The one way a node process runs: init, spin, clean shutdown on Ctrl-C or SIGTERM."""
from __future__ import annotations

from typing import Callable

import rclpy
from rclpy.executors import (ExternalShutdownException, MultiThreadedExecutor,
                             SingleThreadedExecutor)
from rclpy.node import Node


def run(make_node: Callable[[], Node], args=None, threads: int = 1) -> None:
    """Spin the node built by `make_node`; `threads` > 1 uses a MultiThreadedExecutor."""
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        executor = (MultiThreadedExecutor(num_threads=threads) if threads > 1
                    else SingleThreadedExecutor())
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
