"""Client calls with deadlines: spin until a condition, call a service, run an action goal.

Waits use `call_async` and a `spin_once` loop with a deadline: `spin_until_future_complete`
was measured here to slow down with every call and stall for seconds. A node added to an
executor (ros.session) is spun by that executor unless another is given.
"""
from __future__ import annotations

import contextlib
import time

from action_msgs.msg import GoalStatus
import rclpy
from rclpy.node import Node

from cobot_calib_ros.ros import interrupts
from cobot_calib_ros.ros.action_client import ASK_AGAIN, ActionClient
from cobot_calib_ros.ros.suite_nodes import suite_watch


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



def call_service(node: Node, client, request, timeout: float = 10.0, executor=None,
                 idempotent: bool = False):
    """Call and wait; raises CallError with what to check. ``idempotent``: the request may be
    served twice (a query), so it is sent again every ASK_AGAIN s while unanswered."""
    if not spin_until(node, client.service_is_ready, min(timeout, 10.0), executor):
        raise CallError(f'service {client.srv_name} is not available; is the node suite up '
                        '(cobot-calib up) and ROS_DOMAIN_ID the same?')
    future = first_answer(node, lambda: client.call_async(request), timeout,
                          ASK_AGAIN if idempotent else timeout, executor,
                          forget=client.remove_pending_request)
    if future is None:
        raise CallError(f'service {client.srv_name} did not answer within {timeout:.1f} s')
    return future.result()


def first_answer(node: Node, send, timeout: float, ask_again: float, executor=None,
                 forget=lambda future: None):
    """``send()`` (a future of a request) again every ``ask_again`` [s] until one is answered
    or ``timeout`` [s] has passed: the answered future, or None. ``forget(future)`` is called
    for each one left unanswered."""
    deadline = time.monotonic() + timeout
    sent = []
    try:
        while (remaining := deadline - time.monotonic()) > 0:
            sent.append(send())
            if spin_until(node, lambda: any(f.done() for f in sent), min(ask_again, remaining),
                          executor):
                return next(f for f in sent if f.done())
        return None
    finally:
        for future in sent:
            if not future.done():
                forget(future)


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
    Interrupted. A server node that exits meanwhile (the suite's launcher says so on
    ros.suite_nodes' topic), leaves the graph, or is replaced by a new instance that does not
    know the goal (a restarted node) ends the wait (ServerWatch)."""
    if not spin_until(node, client.server_is_ready, min(timeout, 10.0), executor):
        raise CallError(f'action {client._action_name} is not available; '
                        'is the node suite up (cobot-calib up)?')
    suite_watch(node)       # subscribed before the goal: the launcher's news reaches it early
    sent = time.time()
    send = client.send_goal_async(goal, feedback_callback=feedback)
    watch = None
    try:
        if not spin_until(node, send.done, 10.0, executor):
            raise CallError(f'action {client._action_name} did not accept the goal in time')
        handle = send.result()
        if not handle.accepted:
            raise CallError(f'action {client._action_name} rejected the goal (busy?)')
        watch = ServerWatch(node, client, sent)
        result = ResultWait(handle)
        deadline = time.monotonic() + timeout
        while not spin_until(node, result.done, min(WATCH_PERIOD, deadline - time.monotonic()),
                             executor):
            result.ask_again_if_ended()
            ended = watch.ended()
            if ended:
                raise CallError(ended)
            if time.monotonic() >= deadline:
                handle.cancel_goal_async()
                raise CallError(f'action {client._action_name} did not finish within '
                                f'{timeout:.0f} s')
        if result.lost():
            raise CallError(watch.lost_line())
    except KeyboardInterrupt:
        raise _cancelled(node, client, send, executor, watch) from None
    return result.result().status, result.result().result


WATCH_PERIOD = 0.25       # [s] between two looks at the graph while a goal runs


class ResultWait:
    """A goal's result, asked for again when the server's status says the goal ended and
    its answer has not come WATCH_PERIOD s later: the answer to the first request was lost
    where the status got through (a node stopped by Ctrl-C during a collection; it answers
    for spin.RESULT_LINGER s more). Asking again is safe: a server answers each result
    request of a goal with the same result."""

    ASKS = 4          # result requests at most (the first included)

    def __init__(self, handle) -> None:
        self._handle = handle
        self._futures = [handle.get_result_async()]
        self._ended_at = None     # time.monotonic() when the status said the goal ended

    def done(self) -> bool:
        return any(f.done() for f in self._futures)

    def result(self):
        return next(f for f in self._futures if f.done()).result()

    def lost(self) -> bool:
        """The answer says the server does not know the goal (STATUS_UNKNOWN, a default
        result, error code 0 included): a restarted server answered the result request, or
        one that kept the result less long than the wait. The goal is lost, not done."""
        return self.result().status == GoalStatus.STATUS_UNKNOWN

    def wait(self, node: Node, timeout: float, executor=None) -> bool:
        """Spin until the result came or ``timeout`` [s] passed; whether it came."""
        deadline = time.monotonic() + timeout
        while not spin_until(node, self.done, min(WATCH_PERIOD, deadline - time.monotonic()),
                             executor):
            if time.monotonic() >= deadline:
                return False
            self.ask_again_if_ended()
        return True

    def ask_again_if_ended(self) -> None:
        if self._handle.status not in ENDED or len(self._futures) >= self.ASKS:
            return
        now = time.monotonic()
        if self._ended_at is None:
            self._ended_at = now
        elif now - self._ended_at >= WATCH_PERIOD * len(self._futures):
            self._futures.append(self._handle.get_result_async())


ENDED = (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED)
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'    # rmw's node name of an endpoint before its node's info


def run_action_once(node: Node, action_type, name: str, goal, timeout: float = 60.0,
                    feedback=None, executor=None):
    """:func:`run_action` of ``goal`` on action ``name`` through a client made for this one
    goal (and destroyed after it); the result."""
    client = ActionClient(node, action_type, name)
    try:
        return run_action(node, client, goal, timeout, feedback, executor)[1]
    finally:
        client.destroy()


class ServerWatch:
    """Whether the action server instance that accepted a goal still serves it, for a client
    waiting on that goal.

    First the suite's launcher (ros.suite_nodes): `cobot-calib up` says on its latched topic
    when a node process it started exits, within its watch period; a node that exited after
    the goal was sent lost the goal. Without that news (a node `up` did not start, a real
    robot's driver) the graph: the instance is known by the graph ids (GIDs) of its status
    publisher, taken when the watch starts (right after the goal was accepted). A new instance
    of the same node serving the action means the node restarted and the goal was lost with
    the old one (a new server never knows an old one's goals). A node that exits cleanly leaves
    the graph at once; a killed one only when DDS's participant lease runs out (Fast DDS: 20
    s). Once the instance has been out of the graph for GONE_AFTER s, ended() says so.
    """

    GONE_AFTER = 3.0      # [s] unseen before the server counts as gone

    def __init__(self, node: Node, client: ActionClient, sent: float | None = None) -> None:
        """``sent``: when the goal was sent (time.time()); default now."""
        self._node, self._client, self.action = node, client, client._action_name
        self._sent = time.time() if sent is None else sent
        self._suite = suite_watch(node)
        self._status_topic = _resolved(node, self.action) + '/_action/status'
        self._name = self._full_name = ''
        self._accepted = self._servers()
        self._seen = time.monotonic()

    def _servers(self) -> dict[tuple, str]:
        """The action's server instances on the graph now: GID -> full node name ('' while
        DDS has not told it yet)."""
        with contextlib.suppress(Exception):      # a graph query during shutdown
            servers = {tuple(info.endpoint_gid): ('' if info.node_name == UNKNOWN_NODE else
                                                  _full_name(info.node_namespace,
                                                             info.node_name))
                       for info in self._node.get_publishers_info_by_topic(
                           self._status_topic)}
            if not self._full_name:
                self._full_name = next(filter(None, servers.values()), '')
                self._name = self._full_name.rsplit('/', 1)[-1]
            return servers
        return {}

    @property
    def server_node(self) -> str:
        """The name of the node serving the action (the first one the graph named)."""
        if not self._name:
            self._servers()
        return self._name or action_server_node(self._node, self.action) or 'server'

    def ended(self) -> str:
        """'' while the accepting instance serves the goal (or is out of the graph under
        GONE_AFTER s); else why the goal will not end: the node exited or restarted (goal
        lost), or it is gone."""
        now = time.monotonic()
        servers = self._servers()
        exited = self._suite.exit_since(self._full_name, self._sent) if self._full_name \
            else None
        if exited is not None:
            return self.exited_line(exited)
        if self._replaced(servers):
            return self.lost_line()
        there = (self._accepted.keys() & servers.keys()) if self._accepted \
            else self._client.server_is_ready()
        if there:
            self._seen = now
            return ''
        if now - self._seen <= self.GONE_AFTER:
            return ''
        return self.lost_line() if servers else self.gone_line()

    def _replaced(self, servers: dict[tuple, str]) -> bool:
        """A new instance of the one node that served the action when the goal was accepted
        serves it now: that node restarted (two of one name do not serve one action)."""
        if len(self._accepted) != 1 or not self._full_name:
            return False
        return any(gid not in self._accepted and name == self._full_name
                   for gid, name in servers.items())

    def restarted(self) -> bool:
        """The node exited after the goal was sent (the launcher says), or another instance
        serves the action and the accepting one is out of the graph or replaced."""
        servers = self._servers()
        if self._full_name and self._suite.exit_since(self._full_name, self._sent):
            return True
        return self._replaced(servers) or bool(
            self._accepted and servers and not self._accepted.keys() & servers.keys())

    def exited_line(self, exited) -> str:
        """What the launcher's news means for the goal: ``exited`` a ros.suite_nodes
        NodeProcess."""
        after = max(0.0, exited.exited - self._sent)
        how = f'{exited.how_it_ended()} {after:.1f} s after the goal was sent'
        if exited.left_down:
            return (f'the {self.server_node} node is gone ({how}; cobot-calib up left it down '
                    f'after repeated quick exits): the {self.action} goal is lost; its log in '
                    '~/.ros/log says why it ended')
        return (f'the {self.server_node} node restarted: goal lost ({how}; cobot-calib up '
                f'starts it again, and the new {self.server_node} does not know the '
                f'{self.action} goal; its log in ~/.ros/log says why the old one ended)')

    def gone_line(self) -> str:
        return (f'the {self.server_node} node is gone ({self.action} unavailable for '
                f'{self.GONE_AFTER:.0f} s): restart it (cobot-calib up starts the suite; its '
                'log is in ~/.ros/log)')

    def lost_line(self) -> str:
        return (f'the {self.server_node} node restarted: goal lost (the new {self.server_node} '
                f'does not know the {self.action} goal of the one that accepted it; its log '
                'in ~/.ros/log says why the old one ended)')


def _full_name(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}'


def _resolved(node: Node, action: str) -> str:
    """``action``'s full name as this node resolves it (namespace, remappings)."""
    try:
        return node.resolve_topic_name(action)
    except Exception:       # noqa: BLE001 - an invalid name: as given, in the root namespace
        return '/' + action.lstrip('/')


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


def _cancelled(node: Node, client: ActionClient, send, executor,
               watch: ServerWatch | None = None) -> Interrupted:
    """After a Ctrl-C: cancel the goal sent by ``send`` and wait for its end (CANCEL_WAIT).
    ``watch``: the ServerWatch of the accepted goal, to say when its server restarted."""
    name = client._action_name
    if not spin_until(node, send.done, CANCEL_WAIT, executor) or not send.result().accepted:
        return Interrupted(f'{name}: interrupted before the goal was accepted')
    handle = send.result()
    cancel, result = handle.cancel_goal_async(), ResultWait(handle)
    if not result.wait(node, CANCEL_WAIT, executor):
        if watch is not None and watch.restarted():
            return Interrupted(watch.lost_line())
        answered = cancel.done() and bool(cancel.result().goals_canceling)
        return Interrupted(f'{name}: cancel {"accepted" if answered else "not answered"} but '
                           f'the goal did not end within {CANCEL_WAIT:.0f} s; it may still '
                           'complete (see the node log)')
    status, done = result.result().status, result.result().result
    message = getattr(done, 'message', '') or ''
    if result.lost():
        return Interrupted(watch.lost_line() if watch is not None else
                           f'{name}: the server does not know the goal (restarted?): goal '
                           'lost', None)
    if status == GoalStatus.STATUS_CANCELED:
        return Interrupted(message or f'{name}: cancelled', done)
    words = {GoalStatus.STATUS_SUCCEEDED: 'it succeeded',
             GoalStatus.STATUS_ABORTED: 'aborted without a message'}
    return Interrupted(f'{name}: ended before the cancel came: '
                       f'{message or words.get(status, f"status {status}")}', done)
