"""Client side of the suite: graph queries, message <-> dict, service and action calls.

Used by the CLI, the demo, the benches and the tests. Waits use `call_async` and a
`spin_once` loop with a deadline: `spin_until_future_complete` was measured here to slow
down with every call and stall for seconds.
"""
from __future__ import annotations

import array
import contextlib
import importlib
import math
import os
import time
from typing import Any

import numpy as np
import rclpy
from rclpy.action import ActionClient
from rclpy.action.graph import get_action_names_and_types
from rclpy.node import Node


class CallError(RuntimeError):
    """A call that did not complete: not available, timed out, refused."""


def import_type(type_name: str):
    """'sensor_msgs/msg/JointState' (or 'sensor_msgs/JointState') -> the Python class."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3:
        raise ValueError(f'not a ROS type name: {type_name!r}')
    module = importlib.import_module(f'{parts[0]}.{parts[1]}')
    return getattr(module, parts[2])


def to_dict(msg: Any) -> Any:
    """A ROS message (or field value) as plain Python data, in field order."""
    if hasattr(msg, 'get_fields_and_field_types'):
        return {f: to_dict(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple, array.array, np.ndarray)):
        return [to_dict(v) for v in msg]
    if isinstance(msg, (bytes, bytearray)):
        return list(msg)
    if isinstance(msg, np.generic):
        return msg.item()
    return msg


def set_fields(msg: Any, values: dict) -> Any:
    """Fill a message from a dict (as `ros2 service call` does with its YAML argument)."""
    if not isinstance(values, dict):
        raise ValueError(f'expected a mapping for {type(msg).__name__}, got {values!r}')
    fields = msg.get_fields_and_field_types()
    for key, value in values.items():
        if key not in fields:
            raise ValueError(f'{type(msg).__name__} has no field {key!r}; fields: {list(fields)}')
        current = getattr(msg, key)
        if hasattr(current, 'get_fields_and_field_types'):
            set_fields(current, value)
        elif isinstance(value, list) and fields[key].startswith('sequence<') and '/' in fields[key]:
            item_type = import_type(fields[key][len('sequence<'):-1].split(',')[0])
            setattr(msg, key, [set_fields(item_type(), v) for v in value])
        else:
            setattr(msg, key, value)
    return msg


def spin_until(node: Node, done, timeout: float, executor=None) -> bool:
    """Spin `node` until done() or the timeout [s]; returns done()."""
    deadline = time.monotonic() + timeout
    while not done():
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


def run_action(node: Node, client: ActionClient, goal, timeout: float = 60.0,
               feedback=None, executor=None):
    """Send a goal, wait for its result; returns (status, result)."""
    if not spin_until(node, client.server_is_ready, min(timeout, 10.0), executor):
        raise CallError(f'action {client._action_name} is not available; '
                        'is the node suite up (cobot-calib up)?')
    send = client.send_goal_async(goal, feedback_callback=feedback)
    if not spin_until(node, send.done, 10.0, executor):
        raise CallError(f'action {client._action_name} did not accept the goal in time')
    handle = send.result()
    if not handle.accepted:
        raise CallError(f'action {client._action_name} rejected the goal (busy?)')
    result = handle.get_result_async()
    if not spin_until(node, result.done, timeout, executor):
        handle.cancel_goal_async()
        raise CallError(f'action {client._action_name} did not finish within {timeout:.0f} s')
    return result.result().status, result.result().result


def graph(node: Node, wait: float = 1.0) -> dict[str, dict[str, list[str]]]:
    """Nodes, topics, services and actions with their types, after `wait` s of discovery."""
    spin_until(node, lambda: False, wait)
    hidden = ('/_action/', '/rosout', '/parameter_events')
    own = node.get_fully_qualified_name()
    nodes = sorted(f'{ns.rstrip("/")}/{n}' for n, ns in node.get_node_names_and_namespaces()
                   if not n.startswith('_'))      # hidden nodes, as ros2 node list does
    topics = {n: t for n, t in node.get_topic_names_and_types()
              if not any(h in n for h in hidden)}
    services = {n: t for n, t in node.get_service_names_and_types()
                if '/_action/' not in n and not n.rsplit('/', 1)[-1].endswith(
                    ('_parameters', '_parameter_types', 'describe_parameters',
                     'get_type_description'))
                and not n.startswith(own + '/')}
    actions = dict(get_action_names_and_types(node))
    return {'nodes': {n: [] for n in nodes if n != own}, 'topics': topics,
            'services': services, 'actions': actions}


def finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def wait_for_suite(node: Node, timeout: float = 60.0, executor=None) -> None:
    """Until joint_states and probe readings flow (a short capture and a probe average work)."""
    from cobot_calib_msgs.srv import AverageProximity, CaptureJoints
    checks = [(CaptureJoints, 'capture_joints', CaptureJoints.Response.NO_DATA),
              (AverageProximity, 'probe/average', AverageProximity.Response.NO_DATA)]
    deadline = time.monotonic() + timeout
    for srv_type, name, no_data in checks:
        client = node.create_client(srv_type, name)
        try:
            while not _flows(node, client, no_data, executor):
                if time.monotonic() > deadline:
                    raise CallError(f'{name} had no data within {timeout:.0f} s; is the node '
                                    f'suite up (ROS_DOMAIN_ID='
                                    f'{os.environ.get("ROS_DOMAIN_ID", "0")})?')
        finally:
            node.destroy_client(client)


def _flows(node: Node, client, no_data: int, executor) -> bool:
    with contextlib.suppress(CallError):
        response = call_service(node, client, client.srv_type.Request(duration=0.1), 10.0,
                                executor)
        return response.error_code not in (no_data, getattr(response, 'BAD_REQUEST', -1))
    return False
