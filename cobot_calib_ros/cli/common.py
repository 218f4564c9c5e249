"""What the verb modules share: exit codes, one rclpy node per command, output, errors."""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

EXIT_OK = 0
EXIT_FAILED = 1      # the command ran and did not succeed (not found, timed out, refused)
EXIT_USAGE = 2       # the user's input does not fit (as argparse uses 2)
EXIT_INTERRUPTED = 130   # Ctrl-C (128 + SIGINT, as a shell reports it)


class GuardedStdout:
    """sys.stdout while a verb runs. Once its reader has gone (`| head` closed the pipe), the
    rest of the output goes to /dev/null instead of raising BrokenPipeError out of the verb,
    so the verb ends as it would have and a refusal keeps its non-zero exit code; a verb
    that prints an endless stream stops when reader_gone()."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.reader_gone = False

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._drop()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._drop()

    def _drop(self) -> None:
        self.reader_gone = True
        # what is still buffered, and the interpreter's last flush, go nowhere
        os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())

    def __getattr__(self, name):
        return getattr(self._stream, name)


def reader_gone() -> bool:
    """The reader of stdout has gone (GuardedStdout)."""
    return getattr(sys.stdout, 'reader_gone', False)


def domain_id() -> str:
    return os.environ.get('ROS_DOMAIN_ID', '0')


def fail(message: str, code: int = EXIT_FAILED) -> int:
    """Print one line to stderr; the exit code."""
    print(message, file=sys.stderr, flush=True)
    return code


@contextlib.contextmanager
def ros_node(name: str, namespace: str = ''):
    """The rclpy node of one CLI command (ros.session: spun by its own executor). Ctrl-C comes
    as a KeyboardInterrupt from the command's waits (ros.calls.spin_until), never from inside
    rclpy, and the teardown finishes before it goes on (see ros.interrupts). ``namespace``:
    the node's (its relative names resolve there: `up --namespace`)."""
    from cobot_calib_ros.ros import interrupts
    from cobot_calib_ros.ros.session import session
    with interrupts.deferred(), session(name, namespace=namespace) as (node, _):
        yield node


def say(args, text: str) -> None:
    """Progress for the user: on stdout, or on stderr when stdout carries --json."""
    print(text, file=sys.stderr if args.json else sys.stdout, flush=True)


def absolute(name: str) -> str:
    return name if name.startswith('/') else '/' + name


def print_message(data: dict, as_json: bool) -> None:
    """One message: a JSON line, or YAML then '---' as ros2 prints it."""
    if as_json:
        print(json.dumps(data, default=str), flush=True)
        return
    import yaml
    print(yaml.safe_dump(data, sort_keys=False, default_flow_style=None).rstrip())
    print('---', flush=True)


def not_found_hint() -> str:
    return f'see `cobot-calib list` (is the suite up on ROS_DOMAIN_ID={domain_id()}?)'


class IntermixedParser(argparse.ArgumentParser):
    """A verb parser that takes options between optional positionals too
    (`call SERVICE --type T VALUES`), which plain argparse refuses."""

    _inside = False

    def parse_known_args(self, args=None, namespace=None):
        if self._inside:
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def add_intermixed_parser(subparsers, name: str, **kwargs) -> IntermixedParser:
    parser = subparsers.add_parser(name, **kwargs)
    parser.__class__ = IntermixedParser       # add_parser has no per-verb parser class
    return parser


def cell_names() -> str:
    """The cells in config/cells, by name: 'iiwa7_close, sawyer_close'."""
    from cobot_calib_ros import paths
    return ', '.join(sorted(p.stem for p in (paths.config_dir() / 'cells').glob('*.yaml')))


def cell_problem(name_or_path: str, layout: str = '') -> Failure | None:
    """None if the cell file (a path or a name in config/cells) is usable, else an
    INVALID_INPUT Failure of one line: the file, the line and key, what is expected (or the
    cells there are)."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.errors import ErrorCode, Failure
    from cobot_calib_ros.loaders import load_cell
    path = paths.cell_file(name_or_path)
    if not path.is_file():
        return Failure(ErrorCode.INVALID_INPUT, f'cell file {path} not found; give a cell YAML '
                       f'path or a name ({cell_names()})')
    try:
        load_cell(path, layout or None)
    except CellFileError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    return None


def add_robot_options(p, cell_help: str) -> None:
    """--robot-cell, or --urdf with --base-link, --tip-link, --home, --t-flange-tool: the robot
    of a verb that needs no suite (filter, user-frame, move)."""
    p.add_argument('--robot-cell', default=None, help=cell_help)
    p.add_argument('--urdf', default=None,
                   help='instead of a cell file: the robot\'s URDF (with --base-link and '
                        '--tip-link); its results are those identify stored with no --cell')
    p.add_argument('--base-link', default='base_link', help='--urdf: the chain\'s first link '
                                                            '(default base_link)')
    p.add_argument('--tip-link', default=None, help='--urdf: the chain\'s last link (the '
                                                    'flange or tool0)')
    p.add_argument('--home', type=float, nargs='+', default=None, metavar='RAD',
                   help='--urdf: the joints the inverse kinematics starts from (default 0)')
    p.add_argument('--t-flange-tool', '--tool-offset', dest='T_flange_tool',  # legacy name
                   type=float, nargs=6, default=None,
                   metavar=('X', 'Y', 'Z', 'ROLL', 'PITCH', 'YAW'),
                   help='--urdf: the tool centre point on the tip link [m, rad] (default the '
                        'tip link itself; --tool-offset is its old name)')  # legacy name


def robot_cell(args, default: str | None = None):
    """The core Cell of :func:`add_robot_options`: the --urdf chain, else the --robot-cell
    file (else ``default``, a cell name). CellFileError / ValueError saying what to do."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.loaders import cell_of_urdf, load_cell
    if args.urdf:
        if args.robot_cell:
            raise ValueError('give --robot-cell or --urdf, not both')
        if not args.tip_link:
            raise ValueError('--urdf needs --tip-link (the flange or tool0)')
        from cobot_calib_ros.core.frames import from_xyz_rpy
        tool = None if args.T_flange_tool is None else from_xyz_rpy(args.T_flange_tool[:3],
                                                                    args.T_flange_tool[3:])
        return cell_of_urdf(args.urdf, args.base_link, args.tip_link, args.home, tool)
    given = [f for f, v in (('--home', args.home), ('--t-flange-tool', args.T_flange_tool),
                            ('--tip-link', args.tip_link)) if v is not None]
    if given:
        raise ValueError(f'{", ".join(given)} go with --urdf; a cell file has its own')
    return load_cell(paths.cell_file(args.robot_cell or default))
