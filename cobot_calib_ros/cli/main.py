"""cobot-calib: run the node suite and talk to it (`cobot-calib COMMAND --help` for each)."""
from __future__ import annotations

import argparse
import importlib
import os
import re
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
    'tcp',                          # the tool centre point (tcp_calibrator)
    'intrinsics',                   # camera intrinsics from board images: camera_info YAML
    'record', 'bag', 'replay',      # bags (rosbag2): record, bag info, replay
    'detect',
    'export',
    'filter_cmd',                   # program filtering for a controller's nominal kinematics
    'user_frame_cmd',               # a user frame from a points file, no suite
    'move',                         # a pose target, solved with the calibrated kinematics
    'db',
    'history',
    'check',
    'view',                         # the live view: Foxglove WebSocket on loopback
)


class _Parser(argparse.ArgumentParser):
    """argparse's parser, which also takes a negative number in exponent notation for a value
    (``--rpy -3.14 -5.37e-05 7.6e-05``): Python < 3.13 takes ``-5.37e-05`` for an option."""

    NEGATIVE_NUMBER = re.compile(r'^-(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$')

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = self.NEGATIVE_NUMBER


def command_of(module: str) -> str:
    """The command a verb module registers: its name without `_cmd`, '-' for '_'."""
    return module.removesuffix('_cmd').replace('_', '-')


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every verb, or of the one ``argv`` starts with: a command imports only its
    own verb's module (the others' cv2, pinocchio and rosbags cost 0.3-0.4 s of CPU per run)."""
    parser = _Parser(prog='cobot-calib', description=__doc__)
    subparsers = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    named = [m for m in VERBS if argv and command_of(m) == argv[0]]
    for name in named or VERBS:
        verb = importlib.import_module(f'cobot_calib_ros.cli.{name}')
        verb.add_parser(subparsers).set_defaults(run=verb.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    from cobot_calib_ros.api.dds_profile import large_data_env
    os.environ.update(large_data_env())    # camera images of 1 MB and more
    from cobot_calib_ros.cli.common import EXIT_INTERRUPTED, GuardedStdout
    stdout = sys.stdout
    sys.stdout = GuardedStdout(stdout)     # `cobot-calib ... | head`: the verb's own exit code
    native_stdout = None
    try:
        args = build_parser(sys.argv[1:] if argv is None else argv).parse_args(argv)
        if getattr(args, 'json', False):
            native_stdout = _native_stdout_to_stderr(stdout)
        return args.run(args)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    finally:
        sys.stdout.flush()
        if native_stdout is not None:
            sys.stdout.close()
            os.dup2(native_stdout, 1)
            os.close(native_stdout)
        sys.stdout = stdout


def _native_stdout_to_stderr(stdout) -> int | None:
    """--json output is parsed by programs, but Fast DDS logs its errors (e.g. RTPS_TRANSPORT_SHM
    "Failed init_port") with std::cout at any time: file descriptor 1 becomes stderr for the
    native libraries and the verb prints to a copy of the real stdout. Returns the saved
    descriptor, or None where stdout is not the process's own (a caller capturing it)."""
    if stdout is not sys.__stdout__:
        return None
    try:
        if stdout.fileno() != 1:
            return None
    except (AttributeError, OSError, ValueError):
        return None
    from cobot_calib_ros.cli.common import GuardedStdout
    stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = GuardedStdout(os.fdopen(os.dup(saved), 'w', encoding=stdout.encoding,
                                         errors=stdout.errors))
    return saved


if __name__ == '__main__':
    sys.exit(main())
