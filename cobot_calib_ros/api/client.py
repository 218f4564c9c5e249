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
import re
import time
from typing import Any

import numpy as np
import rclpy
from rclpy.action import ActionClient
from rclpy.action.graph import get_action_names_and_types
from rclpy.node import Node

from cobot_calib_ros.ros import interrupts


class CallError(RuntimeError):
    """A call that did not complete: not available, timed out, refused."""


def import_type(type_name: str):
    """'sensor_msgs/msg/JointState' (or 'sensor_msgs/JointState') -> the Python class;
    ValueError with what is missing if it is not installed here."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'not a ROS type name: {type_name!r} (like pkg/msg/Name)')
    try:
        module = importlib.import_module(f'{parts[0]}.{parts[1]}')
    except ImportError:
        raise ValueError(f'unknown type {type_name!r}: no interface package {parts[0]!r} '
                         f'with {parts[1]}/ here') from None
    if not hasattr(module, parts[2]):
        raise ValueError(f'unknown type {type_name!r}: {parts[0]}/{parts[1]} has no '
                         f'{parts[2]!r}')
    return getattr(module, parts[2])


def service_type_name(type_name: str) -> str:
    """'pkg/Name' or 'pkg/srv/Name' -> 'pkg/srv/Name' (as the graph lists services)."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'srv', parts[1]]
    if len(parts) != 3 or parts[1] != 'srv' or not all(parts):
        raise ValueError(f'not a service type name: {type_name!r} (like pkg/srv/Name)')
    return '/'.join(parts)


def import_service(type_name: str):
    """The service class of 'pkg/srv/Name' (or 'pkg/Name'); ValueError if not one."""
    srv = import_type(service_type_name(type_name))
    if not hasattr(srv, 'Request'):
        raise ValueError(f'{type_name} is not a service type')
    return srv


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


class FieldError(ValueError):
    """A request value that does not fit its field; str() names the field path."""


def set_fields(msg: Any, values: Any) -> Any:
    """Fill a message from YAML data as `ros2 service call` does, converting each value to its
    field's type first (int -> float, 'nan' / '1e9' -> float, nested messages, sequences)
    so nothing unfit reaches the C setters; raises FieldError naming the field path."""
    return _fill(msg, {} if values is None else values, '')


def _fill(msg: Any, values: Any, path: str) -> Any:
    if not isinstance(values, dict):
        raise FieldError(f'{path or "request"}: expected a mapping of {_type_label(msg)} '
                         f'fields like {{{next(iter(_slots(msg)), "field")}: ...}}, '
                         f'got {_shown(values)}')
    slots = _slots(msg)
    for key, value in values.items():
        where = f'{path}.{key}' if path else str(key)
        if key not in slots:
            raise FieldError(f'{where}: no such field; {_type_label(msg)} has: '
                             f'{", ".join(slots) or "no fields"}')
        setattr(msg, key, _convert(slots[key], value, where))
    return msg


def _slots(msg: Any) -> dict:
    """Field name -> rosidl_parser.definition type, in field order."""
    return dict(zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES))


def _type_label(msg: Any) -> str:
    return type(msg).__name__.replace('_Request', ' request').replace('_Response', ' response')


def _convert(slot, value: Any, path: str) -> Any:
    from rosidl_parser import definition as d
    if isinstance(slot, d.NamespacedType):
        return _fill(_message_class(slot)(), value, path)
    if isinstance(slot, d.AbstractNestedType):
        return _sequence(slot, value, path)
    if isinstance(slot, d.AbstractGenericString):
        return _string(slot, value, path)
    if isinstance(slot, d.BasicType):
        return _basic(slot.typename, value, path)
    raise FieldError(f'{path}: unsupported field type {type(slot).__name__}')


def _message_class(slot):
    module = importlib.import_module('.'.join(slot.namespaces))
    return getattr(module, slot.name)


def _sequence(slot, value: Any, path: str) -> list:
    from rosidl_parser import definition as d
    if isinstance(value, (bytes, bytearray)) and getattr(slot.value_type, 'typename', '') in (
            'octet', 'uint8'):
        value = list(value)
    if not isinstance(value, (list, tuple)):
        raise FieldError(f'{path}: expected a list like [1, 2], got {_shown(value)}')
    if isinstance(slot, d.Array) and len(value) != slot.size:
        raise FieldError(f'{path}: expected exactly {slot.size} values, got {len(value)}')
    if isinstance(slot, d.BoundedSequence) and len(value) > slot.maximum_size:
        raise FieldError(f'{path}: expected at most {slot.maximum_size} values, '
                         f'got {len(value)}')
    return [_convert(slot.value_type, v, f'{path}[{i}]') for i, v in enumerate(value)]


def _string(slot, value: Any, path: str) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)                  # as ros2 does: `id: 20261121` is the string
    if not isinstance(value, str):
        raise FieldError(f'{path}: expected a string, got {_shown(value)}')
    limit = getattr(slot, 'maximum_size', None)
    if limit is not None and len(value) > limit:
        raise FieldError(f'{path}: expected at most {limit} characters, got {len(value)}')
    return value


_INT_BITS = {'int8': (8, True), 'int16': (16, True), 'int32': (32, True), 'int64': (64, True),
             'uint8': (8, False), 'uint16': (16, False), 'uint32': (32, False),
             'uint64': (64, False), 'short': (16, True), 'long': (32, True),
             'long long': (64, True), 'unsigned short': (16, False),
             'unsigned long': (32, False), 'unsigned long long': (64, False)}
_FLOAT32_MAX = 3.4028234663852886e38
_TRUE, _FALSE = ('true', 'yes', 'on'), ('false', 'no', 'off')


def _basic(typename: str, value: Any, path: str) -> Any:
    if typename in ('float', 'double', 'long double'):
        return _float(typename, value, path)
    if typename in _INT_BITS:
        return _int(typename, value, path)
    if typename == 'boolean':
        return _bool(value, path)
    if typename == 'octet':
        return bytes([_int('uint8', value, path)])
    if typename in ('char', 'wchar'):
        if isinstance(value, str) and len(value) == 1:
            return value
        raise FieldError(f'{path}: expected one character, got {_shown(value)}')
    raise FieldError(f'{path}: unsupported field type {typename}')


def _float(typename: str, value: Any, path: str) -> float:
    number = _parse_float(value)
    if number is None:
        raise FieldError(f'{path}: expected a float, got {_shown(value)}')
    if typename == 'float' and math.isfinite(number) and abs(number) > _FLOAT32_MAX:
        raise FieldError(f'{path}: expected a float32 within +-3.4e38, got {_shown(value)}')
    return number


def _parse_float(value: Any) -> float | None:
    """int, float, or a YAML string PyYAML leaves alone: 'nan', '.inf', '1e9'."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        try:
            return float(value)
        except OverflowError:
            return None
    if not isinstance(value, str):
        return None
    text = re.sub(r'^([+-]?)\.(nan|inf)$', r'\1\2', value.strip().lower())   # YAML .nan
    try:
        return float(text)
    except ValueError:
        return None


def _int(typename: str, value: Any, path: str) -> int:
    bits, signed = _INT_BITS[typename]
    low, high = (-2 ** (bits - 1), 2 ** (bits - 1) - 1) if signed else (0, 2 ** bits - 1)
    number = _parse_int(value)
    if number is None:
        raise FieldError(f'{path}: expected an integer, got {_shown(value)}')
    if not low <= number <= high:
        raise FieldError(f'{path}: expected a {typename} in [{low}, {high}], got {number}')
    return number


def _parse_int(value: Any) -> int | None:
    """int, a whole float (2.0, 1e3) or such a string."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, str) and re.fullmatch(r'\s*[+-]?\d+\s*', value):
        return int(value)                               # exact, even beyond 2**53
    number = _parse_float(value)
    if number is None or not math.isfinite(number) or not number.is_integer():
        return None
    return int(number)


def _bool(value: Any, path: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in _TRUE + _FALSE:
        return value.strip().lower() in _TRUE
    raise FieldError(f'{path}: expected true or false, got {_shown(value)}')


def _shown(value: Any) -> str:
    """A value as the user typed it (YAML-ish), short."""
    text = 'null' if value is None else repr(value)
    return text if len(text) <= 40 else text[:37] + '...'


def spin_until(node: Node, done, timeout: float, executor=None) -> bool:
    """Spin `node` until done() or the timeout [s]; returns done(). A Ctrl-C noted by
    ros.interrupts.deferred() is raised here, between two spins (KeyboardInterrupt)."""
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


GRAPH_POLL = 0.1          # [s] between graph snapshots
GRAPH_SETTLE = 0.5        # [s] unchanged graph that ends a discovery wait
# Fast DDS finds most remote nodes within 0.1 s, but often one or two only when their next
# periodic discovery traffic comes (every 3 s): measured here (2 CPUs under load), the last
# suite node showed up as late as 3.5 s after start, after gaps of up to 2.4 s with no change
# at all, so "unchanged for a while" alone ends too early. Wait this long at least (4 s missed
# nodes of the 9-process suite when three `list` ran at once).
DISCOVERY_MIN_WAIT = 6.0  # [s]
_PARAMETER_SERVICES = ('_parameters', '_parameter_types', 'describe_parameters',
                       'set_parameters_atomically', 'get_type_description')


def graph(node: Node, max_wait: float = 10.0, min_wait: float = DISCOVERY_MIN_WAIT,
          settle: float = GRAPH_SETTLE, done=None) -> dict[str, dict[str, list[str]]]:
    """Nodes, topics, services and actions with their types, once discovery is over: the
    graph has been unchanged for `settle` s after at least `min_wait` s (or done(graph)),
    at most `max_wait` s."""
    start = time.monotonic()
    current, changed = graph_now(node), start
    while not (done is not None and done(current)):
        now = time.monotonic()
        if now - start >= max_wait or (now - start >= min_wait and now - changed >= settle):
            break
        spin_until(node, lambda: False, min(GRAPH_POLL, max_wait - (now - start)))
        latest = graph_now(node)
        if latest != current:
            current, changed = latest, time.monotonic()
    return current


def graph_now(node: Node) -> dict[str, dict[str, list[str]]]:
    """What discovery has found so far (hidden nodes and parameter services left out)."""
    own = node.get_fully_qualified_name()
    nodes = sorted(f'{ns.rstrip("/")}/{n}' for n, ns in node.get_node_names_and_namespaces()
                   if not n.startswith('_'))      # hidden nodes, as ros2 node list does
    topics = {n: t for n, t in node.get_topic_names_and_types()
              if not any(h in n for h in ('/_action/', '/rosout', '/parameter_events'))}
    services = {n: t for n, t in node.get_service_names_and_types()
                if '/_action/' not in n and not n.startswith(own + '/')
                and not n.rsplit('/', 1)[-1].endswith(_PARAMETER_SERVICES)}
    actions = dict(get_action_names_and_types(node))
    return {'nodes': {n: [] for n in nodes if n != own}, 'topics': topics,
            'services': services, 'actions': actions}


def wait_for_publishers(node: Node, topic: str, timeout: float,
                        settle: float = 0.3) -> list:
    """The topic's publishers once one is discovered and no other showed up for `settle` s
    (empty if none within `timeout` s)."""
    deadline = time.monotonic() + timeout
    found: list = []

    def seen() -> bool:
        found[:] = node.get_publishers_info_by_topic(topic)
        return bool(found)
    if not spin_until(node, seen, timeout):
        return []
    while time.monotonic() < deadline:
        count = len(found)
        spin_until(node, lambda: False, min(settle, deadline - time.monotonic()))
        if seen() and len(found) == count:
            break
    return found


def subscription_qos(publishers: list, depth: int = 100):
    """QoS that matches every publisher, as `ros2 topic echo` picks it: best effort if any
    publisher is best effort, transient local only if all of them are."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    qos = QoSProfile(depth=depth)
    if any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if publishers and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for p in publishers):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


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
