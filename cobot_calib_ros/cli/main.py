"""cobot-calib: run the node suite and talk to it (`cobot-calib COMMAND --help` for each)."""
from __future__ import annotations

import argparse
import importlib
import os
import sys

# One module per verb in cobot_calib_ros/cli/, in --help order. A verb module has
# `add_parser(subparsers) -> argparse.ArgumentParser` and `run(args) -> int` (the exit code);
# registering a new verb is adding one line here with its module name.
VERBS = (
    'up',
    'echo',
    'call',
    'list_cmd',
    'param',
    'demo_cmd',
    'teach',
    'trial',
    'experiment_cmd',
    'report',
    'identify',
    'hand_eye',
    'record', 'bag', 'replay',      # bags (rosbag2): record, bag info, replay
    'detect',
    'export',
    'db',
    'history',
    'check',
    'view',                         # the live view: Foxglove WebSocket on loopback
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='cobot-calib', description=__doc__)
    subparsers = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name in VERBS:
        verb = importlib.import_module(f'cobot_calib_ros.cli.{name}')
        verb.add_parser(subparsers).set_defaults(run=verb.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:                       # `cobot-calib echo ... | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == '__main__':
    sys.exit(main())
