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
    'filter_cmd',                   # program filtering for a controller's nominal kinematics
    'move',                         # a pose target, solved with the calibrated kinematics
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
    from cobot_calib_ros.cli.common import EXIT_INTERRUPTED, GuardedStdout
    stdout = sys.stdout
    sys.stdout = GuardedStdout(stdout)     # `cobot-calib ... | head`: the verb's own exit code
    try:
        args = build_parser().parse_args(argv)
        return args.run(args)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    finally:
        sys.stdout.flush()
        sys.stdout = stdout


if __name__ == '__main__':
    sys.exit(main())
