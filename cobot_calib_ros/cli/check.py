"""`cobot-calib check user-frame | kinematics`: quick health checks on the running suite
(core.health_checks), each far less robot time than the calibration it checks; prints the
robot time and the verdict and stores the check as a result of the cell.

- user-frame: touch a few markers, compare with where the active frame and its calibration's
  residuals put them;
- kinematics: a few sphere-coupling poses (16), the spread of the centres the active kinematic
  calibration (nominal if none) predicts.

Exit 0: pass, 1: recalibrate (or the check could not run)."""
from __future__ import annotations

from cobot_calib_ros.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                                        fail, ros_node, say)
from cobot_calib_ros.cli.db import add_db_options
from cobot_calib_ros.paths import DEFAULT_CELL

SUITE_WAIT = 5.0        # [s] for the robot's calls to be discovered (a running suite: < 2 s)


def add_parser(subparsers):
    p = subparsers.add_parser('check', help='quick health check of the active user frame '
                                            '(a few touches, far less robot time than a '
                                            'calibration)')
    p.add_argument('what', choices=['user-frame', 'kinematics'], help='what to check')
    p.add_argument('--poses', type=int, default=None,
                   help='kinematics: sphere poses to visit (default 16)')
    p.add_argument('--points', nargs='+', default=None,
                   help='cell points to touch (default P1 P3 P5)')
    p.add_argument('--tolerance-mm', type=float, default=None,
                   help='user-frame: largest point error that passes [mm] (default 0.2, the '
                        'drift WARN); kinematics: largest RMS spread of the sphere centres '
                        '[mm] (default 0.1)')
    p.add_argument('--robot-cell', default=None, help='cell YAML path or name (its markers, '
                   "robot and tool; default: the running suite's, else " f'{DEFAULT_CELL})')
    p.add_argument('--namespace', default='', help="the suite's namespace (up --namespace)")
    p.add_argument('--json', action='store_true', help='the stored check as one JSON line')
    add_db_options(p)
    return p


def run(args) -> int:
    from cobot_calib_ros.cli.common import cell_problem
    if args.poses is not None and args.poses < 4:       # the user's input first (exit 2)
        return fail(f'check {args.what}: --poses {args.poses}: give 4 or more', EXIT_USAGE)
    problem = cell_problem(args.robot_cell) if args.robot_cell else None
    if problem is not None:
        return fail(problem.message, EXIT_USAGE)
    from cobot_calib_ros.ros import spin
    from cobot_calib_ros.ros.robot_calls import RobotCalls
    with ros_node('cobot_calib_check', args.namespace.strip('/')) as node:
        companion = spin.Companion(node, 'clients')
        try:
            robot = RobotCalls(companion)
            absent = robot.absent(SUITE_WAIT)
            if absent:      # every call would wait and fail: say so before anything else
                return fail(f'check {args.what}: {_no_suite(args, absent)}; nothing checked')
            from cobot_calib_ros import paths    # seconds of imports: after the refusal
            from cobot_calib_ros.api import check as checks
            from cobot_calib_ros.api.move import suite_cell
            from cobot_calib_ros.core.cell import CellFileError
            from cobot_calib_ros.core.errors import ErrorCode
            from cobot_calib_ros.loaders import load_cell
            try:
                cell = load_cell(paths.cell_file(args.robot_cell or suite_cell(node)))
            except CellFileError as e:
                return fail(str(e), EXIT_USAGE)
            repo = checks.open_results(cell, args.data_dir, args.db, args.cell, args.namespace)
            tolerance = None if args.tolerance_mm is None else args.tolerance_mm * 1e-3
            prepared = checks.prepare(args.what, cell, repo, poses=args.poses,
                                      points=args.points or checks.DEFAULT_POINTS,
                                      tolerance_m=tolerance)
            if not prepared:
                return fail(f'check {args.what}: {prepared.message}', EXIT_USAGE
                            if prepared.code == ErrorCode.INVALID_INPUT else EXIT_FAILED)
            say(args, prepared.announce)
            for line in prepared.stale:
                say(args, f'stale: {line.line()}')
            check = prepared.run(robot)
        except ValueError as exc:
            check = exc
        except KeyboardInterrupt:
            return fail('check interrupted; nothing stored', EXIT_INTERRUPTED)
        finally:
            companion.destroy()          # its thread stops before the session shuts down
    if isinstance(check, ValueError) or not check:
        return fail(f'check stopped: {getattr(check, "message", check)}; nothing stored')
    return _report(args, prepared, check)


def _no_suite(args, absent: list[str]) -> str:
    """Why the check cannot run: no suite at all, or which of its nodes are missing."""
    from cobot_calib_ros.cli.common import domain_id
    from cobot_calib_ros.ros.robot_calls import RobotCalls
    namespace = args.namespace.strip('/')
    where = f'ROS_DOMAIN_ID={domain_id()}' + (f' in namespace /{namespace}' if namespace
                                               else '')
    if len(absent) == len(RobotCalls.CALLS):
        return f'no suite running on {where}; start one with cobot-calib up'
    return (f'the suite on {where} is missing {", ".join(absent)}; start it whole with '
            'cobot-calib up')


def _report(args, prepared, check) -> int:
    import json
    import numpy as np
    from cobot_calib_ros.api.check import record
    from cobot_calib_ros.core.health_checks import PASS
    stored = record(prepared, check)
    if not stored:
        return fail(f'check: {stored.message}')
    if args.json:
        print(json.dumps(stored))
    else:
        for name, error in zip(prepared.points, getattr(check, 'errors', ())):
            print(f'  {name}: {np.linalg.norm(error) * 1e3:.3f} mm  '
                  f'({", ".join(f"{e * 1e3:+.3f}" for e in error)})')
        print(f'robot time: {check.robot_seconds:.1f} s')
        print(check.message())
        for stale in stored['stale']:
            print(f'stale: {stale["message"]}')
        print(f'stored as {stored["id"]}')
    return EXIT_OK if check.verdict == PASS else EXIT_FAILED
