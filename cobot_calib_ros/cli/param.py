"""`cobot-calib param list|get|set NODE [NAME] [VALUE]`: a node's parameters, as `ros2 param`.

Values are written as YAML, as ros2 param takes them (``0.5``, ``true``, ``[1, 2]``, ``text``);
an integer given for a double parameter is set as a double. A value the node refuses (out of
its range, read-only, a check of its own) exits 1 with the node's reason.
"""
from __future__ import annotations

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, fail, ros_node

_TYPES = {1: 'Boolean value is', 2: 'Integer value is', 3: 'Double value is',
          4: 'String value is', 5: 'Byte values are', 6: 'Boolean values are',
          7: 'Integer values are', 8: 'Double values are', 9: 'String values are'}


def add_parser(subparsers):
    p = subparsers.add_parser('param', help='list, get or set a node\'s parameters (as ros2 '
                              'param)', description=__doc__.split('\n\n')[0])
    p.add_argument('action', choices=('list', 'get', 'set'))
    p.add_argument('node', metavar='NODE', help='node name, e.g. user_frame_solver')
    p.add_argument('name', nargs='?', metavar='NAME', help='parameter (get, set)')
    p.add_argument('value', nargs='?', metavar='VALUE', help='new value as YAML (set)')
    p.add_argument('--timeout', type=float, default=5.0,
                   help='[s] to wait for the node\'s parameter services (default 5)')
    return p


def run(args) -> int:
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.ros.remote_params import RemoteParameters
    wanted = {'list': 0, 'get': 1, 'set': 2}[args.action]
    given = sum(v is not None for v in (args.name, args.value))
    if given != wanted:
        usage = {'list': 'param list NODE', 'get': 'param get NODE NAME',
                 'set': 'param set NODE NAME VALUE'}[args.action]
        return fail(f'usage: cobot-calib {usage}', 2)
    with ros_node('cobot_calib_param') as node:
        remote = RemoteParameters(node, args.node, args.timeout)
        try:
            return {'list': _list, 'get': _get, 'set': _set}[args.action](remote, args)
        except CallError as e:
            return fail(str(e))


def _list(remote, args) -> int:
    for name in remote.names():
        print(f'  {name}')
    return EXIT_OK


def _get(remote, args) -> int:
    from rclpy.parameter import parameter_value_to_python
    value = remote.get(args.name)
    if value.type not in _TYPES:
        return fail(f'{remote.target} has no parameter {args.name!r} (cobot-calib param list '
                    f'{args.node})')
    print(f'{_TYPES[value.type]}: {parameter_value_to_python(value)}')
    return EXIT_OK


def _set(remote, args) -> int:
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import get_parameter_value, parameter_value_to_python
    value = parameter_value_to_python(get_parameter_value(args.value))
    current = remote.get(args.name).type
    if current == ParameterType.PARAMETER_DOUBLE and type(value) is int:
        value = float(value)
    ok, reason = remote.set(args.name, value)
    if not ok:
        return fail(f'Setting parameter failed: {reason or "refused by the node"}', EXIT_FAILED)
    print('Set parameter successful')
    return EXIT_OK
