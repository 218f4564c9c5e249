"""One rclpy session for a client (a CLI command, a replay check, a bench, a bag maker).

``session(name)`` yields ``(node, executor)``: a node with a single-threaded executor of its
own, on the process's default context (``domain_id`` None: ROS_DOMAIN_ID) or on a private
context for ``domain_id`` (a replay check's own domain beside the caller's), optionally on
sim time. rclpy's signal handlers are not installed (Ctrl-C stays a KeyboardInterrupt the
caller handles). On exit the node is destroyed and its context shut down.

A client writes no log file (``python_<pid>.log`` in the ROS log dir, one per CLI call) unless
asked with ``COBOT_CALIB_CLIENT_LOG=1``: its messages go to the terminal and /rosout.
"""
from __future__ import annotations

from collections.abc import Iterator
import contextlib
import os
import sys

FILE_LOG_ENV = 'COBOT_CALIB_CLIENT_LOG'


def no_log_file_args() -> list[str]:
    """The ROS arguments that keep rcl from writing its log file, unless FILE_LOG_ENV=1."""
    asked = os.environ.get(FILE_LOG_ENV, '') not in ('', '0')
    return [] if asked else ['--disable-external-lib-logs']


def client_ros_args() -> list[str]:
    """rclpy.init's args of a client: the command line's (its --ros-args), and no log file
    unless FILE_LOG_ENV is set."""
    quiet = no_log_file_args()
    return [*sys.argv, *(['--ros-args', *quiet] if quiet else [])]


@contextlib.contextmanager
def session(name: str, *, domain_id: int | None = None, sim_time: bool = False,
            parameter_services: bool = False, namespace: str = '') -> Iterator[tuple]:
    """(node, executor) for one client; see the module doc."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from cobot_calib_ros.ros.spin import destroy
    context = None if domain_id is None else Context()
    rclpy.init(args=client_ros_args(), context=context, domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node(
            name, context=context, start_parameter_services=parameter_services,
            namespace=namespace or None,
            parameter_overrides=[Parameter('use_sim_time', value=True)] if sim_time else [])
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        yield node, executor
    finally:
        if node is not None:
            destroy(node)
        rclpy.try_shutdown(context=context)
