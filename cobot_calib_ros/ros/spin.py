"""The one way a node process runs: init, spin, clean shutdown on Ctrl-C or SIGTERM."""
from __future__ import annotations

import sys
import threading
from typing import Callable

import rclpy
from rclpy.executors import (ExternalShutdownException, MultiThreadedExecutor,
                             SingleThreadedExecutor)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.logging import LoggingSeverity
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


class Companion:
    """A hidden helper node with its own single-threaded executor on its own thread.

    rclpy's MultiThreadedExecutor handles well under 100 messages per second on two cores,
    while a SingleThreadedExecutor keeps up with 1 kHz. So every node here spins
    single-threaded, and what must keep running while one of its callbacks blocks (a 1 kHz
    subscription during a capture's hold window, the responses a service waits for) lives on
    a companion: same namespace, remappings and context, name with a leading underscore
    (hidden from node lists). Create subscriptions and clients on ``companion.node``.
    """

    def __init__(self, owner: Node, role: str) -> None:
        self.node = Node(f'_{owner.get_name()}_{role}', namespace=owner.get_namespace(),
                         context=owner.context, start_parameter_services=False)
        self._executor = SingleThreadedExecutor(context=owner.context)
        self._executor.add_node(self.node)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True, name=role)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while self._running and self.node.context.ok():
                self._executor.spin_once(timeout_sec=0.1)
        except Exception:  # noqa: BLE001 - the context was shut down under us
            pass

    def run_action(self, client, goal, accept_timeout: float, result_timeout: float):
        """Send ``goal`` from any thread and block until its result; None if rejected.

        rclpy's ActionClient is not thread-safe: a goal response can arrive on this executor
        before send_goal_async (called from another thread) has registered its sequence
        number, and is then dropped ("Ignoring unexpected goal response") and the call hangs.
        So sending and asking for the result both happen on the companion's own thread.
        """
        sent = wait(self._executor.create_task(client.send_goal_async, goal), accept_timeout)
        handle = wait(sent, accept_timeout)
        if not handle.accepted:
            return None
        asked = wait(self._executor.create_task(handle.get_result_async), accept_timeout)
        return wait(asked, result_timeout).result

    def destroy(self) -> None:
        # Stop the spinning thread before shutting its executor down: Executor.shutdown()
        # destroys the guard condition a concurrent wait may still hold (a segfault at exit).
        self._running = False
        self._thread.join(timeout=5.0)
        if self._thread.is_alive():
            return                      # still blocked: leave the rest to process exit
        self._executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()


def log_info(logger, message: str) -> None:
    """``logger.info(message)`` for hot paths: same output, same /rosout, no filters.

    rclpy's logger finds its caller with inspect.getframeinfo, which scans every loaded module
    (1-3 ms per call here, more than a whole calibration); the caller's frame is enough.
    """
    if not logger.is_enabled_for(LoggingSeverity.INFO):
        return
    caller = sys._getframe(1)
    _rclpy.rclpy_logging_rcutils_log(LoggingSeverity.INFO, logger.name, message,
                                     caller.f_code.co_name, caller.f_code.co_filename,
                                     caller.f_lineno)


def wait(future, timeout: float):
    """Block this thread until ``future`` is done (another executor completes it); its result.

    Raises TimeoutError after ``timeout`` [s].
    """
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout):
        raise TimeoutError(f'no answer within {timeout:.0f} s')
    return future.result()
