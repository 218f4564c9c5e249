"""`cobot-calib call SERVICE [TYPE] [VALUES]`: call a service, like `ros2 service call`.

The answer is waited for until it comes, as ros2 service call does: a calibration that moves
the robot takes as long as it takes (landmark_multi: ~15 s). Meanwhile the capture marks the
suite publishes (``cobot_calib/captures``: every view, every pose) are printed on stderr as
progress. A client that stops waiting (``--answer-timeout``, Ctrl-C) says that the call may
still complete on the server and how to see its result, never that it failed. A response that
reports a failure (a non-zero ``error_code``, ``success: false``) is printed and exits 1.
"""
from __future__ import annotations

import re
import sys
import time

from cobot_calib_ros.cli.common import (
    absolute, add_intermixed_parser, EXIT_USAGE, fail, not_found_hint, print_message, ros_node)

TYPE_NAME = re.compile(r'[A-Za-z]\w*/(srv/)?[A-Za-z]\w*')
QUIET_PROGRESS = 5.0    # [s] without a capture mark before a line saying the call still runs
MATCH_WAIT = 2.0        # [s] at most, for the capture marks' publishers to match before the call
# [s] of an unchanged graph (other nodes on it) before a service missing from it counts as
# having no server: 1.5 s said "none offers it" for a running suite at load ~25 (a new
# participant learns the nodes' services seconds after the nodes themselves)
GRAPH_SETTLED = 5.0
SERVER_GONE = 3.0       # [s] a server unseen on the graph while its answer is awaited

# Services whose request only reads (the same request answered twice changes nothing). Their
# request is sent again after RESEND_AFTER s without an answer: a response written before the
# server's response writer matched this client's reader is dropped by DDS (seen at load 25:
# /user_to_robot waited 120 s on a live server), and the first answer of any copy is taken.
QUERY_TYPES = ('cobot_calib_msgs/srv/ConvertPoints', 'cobot_calib_msgs/srv/ListCalibrations',
               'cobot_calib_msgs/srv/GetGroundTruth')
RESEND_AFTER = 10.0     # [s]
# where to see what a call did when the client stopped waiting for its answer
RESULT_HINTS = {
    '/calibrate_user_frame': '`cobot-calib echo user_frame --once` (the active calibration) '
                             'or `cobot-calib call list_calibrations`',
    '/set_active_calibration': '`cobot-calib call list_calibrations`',
}


class UsageError(ValueError):
    """The command line does not fit: exit 2 with this one line."""


def add_parser(subparsers):
    p = add_intermixed_parser(
        subparsers, 'call', help='call a service, like ros2 service call',
        description='Call a service: `call SERVICE [TYPE] [VALUES]` as ros2 service call '
                    'takes them, e.g. `call /capture_joints cobot_calib_msgs/srv/CaptureJoints '
                    '"{duration: 0.5}"` or `call capture_joints "{duration: 0.5}"` (the type '
                    'is then looked up on the graph).')
    p.add_argument('service')
    p.add_argument('type_or_values', nargs='?', metavar='TYPE',
                   help='service type, e.g. cobot_calib_msgs/srv/CaptureJoints')
    p.add_argument('values', nargs='?', metavar='VALUES',
                   help='request fields as YAML, e.g. "{duration: 0.5}"')
    p.add_argument('--type', help='service type (same as the TYPE argument)')
    p.add_argument('--json', action='store_true', help='print the response as JSON')
    p.add_argument('--timeout', type=float, default=10.0,
                   help='[s] to find the service (default 10)')
    p.add_argument('--answer-timeout', type=float, default=None, metavar='S',
                   help='[s] to wait for the answer (default: until it comes, as ros2 service '
                        'call; a calibration that moves the robot takes a while)')
    return p


def run(args) -> int:
    from cobot_calib_ros.ros.fields import FieldError
    try:
        type_name, values = _positionals(args)
        data = _load_yaml(values)
        if type_name:
            _service_class(type_name)                 # an unknown type needs no discovery
    except (UsageError, FieldError) as e:
        return fail(f'bad request: {e}', EXIT_USAGE)
    service = absolute(args.service)
    with ros_node('cobot_calib_call') as node:
        return _call(node, service, type_name, data, args)


def _positionals(args) -> tuple[str | None, str | None]:
    """(type, values) from `SERVICE [TYPE] [VALUES]` and --type."""
    first, values = args.type_or_values, args.values
    if values is None and first is not None and not TYPE_NAME.fullmatch(first):
        first, values = None, first                 # `call SERVICE VALUES`
    if first and args.type and _srv(first) != _srv(args.type):
        raise UsageError(f'two different types given: {first} and --type {args.type}')
    return first or args.type, values


def _srv(type_name: str) -> str:
    from cobot_calib_ros.ros.types import service_type_name
    try:
        return service_type_name(type_name)
    except ValueError as e:
        raise UsageError(str(e)) from None


def _load_yaml(text: str | None):
    import yaml
    try:
        return yaml.safe_load(text or '{}')
    except yaml.YAMLError as e:
        mark = getattr(e, 'problem_mark', None)
        where = f' at column {mark.column + 1}' if mark is not None else ''
        problem = getattr(e, 'problem', None) or type(e).__name__
        raise UsageError(f'VALUES is not valid YAML ({problem}{where}); '
                         'write it like "{duration: 0.5}"') from None


def _service_class(type_name: str):
    from cobot_calib_ros.ros.types import import_service
    try:
        return import_service(type_name)
    except ValueError as e:
        raise UsageError(f'{e}; see the service types in `cobot-calib list`') from None


def _advertised(node, service: str, timeout: float) -> tuple[list[str], int]:
    """(the service's types, 0) once discovery finds it. Empty
    types if not found within `timeout` s, or sooner: once the graph has other nodes and has
    not changed for GRAPH_SETTLED s without the service (its server is gone, not late): then
    the number of other nodes on the settled graph comes second."""
    from cobot_calib_ros.ros.calls import spin_until
    found: list[str] = []
    settle = _Settle(node)

    def seen() -> bool:
        services = dict(node.get_service_names_and_types())
        found[:] = services.get(service, [])
        return bool(found) or settle.settled(services)
    spin_until(node, seen, timeout)
    return found, 0 if found or not settle.done else settle.others


class _Settle:
    """Whether discovery has settled: other nodes on the graph, and the graph's nodes and
    services unchanged for GRAPH_SETTLED s."""

    def __init__(self, node) -> None:
        self._node, self._snapshot, self._since = node, None, time.monotonic()
        self.others, self.done = 0, False

    def settled(self, services: dict) -> bool:
        nodes = frozenset(self._node.get_node_names_and_namespaces())
        self.others = len(nodes) - 1                  # this client is on the graph too
        snapshot = (nodes, frozenset(services))
        if snapshot != self._snapshot:
            self._snapshot, self._since = snapshot, time.monotonic()
        self.done = self.others > 0 and time.monotonic() - self._since >= GRAPH_SETTLED
        return self.done


def _call(node, service: str, type_name: str | None, data, args) -> int:
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.ros.fields import FieldError, set_fields
    from cobot_calib_ros.ros.types import to_dict
    # subscribed before discovery: the server's node learns of this reader while the service
    # is looked for, so the first mark of the call reaches it (a mark published before the
    # server had matched a reader made after discovery was lost: 17 views of 18 printed, a
    # loaded test run); _answer closes it, or the node's end
    progress = _Progress(node)
    advertised, others = _advertised(node, service, args.timeout)
    if not advertised and others:
        return fail(f'no server for {service}: {others} other node(s) are on the graph and '
                    'none offers it; is its node running? ' + not_found_hint())
    if not advertised:
        return fail(f'service {service} not found within {args.timeout:g} s; '
                    + not_found_hint())
    if type_name and _srv(type_name) not in advertised:
        return fail(f'type {type_name} does not match the advertised type(s) of {service}: '
                    f'{", ".join(advertised)}; drop the type or give that one', EXIT_USAGE)
    try:
        srv = _service_class(type_name or advertised[0])
        request = set_fields(srv.Request(), data)
    except (UsageError, FieldError) as e:
        return fail(f'bad request: {e}', EXIT_USAGE)
    try:
        response = _answer(node, node.create_client(srv, service), request, args, progress,
                           query=(_srv(type_name) if type_name else advertised[0]) in QUERY_TYPES)
    except CallError as e:
        return fail(str(e))
    except KeyboardInterrupt:
        return fail(f'stopped waiting for the answer of {service} (Ctrl-C); '
                    + _may_complete(service), 130)
    print_message(to_dict(response), args.json)
    refused = refusal(response)
    return fail(f'{service} answered {refused}') if refused else 0


def refusal(response) -> str:
    """'' when a response reports success, else what it reports: a non-zero ``error_code``
    (with its constant's name and the ``message``), or ``success: false`` (std_srvs). `call`
    exits 1 then, as a failed command does, so that a script can test it."""
    code = getattr(response, 'error_code', 0)
    message = getattr(response, 'message', '')
    if code:
        names = [n for n in dir(type(response)) if n.isupper() and not n.startswith('_')
                 and getattr(type(response), n) == code and n != 'SUCCESS']
        name = f' ({names[0]})' if len(names) == 1 else ''
        return f'error_code {code}{name}: {message}' if message else f'error_code {code}{name}'
    if getattr(response, 'success', True) is False:
        return f'success: false: {message}' if message else 'success: false'
    return ''


def _answer(node, client, request, args, progress: _Progress, query: bool = False):
    """Call once the server is there; wait for the answer (args.answer_timeout [s], None: until
    it comes), printing the suite's capture marks meanwhile (``progress``). CallError if no
    server or no answer in time (the message says the call may still complete)."""
    from cobot_calib_ros.ros.calls import CallError, spin_until
    if not spin_until(node, client.service_is_ready, args.timeout):
        raise CallError(f'service {client.srv_name} is not available; is the node suite up '
                        '(cobot-calib up) and ROS_DOMAIN_ID the same?')
    server = _ServerWatch(node, client.srv_name)
    # so the first view shows too, and the server's node is named if it dies (a node's name
    # comes from its own publication, after its services: never, once it is killed)
    spin_until(node, lambda: progress.matched() and server.named(), MATCH_WAIT)
    started = sent = time.monotonic()
    futures = [client.call_async(request)]

    def answered() -> bool:
        return any(f.done() for f in futures)

    try:
        while not spin_until(node, answered, 0.5):
            if server.gone():
                _forget(client, futures)
                raise CallError(server.gone_line())
            waited = time.monotonic() - started
            if args.answer_timeout is not None and waited > args.answer_timeout:
                _forget(client, futures)
                raise CallError(f'no answer from {client.srv_name} within '
                                f'{args.answer_timeout:g} s; ' + _may_complete(client.srv_name))
            if query and time.monotonic() - sent > RESEND_AFTER:
                futures.append(client.call_async(request))
                sent = time.monotonic()
            progress.still_waiting(client.srv_name, waited)
    finally:
        progress.close()
    done = next(f for f in futures if f.done())
    _forget(client, [f for f in futures if f is not done])
    return done.result()


def _forget(client, futures) -> None:
    for future in futures:
        client.remove_pending_request(future)


class _ServerWatch:
    """Whether a service's server is still on the graph while its answer is awaited. A node
    that exits leaves the graph at once; a killed one (kill -9) when DDS's participant lease
    runs out (Fast DDS: 20 s). Gone once unseen for SERVER_GONE s."""

    def __init__(self, node, service: str) -> None:
        self._node, self._service, self._seen = node, service, time.monotonic()
        self._server_node = ''

    def gone(self) -> bool:
        now = time.monotonic()
        if self._node.count_services(self._service) > 0:
            self._seen = now
        return now - self._seen > SERVER_GONE

    def named(self) -> bool:
        """Whether the server's node is known (looked up until it is)."""
        self._server_node = self._server_node or _service_node(self._node, self._service)
        return bool(self._server_node)

    def gone_line(self) -> str:
        who = f'the {self._server_node} node' if self._server_node else 'its node'
        return (f'no server for {self._service} any more: {who} is gone (off the graph for '
                f'{SERVER_GONE:g} s) without answering; restart it (cobot-calib up restarts a '
                'node that exits) and call again')


def _service_node(node, service: str) -> str:
    """The name of the node that serves ``service`` on the graph now, '' if none."""
    for name, namespace in node.get_node_names_and_namespaces():
        try:
            served = node.get_service_names_and_types_by_node(name, namespace)
        except Exception:                 # noqa: BLE001 - a node that left meanwhile
            continue
        if any(n == service for n, _ in served):
            return name
    return ''


def _may_complete(service: str) -> str:
    where = RESULT_HINTS.get(service, 'check its effect once it is done')
    return f'the call was sent and may still complete on the server: see {where}'


class _Progress:
    """Prints each capture mark (cobot_calib/captures: a landmark view, a collected pose)
    on stderr while a call runs, and a line every QUIET_PROGRESS s without one."""

    def __init__(self, node) -> None:
        from cobot_calib_msgs.msg import CaptureMark
        from cobot_calib_ros.ros.marks import CAPTURES_TOPIC
        self._node, self._count = node, 0
        self._last = time.monotonic()
        self._topic = CAPTURES_TOPIC
        self._sub = node.create_subscription(CaptureMark, CAPTURES_TOPIC, self._on_capture, 100)

    def matched(self) -> bool:
        """Every publisher of the marks the graph shows is matched to this subscription."""
        return self._sub.get_publisher_count() >= self._node.count_publishers(self._topic)

    def _on_capture(self, msg) -> None:
        self._count += 1
        self._last = time.monotonic()
        print(f'  capture {self._count}: {msg.target}', file=sys.stderr, flush=True)

    def still_waiting(self, service: str, waited: float) -> None:
        if time.monotonic() - self._last >= QUIET_PROGRESS:
            self._last = time.monotonic()
            print(f'  waiting for the answer of {service} ({waited:.0f} s)', file=sys.stderr,
                  flush=True)

    def close(self) -> None:
        self._node.destroy_subscription(self._sub)
