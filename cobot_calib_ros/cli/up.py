"""`cobot-calib up`: start the node suite and keep it running until Ctrl-C."""
from __future__ import annotations

import signal
import sys
import time

from cobot_calib_ros.cli.common import domain_id, EXIT_FAILED, EXIT_USAGE, fail, ros_node
from cobot_calib_ros.paths import DEFAULT_CELL

# Discovery before starting: the first node of a running suite showed up within 0.1 s in
# most runs, after 1.6 s at worst (25 runs).
CHECK_MIN_WAIT = 2.5     # [s]
CHECK_MAX_WAIT = 3.0     # [s]


def add_parser(subparsers):
    p = subparsers.add_parser(
        'up', help='start the node suite (Ctrl-C stops it)',
        description='Start the node suite on the exported ROS_DOMAIN_ID (Ctrl-C stops it). '
                    'Refuses if suite nodes already run on that domain.')
    p.add_argument('--cell', default=DEFAULT_CELL, help='cell YAML path or name '
                   '(sawyer_close, iiwa7_close)')
    p.add_argument('--layout', default='', help='marker layout of the cell (close, wide); '
                   'default: the cell file\'s own')
    p.add_argument('--force', action='store_true',
                   help='start even if suite nodes already run on this ROS_DOMAIN_ID')
    return p


def run(args) -> int:
    from cobot_calib_ros import paths
    from cobot_calib_ros.api import launcher
    cell = paths.cell_file(args.cell)
    if not cell.is_file():
        names = ', '.join(sorted(p.stem for p in (paths.config_dir() / 'cells').glob('*.yaml')))
        return fail(f'cell file {cell} not found; give a cell YAML path or a name ({names})',
                    EXIT_USAGE)
    problem = cell_problem(cell, args.layout)
    if problem:
        return fail(f'{problem}; nothing started', EXIT_USAGE)
    layout = {'layout': args.layout} if args.layout else {}
    specs = launcher.suite_specs(args.cell, overrides={
        n: layout for n in ('mock_robot', 'user_frame_solver', 'repeatability_trial')})
    if not args.force:
        running = running_nodes(['/' + spec.name for spec in specs])
        if running:
            return fail(f'the node suite already runs on ROS_DOMAIN_ID={domain_id()} '
                        f'({", ".join(running)}); stop it, export another ROS_DOMAIN_ID, '
                        'or pass --force to start a second one anyway')
    return _serve(launcher.Suite(launcher.default_log_dir()), specs)


def cell_problem(path, layout: str) -> str:
    """'' if both parts of the cell file are usable, else file:line: key: what is expected.

    `up` starts the mock robot, so it checks the simulation part too, before any node runs.
    """
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.sim.scenario import load_simulation
    try:
        load_simulation(path, layout or None)
    except CellFileError as e:
        return str(e)
    return ''


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


def _serve(suite, specs) -> int:
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    suite.start(specs)
    print(f'node suite up on ROS_DOMAIN_ID={domain_id()}: {", ".join(suite.processes)}')
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
