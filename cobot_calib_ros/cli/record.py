"""`cobot-calib record`: record topics into a rosbag2 bag (mcap), like `ros2 bag record`.

The bag is a directory (`<DIR>/metadata.yaml`, `<DIR>/<DIR>_0.mcap`) that Jazzy's rosbag2,
rosbags and Foxglove read. Ctrl-C (or SIGTERM, or the end of --duration) closes it cleanly; a
recording cut by a crash still reads up to its last second (`cobot-calib bag info`).
"""
from __future__ import annotations

from pathlib import Path
import sys

from cobot_calib_ros.cli.common import EXIT_OK, EXIT_USAGE, add_intermixed_parser, fail


def add_parser(subparsers):
    p = add_intermixed_parser(
        subparsers, 'record', help='record topics into a rosbag2 bag (mcap), like ros2 bag record',
        description=__doc__.split('\n\n')[0] + ' Uses the exported ROS_DOMAIN_ID.')
    p.add_argument('topics', nargs='*', metavar='TOPIC', help='topics to record')
    p.add_argument('-o', '--output', required=True, metavar='DIR',
                   help='the bag directory to create (must not exist)')
    p.add_argument('-a', '--all', action='store_true',
                   help='record every topic, including those that appear later')
    p.add_argument('--include-hidden', action='store_true',
                   help='with --all: also hidden topics (a name part starting with _)')
    p.add_argument('--compress', choices=('zstd', 'none'), default='none',
                   help='mcap chunk compression (default none, as ros2 bag record)')
    p.add_argument('--duration', type=float, metavar='SECONDS',
                   help='stop after this long (default: until Ctrl-C)')
    p.add_argument('--use-sim-time', action='store_true',
                   help='stamp messages with /clock time (as ros2 bag record --use-sim-time)')
    return p


def run(args) -> int:
    if bool(args.topics) == bool(args.all):
        return fail('record: give the topics to record, or --all (not both)', EXIT_USAGE)
    if args.duration is not None and args.duration <= 0:
        return fail('record: --duration must be > 0', EXIT_USAGE)
    if Path(args.output).exists():
        return fail(f'record: {args.output} already exists; give a new directory '
                    '(a bag is never written over)')
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.recorder import BagRecorder
    from cobot_calib_ros.ros import spin

    def say(text: str) -> None:
        print(text, flush=True)

    def make_node():
        from rclpy.parameter import Parameter
        return BagRecorder(args.output, args.topics, all_topics=args.all,
                           include_hidden=args.include_hidden,
                           compression=None if args.compress == 'none' else args.compress,
                           duration=args.duration, report=say,
                           parameter_overrides=[Parameter('use_sim_time',
                                                          value=args.use_sim_time)])

    say(f'recording into {args.output}' + ('' if args.duration else ' (Ctrl-C to stop)'))
    try:
        spin.run(make_node, args=[sys.argv[0]])
    except BagError as exc:
        return fail(f'record: {exc}')
    return EXIT_OK
