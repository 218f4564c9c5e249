"""`cobot-calib list`: nodes, topics, services and actions with their types."""
from __future__ import annotations

import json

from cobot_calib_ros.cli.common import ros_node


def add_parser(subparsers):
    p = subparsers.add_parser(
        'list', help='nodes, topics, services and actions with types',
        description='Discover the graph on the exported ROS_DOMAIN_ID, then list it once it '
                    'has stopped changing: at least 6 s, and 3.5 s after the last node or '
                    'interface found (a node whose discovery traffic was missed shows at its '
                    'next 3 s announcement).')
    p.add_argument('--wait', type=float, default=10.0,
                   help='longest discovery time [s] (default 10)')
    p.add_argument('--json', action='store_true')
    return p


def run(args) -> int:
    from cobot_calib_ros.ros.graph import DISCOVERY_MIN_WAIT, graph
    with ros_node('cobot_calib_list') as node:
        g = graph(node, args.wait, min(DISCOVERY_MIN_WAIT, args.wait))
    if args.json:
        print(json.dumps(g, indent=2))
        return 0
    for kind in ('nodes', 'topics', 'services', 'actions'):
        print(f'{kind}:')
        for name, types in sorted(g[kind].items()):
            print(f'  {name}' + (f' [{", ".join(types)}]' if types else ''))
    return 0
