"""`cobot-calib call SERVICE [TYPE] [VALUES]`: call a service, like `ros2 service call`."""
from __future__ import annotations

import re

from cobot_calib_ros.cli.common import (
    absolute, add_intermixed_parser, EXIT_USAGE, fail, not_found_hint, print_message, ros_node)

TYPE_NAME = re.compile(r'[A-Za-z]\w*/(srv/)?[A-Za-z]\w*')


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
                   help='[s] to find the service / for its answer (default 10)')
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


def _advertised(node, service: str, timeout: float) -> list[str]:
    """The service's types once discovery finds it (empty if not within `timeout` s)."""
    from cobot_calib_ros.ros.calls import spin_until
    found: list[str] = []

    def seen() -> bool:
        found[:] = dict(node.get_service_names_and_types()).get(service, [])
        return bool(found)
    spin_until(node, seen, timeout)
    return found


def _call(node, service: str, type_name: str | None, data, args) -> int:
    from cobot_calib_ros.ros.calls import call_service, CallError
    from cobot_calib_ros.ros.fields import FieldError, set_fields
    from cobot_calib_ros.ros.types import to_dict
    advertised = _advertised(node, service, args.timeout)
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
        response = call_service(node, node.create_client(srv, service), request, args.timeout)
    except CallError as e:
        return fail(str(e))
    print_message(to_dict(response), args.json)
    return 0
