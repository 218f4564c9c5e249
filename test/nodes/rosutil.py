"""Calls the node tests make from their client node (`ros` fixture) or through the CLI."""
import os
import subprocess
import sys

from cobot_calib_ros.ros.calls import call_service, spin_until
from machine import STARTUP_TIMEOUT, STOP_TIMEOUT  # noqa: F401 - node tests import them here


# Requests that may be served twice: asked again while unanswered, as the product's own
# clients ask them (ros.calls.call_service). A fresh client's first answer can be dropped by
# a server that has not matched its reply reader yet: get_ground_truth went unanswered for
# 10 s in a fresh-clone run at load 15.
QUERIES = ('GetGroundTruth', 'ListCalibrations', 'CaptureJoints', 'ConvertPoints',
           'AverageProximity', 'GetParameters')


# The other requests are not sent again, and a fresh client's first one lost its answer the
# same way (fresh-clone run Y, load ~10: a calibrate_user_frame refusal, the server's log saying
# "failed to send response (timeout): client will not receive response"). So a test node keeps
# one client per service, matched once, and a new one waits NEW_CLIENT_SETTLE s after its
# server shows, for the server's side of the match, before its first request (a query's first
# request goes at once: a lost answer costs it one re-send).
NEW_CLIENT_SETTLE = 1.0     # [s]


def call(node, srv_type, name, timeout=10.0, ready_timeout=0.0, resend=None, **fields):
    """One service call with the request fields given; the response. ``ready_timeout`` [s]: a
    longer wait for the service to appear than call_service's 10 s (a node process a test just
    started: 10 s was not enough at load 15; STARTUP_TIMEOUT). ``resend``: ask again while
    unanswered (default: for QUERIES); False for a query whose answer is known to take long
    (each copy is served in turn, and a node stopping after it first serves the copies)."""
    resend = srv_type.__name__ in QUERIES if resend is None else resend
    client = _client(node, srv_type, name)
    spin_until(node, client.service_is_ready, max(ready_timeout, min(timeout, 10.0)),
               node.executor_for_tests)
    settled = node.__dict__.setdefault('_rosutil_settled', set())
    if not resend and (srv_type, name) not in settled and client.service_is_ready():
        spin_until(node, lambda: False, NEW_CLIENT_SETTLE, node.executor_for_tests)
        settled.add((srv_type, name))
    return call_service(node, client, srv_type.Request(**fields), timeout,
                        node.executor_for_tests, idempotent=resend)


def set_parameter(node, target: str, name: str, value: str | float):
    """SetParameters on node ``target`` (a string or a double value); its SetParametersResult."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    param = Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                      string_value=value)
                      if isinstance(value, str) else
                      ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))
    return call(node, SetParameters, f'{target}/set_parameters', parameters=[param]).results[0]


def _client(node, srv_type, name):
    """The test node's client of service ``name`` (made at the first call)."""
    clients = node.__dict__.setdefault('_rosutil_clients', {})
    if (srv_type, name) not in clients:
        clients[srv_type, name] = node.create_client(srv_type, name)
    return clients[srv_type, name]


def true_gap(truth, positions, point: str) -> float:
    """[m] of the real tool tip above ``point``'s true top face, along the user frame's z, at
    the joints ``positions``: the mock's ground truth (GetGroundTruth: its true arm and true
    tool), up to its repeatability (18 um per axis on the Sawyer cell)."""
    import numpy as np
    from cobot_calib_ros.core.kinematics import fk, model_by_name
    from cobot_calib_ros.ros import convert
    chain = model_by_name(truth.robot).chain(
        np.array(truth.true_parameters), tool=convert.transform_to_matrix(truth.t_flange_tool_true))
    tip = fk(chain, np.array(positions, dtype=float))[:3, 3]
    top = convert.points_to_array(truth.points_base)[truth.point_names.index(point)]
    return float((tip - top) @ convert.transform_to_matrix(truth.user_frame)[:3, 2])


def listen_late(node, msg_type, topic, profile, done, timeout=10.0) -> list:
    """The messages a new (late-joining) subscriber got until done(messages) or the timeout."""
    got = []
    sub = node.create_subscription(msg_type, topic, got.append, profile)
    try:
        spin_until(node, lambda: done(got), timeout, node.executor_for_tests)
    finally:
        node.destroy_subscription(sub)
    return got


def cli_command(*args) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


def cli(*args, timeout=STARTUP_TIMEOUT) -> subprocess.CompletedProcess:
    """Run `cobot-calib ARGS` on the session's domain; its completed process (a cold start of
    the interpreter and rclpy is part of ``timeout``)."""
    return subprocess.run(cli_command(*args), capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ))


ACTIVE_GOAL = (1, 2, 3)     # action_msgs/GoalStatus ACCEPTED, EXECUTING, CANCELING


def wait_goals_ended(node, action: str, timeout: float = 30.0) -> bool:
    """Until the action server's status lists no goal that is still accepted, executing or
    canceling (what it latches on <action>/_action/status); True if so within ``timeout``."""
    from action_msgs.msg import GoalStatusArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    latest = []

    def keep(msg) -> None:
        latest[:] = [msg]
    profile = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    sub = node.create_subscription(GoalStatusArray, f'{action}/_action/status', keep, profile)
    try:
        return spin_until(node, lambda: bool(latest) and not any(
            s.status in ACTIVE_GOAL for s in latest[0].status_list), timeout,
            node.executor_for_tests)
    finally:
        node.destroy_subscription(sub)


def wait_subscribed(node, topic: str, subscriber: str, timeout: float = 30.0) -> bool:
    """Until node ``subscriber`` (a name) has a subscription on ``topic`` in the graph."""
    return spin_until(node, lambda: any(
        info.node_name == subscriber for info in node.get_subscriptions_info_by_topic(topic)),
        timeout, node.executor_for_tests)

