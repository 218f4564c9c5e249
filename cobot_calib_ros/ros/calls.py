"""Client calls with deadlines: spin until a condition, call a service, run an action goal.

Waits use `call_async` and a `spin_once` loop with a deadline: `spin_until_future_complete`
was measured here to slow down with every call and stall for seconds. A node added to an
executor (ros.session) is spun by that executor unless another is given.
"""
from __future__ import annotations

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
    Interrupted."""
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
        if not spin_until(node, result.done, timeout, executor):
            handle.cancel_goal_async()
            raise CallError(f'action {client._action_name} did not finish within '
                            f'{timeout:.0f} s')
    except KeyboardInterrupt:
        raise _cancelled(node, client, send, executor) from None
    return result.result().status, result.result().result


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
