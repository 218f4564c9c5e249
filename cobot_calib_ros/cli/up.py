"""`cobot-calib up`: start the node suite and keep it running until Ctrl-C."""
from __future__ import annotations

from dataclasses import replace
import math
import os
import re
import signal
import sys
import time

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.cli.common import cell_problem, domain_id, EXIT_USAGE, fail, ros_node
from cobot_calib_ros.paths import DEFAULT_CELL

# Discovery before starting: the first node of a running suite showed up within 0.1 s in
# most runs, after 1.6 s at worst (25 runs).
CHECK_MIN_WAIT = 2.5     # [s]
CHECK_MAX_WAIT = 3.0     # [s]
READY_TIMEOUT = 120.0    # [s] for every node to answer after the start (11 processes, 2 cores)
WATCH_PERIOD = 0.2       # [s] between looks at the node processes
QUICK_EXIT = 10.0        # [s] an exit this soon after the start counts as a failed start
QUICK_EXITS = 3          # failed starts in a row before a node is left down


def add_parser(subparsers):
    p = subparsers.add_parser(
        'up', help='start the node suite (Ctrl-C stops it)',
        description='Start the node suite on the exported ROS_DOMAIN_ID (Ctrl-C stops it). '
                    'Refuses if suite nodes already run on that domain.')
    p.add_argument('--cell', default=DEFAULT_CELL, help='cell YAML path or name '
                   '(sawyer_close, iiwa7_close)')
    p.add_argument('--layout', default='', help='marker layout of the cell (close, wide); '
                   'default: the cell file\'s own')
    p.add_argument('--namespace', default='',
                   help='run the suite under this ROS namespace (e.g. cell_07: /cell_07/...), '
                        'its results stored as that cell\'s (else as the cell file\'s name); '
                        'several suites on one machine or one DDS domain, one database')
    p.add_argument('--db', default='', help='results database URL for every node, e.g. '
                   'postgresql://user@host/plant (default $COBOT_CALIB_DB, else the SQLite '
                   'file in the data dir)')
    p.add_argument('--robot-interface', choices=('move_to', 'driver'), default='move_to',
                   help='move_to: mock_robot serves the suite\'s move_to; driver: mock_robot '
                   'offers only joint_states and FollowJointTrajectory, as a ros2_control arm, '
                   'and robot_adapter serves move_to over them')
    p.add_argument('--robot-description', action='store_true',
                   help='publish robot_description (latched) from the active kinematic '
                   'calibration: the cell\'s URDF with the identified joint origins, the '
                   'nominal one while none is active (for robot_state_publisher, MoveIt, RViz)')
    p.add_argument('--nodes', default='',
                   help='start only these nodes of the suite, comma separated (e.g. '
                   'user_frame_solver,hand_eye_calibrator to serve stored results without a '
                   'robot); default: the whole suite')
    p.add_argument('--force', action='store_true',
                   help='start even if suite nodes already run on this ROS_DOMAIN_ID')
    return p


def run(args) -> int:
    from cobot_calib_ros.api import launcher
    problem = cell_problem(args.cell, args.layout)
    if problem is None:     # the mock's part: only of a cell file that reads
        problem = simulation_problem(args.cell, args.layout)
    if problem is not None:
        return fail(f'{problem.message}; nothing started', EXIT_USAGE)
    namespace = args.namespace.strip('/')
    problem = namespace_problem(namespace)
    if problem is not None:
        return fail(f'--namespace {args.namespace!r}: {problem.message}; nothing started',
                    EXIT_USAGE)
    layout = {'layout': args.layout} if args.layout else {}
    overrides = {n: layout for n in ('mock_robot', 'user_frame_solver', 'repeatability_trial')}
    if args.robot_description:
        overrides['kinematic_identifier'] = {'publish_robot_description': 'true'}
    specs = [replace(spec, namespace=namespace) for spec in launcher.suite_specs(
        args.cell, overrides=overrides, robot_interface=args.robot_interface)]
    if args.nodes:
        wanted = [n.strip() for n in args.nodes.split(',') if n.strip()]
        unknown = sorted(set(wanted) - {spec.name for spec in specs})
        if unknown or not wanted:
            return fail(f'--nodes {args.nodes!r}: {", ".join(unknown) or "no node"} not in '
                        f'the suite ({", ".join(spec.name for spec in specs)}); nothing '
                        'started', EXIT_USAGE)
        specs = [spec for spec in specs if spec.name in wanted]
    if not args.force:
        running = running_nodes([spec.full_name for spec in specs])
        if running:
            return fail(f'the node suite already runs on ROS_DOMAIN_ID={domain_id()} '
                        f'({", ".join(running)}); stop it, export another ROS_DOMAIN_ID, '
                        'use another --namespace, or pass --force to start a second one '
                        'anyway')
    return _serve(launcher.Suite(launcher.default_log_dir(), own_group=True), specs,
                  suite_environment(args.db, _robot_of(args.cell)), namespace)


def _robot_of(cell: str) -> str:
    """The robot model of a cell (a name or a YAML path), '' if the file does not read."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.loaders import load_cell
    try:
        return load_cell(paths.cell_file(cell)).robot
    except CellFileError:
        return ''


def namespace_problem(namespace: str) -> Failure | None:
    """None if ``namespace`` ('' : none) is a usable ROS namespace and cell name, else an
    INVALID_INPUT Failure saying why not."""
    if namespace and not re.fullmatch(r'[A-Za-z][A-Za-z0-9_]{0,62}(/[A-Za-z][A-Za-z0-9_]{0,62})*',
                                      namespace):
        return Failure(ErrorCode.INVALID_INPUT, 'a namespace is letters, digits and _ (starting '
                       'with a letter), parts separated by /, e.g. cell_07')
    return None


def suite_environment(db: str, robot: str = '') -> dict[str, str] | None:
    """The nodes' environment: the database, the robot model for the results' provenance;
    None: this process's own. (The cell their results are stored under each node knows from
    its cell file and namespace: store.cells.ResultsCell.of.)"""
    from cobot_calib_ros.store.database import DB_ENV, PROVENANCE_ENV
    if not db and not robot:
        return None
    env = dict(os.environ)
    if db:
        env[DB_ENV] = db
    if robot:
        env.setdefault(PROVENANCE_ENV['robot_model'], robot)
    return env


def simulation_problem(cell: str, layout: str) -> Failure | None:
    """None if the mock robot's part of the cell file is usable too, else an INVALID_INPUT
    Failure file:line: key: what is expected: `up` starts the mock, so it checks that part
    before any node runs."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.sim.scenario import load_simulation
    path = paths.cell_file(cell)
    try:
        load_simulation(path, layout or None)
    except CellFileError as e:
        if 'simulation' not in _top_keys(path):
            return Failure(ErrorCode.INVALID_INPUT,
                           f'up starts the mock robot, which needs the cell\'s simulation: '
                           f'section; {path} has none (a real cell): identify, user-frame, '
                           'filter and export run from it with no suite (README "A plant\'s '
                           'path")')
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    return None


def _top_keys(path) -> tuple[str, ...]:
    import yaml
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return ()
    return tuple(doc) if isinstance(doc, dict) else ()


def running_nodes(names: list[str]) -> list[str]:
    """Which of these nodes a short discovery finds on the domain."""
    from cobot_calib_ros.ros.graph import DISCOVERY_MIN_WAIT, graph
    with ros_node('cobot_calib_up') as node:
        found = graph(node, CHECK_MAX_WAIT, CHECK_MIN_WAIT,
                      done=lambda g: any(n in g['nodes'] for n in names))['nodes']
        if any(n in found for n in names):      # refusing: take the time to name them all
            found = graph(node, DISCOVERY_MIN_WAIT, DISCOVERY_MIN_WAIT,
                          done=lambda g: all(n in g['nodes'] for n in names))['nodes']
    return [n for n in names if n in found]


def _serve(suite, specs, env: dict[str, str] | None = None, namespace: str = '') -> int:
    """Run the suite until Ctrl-C (or SIGTERM): 'ready' once every node answers; a node that
    exits is started again (launch's respawn), the others keep running. The nodes run in
    process groups of their own: a Ctrl-C at the terminal reaches `up` alone, which then sends
    each node one SIGINT."""
    from cobot_calib_ros.ros import spin
    from cobot_calib_ros.ros.calls import spin_until
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    suite.start(specs, env)
    where = f' in namespace /{namespace}' if namespace else ''
    print(f'node suite starting on ROS_DOMAIN_ID={domain_id()}{where}: '
          f'{", ".join(suite.processes)}')
    print(f'logs: {suite.log_dir}   (Ctrl-C stops every node)', flush=True)
    stopped = False
    try:
        with ros_node('_cobot_calib_up', namespace) as node:     # Ctrl-C: a KeyboardInterrupt in a wait
            from cobot_calib_ros.ros.suite_nodes import SuitePublisher
            news = SuitePublisher(node)     # every node's start and exit, for the clients
            for key, process in suite.processes.items():
                news.started(suite.specs[key].full_name, process.pid)
            respawn, ready = _Respawn(suite, node, news), _Ready(suite, node)
            try:
                while not stop:
                    ready.forget(respawn.check())
                    ready.check(lambda: bool(stop))
                    spin_until(node, lambda: bool(stop), WATCH_PERIOD)
            except KeyboardInterrupt:
                pass
            finally:
                ready.close()
                respawn.forget_all()
                # the nodes first: they stop even if this process's own rclpy teardown
                # hangs (as rclpy's destroy_node has in nodes), which the watchdog then ends
                _stop(suite)
                stopped = True
                spin.TeardownWatchdog()
    except KeyboardInterrupt:
        pass
    if not stopped:
        _stop(suite)
    return 0


def _stop(suite) -> None:
    started = time.monotonic()
    codes = suite.stop()
    print(f'stopped in {time.monotonic() - started:.1f} s: '
          + ', '.join(f'{n} ({c})' for n, c in codes.items()), flush=True)


class _Ready:
    """Prints 'ready' once every node answers (launcher.AnswerCheck) and joint_states and probe
    readings flow; or, after READY_TIMEOUT, which nodes do not answer."""

    def __init__(self, suite, node) -> None:
        self._suite, self._node = suite, node
        self._pending: dict | None = {}
        self.forget(list(suite.specs))
        self._deadline = time.monotonic() + READY_TIMEOUT

    def forget(self, keys: list[str]) -> None:
        """Ask these nodes again (restarted: a call to the old process never answers)."""
        from cobot_calib_ros.api.launcher import AnswerCheck
        for key in keys:
            if self._pending is not None:
                if key in self._pending:
                    self._pending[key].close()
                self._pending[key] = AnswerCheck(self._node, self._suite.specs[key].full_name)

    def close(self) -> None:
        for check in (self._pending or {}).values():
            check.close()
        self._pending = None

    def check(self, stop) -> None:
        from cobot_calib_ros.api.client import CallError, wait_for_suite
        if self._pending is None:
            return
        for key in [k for k, c in self._pending.items() if c.answered()]:
            self._pending.pop(key).close()
        if self._pending and time.monotonic() > self._deadline:
            self._deadline = float('inf')
            print(f'not ready after {READY_TIMEOUT:.0f} s: {", ".join(self._pending)} do not '
                  f'answer (see their logs in {self._suite.log_dir})', file=sys.stderr,
                  flush=True)
        if self._pending:
            return
        self._pending = None
        running = {spec.name for spec in self._suite.specs.values()}
        try:
            wait_for_suite(self._node, READY_TIMEOUT, stop=stop, nodes=running)
        except CallError as e:
            print(f'not ready: {e}', file=sys.stderr, flush=True)
            return
        if not stop():
            print(f'ready: all {len(self._suite.specs)} nodes answer', flush=True)


class _Respawn:
    """A node that exits is started again, as launch's respawn, and said so; one that exits
    QUICK_EXITS times in a row within QUICK_EXIT s of its start is left down (named)."""

    def __init__(self, suite, node, news) -> None:
        self._suite, self._node, self._news = suite, node, news   # news: SuitePublisher
        self._started = {key: time.monotonic() for key in suite.processes}
        self._quick = dict.fromkeys(suite.processes, 0)
        self._restarts = dict.fromkeys(suite.processes, 0)
        self._down: set[str] = set()
        self._coming_back: dict = {}     # restarted, not answering yet: key -> AnswerCheck
        self._answer_by: dict[str, float] = {}  # of those, not yet said late: key -> deadline

    def check(self) -> list[str]:
        """Restart the nodes that exited; the keys of those restarted. A restarted node that
        answers is said so; one that does not within READY_TIMEOUT is named with its log,
        once (it runs: not restarted again)."""
        restarted = [key for key, code in self._suite.failed().items()
                     if key not in self._down and self._exited(key, code)]
        for key, answer in list(self._coming_back.items()):
            if answer.answered():
                self._forget(key)
                print(f'{key}: restarted and answering again', flush=True)
            elif time.monotonic() > self._answer_by.get(key, math.inf):
                del self._answer_by[key]
                print(f'{key}: restarted {READY_TIMEOUT:.0f} s ago and does not answer yet '
                      f'(its process runs; log: {self._suite.log_path(key)})',
                      file=sys.stderr, flush=True)
        return restarted

    def forget_all(self) -> None:
        for key in list(self._coming_back):
            self._forget(key)

    def _forget(self, key: str) -> None:
        if key in self._coming_back:
            self._coming_back.pop(key).close()
        self._answer_by.pop(key, None)

    def _exited(self, key: str, code: int) -> bool:
        quick = time.monotonic() - self._started[key] < QUICK_EXIT
        self._quick[key] = self._quick[key] + 1 if quick else 0
        full_name = self._suite.specs[key].full_name
        self._news.exited(full_name, code, left_down=self._quick[key] >= QUICK_EXITS)
        print(f'{key} exited with code {code}; last log lines:\n{self._suite.log_tail(key)}',
              file=sys.stderr, flush=True)
        if self._quick[key] >= QUICK_EXITS:
            self._down.add(key)
            self._forget(key)
            print(f'{key} exited {QUICK_EXITS} times within {QUICK_EXIT:.0f} s of its start: '
                  f'not restarted again; the other nodes keep running (log: '
                  f'{self._suite.log_path(key)})', file=sys.stderr, flush=True)
            return False
        from cobot_calib_ros.api.launcher import AnswerCheck
        self._restarts[key] += 1
        self._forget(key)
        self._suite.restart(key)
        self._news.started(full_name, self._suite.processes[key].pid)
        self._started[key] = time.monotonic()
        self._coming_back[key] = AnswerCheck(self._node, self._suite.specs[key].full_name)
        self._answer_by[key] = time.monotonic() + READY_TIMEOUT
        print(f'{key}: restarting (restart {self._restarts[key]}); the other nodes keep '
              'running', file=sys.stderr, flush=True)
        return True
