"""cobot-calib: run the node suite and talk to it (up, echo, call, list, demo, trial,
experiment, report)."""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import time

import yaml

from cobot_calib_ros.api import launcher

EXIT_USAGE = 2
EXIT_FAILED = 1


def _ros_env() -> None:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


@contextlib.contextmanager
def ros_node(name: str):
    """An rclpy context and node for one CLI command."""
    import rclpy
    rclpy.init(args=None, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node(name, start_parameter_services=False)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def cmd_up(args) -> int:
    suite = launcher.Suite(launcher.default_log_dir())
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    suite.start(launcher.suite_specs(args.cell))
    print(f'node suite up on ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}: '
          f'{", ".join(suite.processes)}')
    print(f'logs: {suite.log_dir}   (Ctrl-C stops every node)', flush=True)
    while not stop:
        failed = suite.failed()
        if failed:
            for name, code in failed.items():
                print(f'{name} exited with {code}; last log lines:\n{suite.log_tail(name)}',
                      file=sys.stderr)
            suite.stop()
            return EXIT_FAILED
        time.sleep(0.2)
    codes = suite.stop()
    print('stopped: ' + ', '.join(f'{n} ({c})' for n, c in codes.items()))
    return 0


def _topic_qos(node, topic: str):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    infos = node.get_publishers_info_by_topic(topic)
    qos = QoSProfile(depth=100)
    if infos and all(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if infos and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                     for i in infos):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


def _resolve_type(node, name: str, kind: str, wait: float) -> str | None:
    from cobot_calib_ros.api.client import spin_until
    lookup = (node.get_topic_names_and_types if kind == 'topic'
              else node.get_service_names_and_types)
    found: list[str] = []

    def seen() -> bool:
        found[:] = [t[0] for n, t in lookup() if n == name]
        return bool(found)
    spin_until(node, seen, wait)
    return found[0] if found else None


def _absolute(name: str) -> str:
    return name if name.startswith('/') else '/' + name


def _print_message(data: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(data, default=str), flush=True)
    else:
        print(yaml.safe_dump(data, sort_keys=False, default_flow_style=None).rstrip())
        print('---', flush=True)


def cmd_echo(args) -> int:
    from cobot_calib_ros.api.client import import_type, spin_until, to_dict
    topic = _absolute(args.topic)
    with ros_node('cobot_calib_echo') as node:
        type_name = _resolve_type(node, topic, 'topic', args.timeout)
        if type_name is None:
            print(f'topic {topic} not found within {args.timeout:.0f} s; '
                  'see `cobot-calib list` (is the suite up, same ROS_DOMAIN_ID?)',
                  file=sys.stderr)
            return EXIT_FAILED
        received = []
        node.create_subscription(import_type(type_name), topic,
                                 lambda m: received.append(m), _topic_qos(node, topic))
        printed = 0
        deadline = time.monotonic() + args.timeout if args.once else float('inf')
        try:
            while time.monotonic() < deadline:
                spin_until(node, lambda: bool(received), min(1.0, deadline - time.monotonic()))
                while received:
                    _print_message(to_dict(received.pop(0)), args.json)
                    printed += 1
                    if args.once:
                        return 0
        except KeyboardInterrupt:
            return 0
        print(f'no message on {topic} within {args.timeout:.0f} s', file=sys.stderr)
        return EXIT_FAILED


def cmd_call(args) -> int:
    from cobot_calib_ros.api.client import call_service, CallError, import_type, set_fields, to_dict
    service = _absolute(args.service)
    with ros_node('cobot_calib_call') as node:
        type_name = args.type or _resolve_type(node, service, 'service', args.timeout)
        if type_name is None:
            print(f'service {service} not found; see `cobot-calib list`', file=sys.stderr)
            return EXIT_FAILED
        srv = import_type(type_name)
        try:
            request = set_fields(srv.Request(), yaml.safe_load(args.values or '{}') or {})
        except (ValueError, TypeError, AttributeError, AssertionError) as e:
            print(f'bad request for {type_name}: {e}', file=sys.stderr)
            return EXIT_USAGE
        client = node.create_client(srv, service)
        try:
            response = call_service(node, client, request, args.timeout)
        except CallError as e:
            print(e, file=sys.stderr)
            return EXIT_FAILED
        _print_message(to_dict(response), args.json)
        return 0


def cmd_list(args) -> int:
    from cobot_calib_ros.api.client import graph
    with ros_node('cobot_calib_list') as node:
        g = graph(node, args.wait)
    if args.json:
        print(json.dumps(g, indent=2))
        return 0
    for kind in ('nodes', 'topics', 'services', 'actions'):
        print(f'{kind}:')
        for name, types in sorted(g[kind].items()):
            print(f'  {name}' + (f' [{", ".join(types)}]' if types else ''))
    return 0


def cmd_demo(args) -> int:
    from cobot_calib_ros.cli import demo
    return demo.run(args)


def cmd_trial(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_trial(args)


def cmd_experiment(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_experiment(args)


def cmd_report(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_report(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='cobot-calib', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True)
    p = sub.add_parser('up', help='start the node suite (Ctrl-C stops it)')
    p.add_argument('--cell', default='sawyer_close', help='cell YAML path or name')
    p.set_defaults(func=cmd_up)
    p = sub.add_parser('echo', help='print messages of a topic, like ros2 topic echo')
    p.add_argument('topic')
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--json', action='store_true', help='one JSON object per line')
    p.add_argument('--timeout', type=float, default=10.0, help='[s] to find the topic / a message')
    p.set_defaults(func=cmd_echo)
    p = sub.add_parser('call', help='call a service, like ros2 service call')
    p.add_argument('service')
    p.add_argument('values', nargs='?', help='request fields as YAML, e.g. "{duration: 0.5}"')
    p.add_argument('--type', help='service type, e.g. cobot_calib_msgs/srv/CaptureJoints')
    p.add_argument('--json', action='store_true')
    p.add_argument('--timeout', type=float, default=10.0, help='[s]')
    p.set_defaults(func=cmd_call)
    p = sub.add_parser('list', help='nodes, topics, services and actions with types')
    p.add_argument('--wait', type=float, default=1.5, help='discovery time [s]')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=cmd_list)
    p = sub.add_parser('demo', help='the main job on the mock robot')
    p.add_argument('--cell', default='sawyer_close', help='cell YAML path or name')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--attach', action='store_true',
                   help='use an already running suite instead of starting one')
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser('trial', help='run (or resume) one ISO 9283 repeatability trial on a '
                       'running suite, printing RP after each cycle')
    p.add_argument('--method', default='reference',
                   help='reference | three_point | five_point_lsq | rigid | robust')
    p.add_argument('--axis', default='z', choices=('x', 'y', 'z'))
    p.add_argument('--cycles', type=int, default=30)
    p.add_argument('--trial-id', default='', help='an unfinished trial id resumes it')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=cmd_trial)
    p = sub.add_parser('experiment', help="reproduce the first paper's comparison on the "
                       'mock robot (starts its own suite)')
    p.add_argument('which', choices=('user-frame',))
    p.add_argument('--setup', default='close', choices=('close', 'wide'))
    p.add_argument('--axis', default='z', choices=('x', 'y', 'z'))
    p.add_argument('--cycles', type=int, default=30)
    p.add_argument('--cell', default='sawyer_close', help='cell YAML path or name')
    p.add_argument('--data-dir', help='where trials are stored (default ~/.ros/cobot_calib)')
    p.add_argument('--out', help='report folder (default <data dir>/reports)')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=cmd_experiment)
    p = sub.add_parser('report', help='PNG box plot and table of stored trials')
    p.add_argument('trials', nargs='+', help='trial ids')
    p.add_argument('--data-dir', help='where trials are stored (default ~/.ros/cobot_calib)')
    p.add_argument('--out', help='report folder (default <data dir>/reports)')
    p.set_defaults(func=cmd_report)
    return parser


def main(argv: list[str] | None = None) -> int:
    _ros_env()
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == '__main__':
    sys.exit(main())
