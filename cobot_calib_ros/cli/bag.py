"""`cobot-calib bag info BAG`: what `ros2 bag info` prints, for ours and rosbag2's bags.

Reads mcap and sqlite3 bags (any metadata version up to Jazzy's), a single .mcap/.db3 file,
and bags cut short by a crash (said on stderr; --strict refuses them instead).
"""
from __future__ import annotations

import sys

from cobot_calib_ros.cli.common import EXIT_OK, fail


def add_parser(subparsers):
    p = subparsers.add_parser('bag', help='rosbag2 bags: info',
                              description=__doc__.split('\n\n')[0])
    verbs = p.add_subparsers(dest='bag_command', required=True, metavar='SUBCOMMAND')
    info = verbs.add_parser('info', help='print what ros2 bag info prints',
                            description=__doc__)
    info.add_argument('bag', metavar='BAG', help='bag directory, or a .mcap/.db3 file')
    info.add_argument('-t', '--topic-name', action='store_true',
                      help='only the topic names (as ros2 bag info -t)')
    info.add_argument('-v', '--verbose', action='store_true',
                      help='also each topic\'s type hash and the QoS its publishers offered')
    info.add_argument('--strict', action='store_true',
                      help='refuse a bag cut short or damaged instead of reading what is there')
    return p


def run(args) -> int:
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.info import format_info, format_topic_names
    from cobot_calib_ros.bags.reader import open_bag
    try:
        with open_bag(args.bag, strict=args.strict) as bag:
            for warning in bag.warnings:
                print(f'warning: {warning}', file=sys.stderr, flush=True)
            if args.topic_name and args.verbose:
                print("Warning! You have set both the '-t' and '-v' parameters. The '-t' "
                      'parameter will be ignored.', flush=True)     # as ros2 bag info says
            if args.topic_name and not args.verbose:
                text = format_topic_names(bag)
            else:
                text = format_info(bag, verbose=args.verbose)
    except BagError as exc:
        return fail(f'bag info: {exc}')
    print(text, flush=True)
    return EXIT_OK
