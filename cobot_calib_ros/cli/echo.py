"""`cobot-calib echo TOPIC`: print a topic's messages, like `ros2 topic echo`."""
from __future__ import annotations

import sys
import time

from cobot_calib_ros.cli.common import (
    absolute, fail, not_found_hint, print_message, reader_gone, ros_node)


def add_parser(subparsers):
    p = subparsers.add_parser('echo', help='print messages of a topic, like ros2 topic echo')
    p.add_argument('topic')
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--json', action='store_true', help='one JSON object per line')
    p.add_argument('--timeout', type=float, default=10.0,
                   help='[s] to find a publisher of the topic / a message (default 10)')
    return p


def run(args) -> int:
    from cobot_calib_ros.ros.types import import_type
    from cobot_calib_ros.ros.graph import subscription_qos, wait_for_publishers
    topic = absolute(args.topic)
    with ros_node('cobot_calib_echo') as node:
        publishers = wait_for_publishers(node, topic, args.timeout)
        type_name = publishers[0].topic_type if publishers else _known_type(node, topic)
        if type_name is None:
            return fail(f'topic {topic} not found within {args.timeout:g} s; '
                        + not_found_hint())
        if not publishers and args.once:
            return fail(f'no publisher on {topic} within {args.timeout:g} s')
        if not publishers:
            print(f'no publisher on {topic} yet; waiting with reliable, volatile QoS',
                  file=sys.stderr, flush=True)
        try:
            msg_type = import_type(type_name)
        except ValueError as e:
            return fail(f'cannot echo {topic}: {e}')
        received = []
        node.create_subscription(msg_type, topic, received.append,
                                 subscription_qos(publishers))
        try:
            return _print_received(node, received, topic, args)
        except KeyboardInterrupt:
            return 0


def _known_type(node, topic: str) -> str | None:
    """The topic's type when only subscribers of it are known."""
    types = dict(node.get_topic_names_and_types()).get(topic)
    return types[0] if types else None


def _print_received(node, received: list, topic: str, args) -> int:
    from cobot_calib_ros.ros.calls import spin_until
    from cobot_calib_ros.ros.types import to_dict
    deadline = time.monotonic() + args.timeout if args.once else float('inf')
    while time.monotonic() < deadline:
        spin_until(node, lambda: bool(received), min(1.0, deadline - time.monotonic()))
        while received:
            print_message(to_dict(received.pop(0)), args.json)
            if args.once or reader_gone():        # `cobot-calib echo ... | head`
                return 0
    return fail(f'no message on {topic} within {args.timeout:g} s')
