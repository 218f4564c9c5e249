"""Client calls with deadlines: spin until a condition, call a service, run an action goal.

Waits use `call_async` and a `spin_once` loop with a deadline: `spin_until_future_complete`
was measured here to slow down with every call and stall for seconds. A node added to an
executor (ros.session) is spun by that executor unless another is given.
"""
from __future__ import annotations

import contextlib
import time

import rclpy
from rclpy.action import ActionClient
from rclpy.node import Node

from cobot_calib_ros.ros import interrupts


class CallError(RuntimeError):
    """A call that did not complete: not available, timed out, refused."""


def spin_until(node: Node, done, timeout: float, executor=None) -> bool:
    """Spin `node` until done() or the timeout [s]; returns done(). ``executor``: the one to
    spin; by default the executor the node was added to (ros.session), else rclpy's global one.
    A Ctrl-C noted by ros.interrupts.deferred() is raised here, between two spins
    (KeyboardInterrupt)."""
    if executor is None:
        executor = node.executor
    deadline = time.monotonic() + timeout
    while not done():
        interrupts.check()
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        if executor is not None:
            executor.spin_once(timeout_sec=min(0.05, remaining))
        else:
            rclpy.spin_once(node, timeout_sec=min(0.05, remaining))
    return True


def call_service(node: Node, client, request, timeout: float = 10.0, executor=None):
    """Call and wait; raises CallError with what to check."""
    if not spin_until(node, client.service_is_ready, min(timeout, 10.0), executor):
        raise CallError(f'service {client.srv_name} is not available; is the node suite up '
                        '(cobot-calib up) and ROS_DOMAIN_ID the same?')
    future = client.call_async(request)
    if not spin_until(node, future.done, timeout, executor):
        client.remove_pending_request(future)
        raise CallError(f'service {client.srv_name} did not answer within {timeout:.1f} s')
    return future.result()


CANCEL_WAIT = 10.0        # [s] after a Ctrl-C, for the goal to end (servers stop between steps)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C while an action ran: its goal was cancelled. ``message`` says how it ended (the
    server's message when it answered within CANCEL_WAIT), ``result`` is its result or None."""

    def __init__(self, message: str, result=None) -> None:
        super().__init__(message)
        self.message, self.result = message, result


def run_action(node: Node, client: ActionClient, goal, timeout: float = 60.0,
               feedback=None, executor=None):
    """Send a goal, wait for its result; returns (status, result). Ctrl-C (KeyboardInterrupt)
    while it runs cancels the goal, waits up to CANCEL_WAIT s for it to end and raises
    Interrupted. A server that leaves the graph meanwhile ends the wait (ServerWatch)."""
    if not spin_until(node, client.server_is_ready, min(timeout, 10.0), executor):
        raise CallError(f'action {client._action_name} is not available; '
                        'is the node suite up (cobot-calib up)?')
    send = client.send_goal_async(goal, feedback_callback=feedback)
    try:
        if not spin_until(node, send.done, 10.0, executor):
            raise CallError(f'action {client._action_name} did not accept the goal in time')
        handle = send.result()
        if not handle.accepted:
            raise CallError(f'action {client._action_name} rejected the goal (busy?)')
        result = handle.get_result_async()
        watch = ServerWatch(node, client)
        deadline = time.monotonic() + timeout
        while not spin_until(node, result.done, min(WATCH_PERIOD, deadline - time.monotonic()),
                             executor):
            if watch.gone():
                raise CallError(watch.gone_line())
            if time.monotonic() >= deadline:
                handle.cancel_goal_async()
                raise CallError(f'action {client._action_name} did not finish within '
                                f'{timeout:.0f} s')
    except KeyboardInterrupt:
        raise _cancelled(node, client, send, executor) from None
    return result.result().status, result.result().result


WATCH_PERIOD = 0.25       # [s] between two looks at the graph while a goal runs


class ServerWatch:
    """Whether an action's server is still on the graph, for a client waiting on a goal.

    A node that exits cleanly leaves the graph at once; a killed one (kill -9, a crash) only
    when DDS's participant lease runs out (Fast DDS: 20 s). The server counts as gone once it
    has been out of the graph for GONE_AFTER s; gone_line() names its node (found on the graph
    when the watch starts) and says how to go on.
    """

    GONE_AFTER = 3.0      # [s] unseen before the server counts as gone

    def __init__(self, node: Node, client: ActionClient) -> None:
        self._client, self.action = client, client._action_name
        self.server_node = action_server_node(node, self.action) or 'server'
        self._seen = time.monotonic()

    def gone(self) -> bool:
        now = time.monotonic()
        if self._client.server_is_ready():
            self._seen = now
        return now - self._seen > self.GONE_AFTER

    def gone_line(self) -> str:
        return (f'the {self.server_node} node is gone ({self.action} unavailable for '
                f'{self.GONE_AFTER:.0f} s): restart it (cobot-calib up starts the suite; its '
                'log is in ~/.ros/log)')


def action_server_node(node: Node, action: str) -> str:
    """The name of the node that serves ``action`` (a relative name: in the root namespace,
    as the CLI's nodes resolve it) on the graph now, '' if none."""
    from rclpy.action.graph import get_action_server_names_and_types_by_node
    wanted = '/' + action.lstrip('/')
    for name, namespace in node.get_node_names_and_namespaces():
        with contextlib.suppress(Exception):      # a node that left meanwhile
            served = get_action_server_names_and_types_by_node(node, name, namespace)
            if any(n == wanted for n, _ in served):
                return name
    return ''


def _cancelled(node: Node, client: ActionClient, send, executor) -> Interrupted:
    """After a Ctrl-C: cancel the goal sent by ``send`` and wait for its end (CANCEL_WAIT)."""
    from action_msgs.msg import GoalStatus
    name = client._action_name
    if not spin_until(node, send.done, CANCEL_WAIT, executor) or not send.result().accepted:
        return Interrupted(f'{name}: interrupted before the goal was accepted')
    handle = send.result()
    cancel, result = handle.cancel_goal_async(), handle.get_result_async()
    if not spin_until(node, result.done, CANCEL_WAIT, executor):
        answered = cancel.done() and bool(cancel.result().goals_canceling)
        return Interrupted(f'{name}: cancel {"accepted" if answered else "not answered"} but '
                           f'the goal did not end within {CANCEL_WAIT:.0f} s; it may still '
                           'complete (see the node log)')
    status, done = result.result().status, result.result().result
    message = getattr(done, 'message', '') or ''
    if status == GoalStatus.STATUS_CANCELED:
        return Interrupted(message or f'{name}: cancelled', done)
    return Interrupted(f'{name}: ended before the cancel came: {message}', done)
