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

DEFAULT_POINTS = ('P1', 'P3', 'P5')
SUITE_WAIT = 5.0        # [s] for the robot's calls to be discovered (a running suite: < 2 s)


def add_parser(subparsers):
    p = subparsers.add_parser('check', help='quick health check of the active user frame '
                                            '(a few touches, far less robot time than a '
                                            'calibration)')
    p.add_argument('what', choices=['user-frame', 'kinematics'], help='what to check')
    p.add_argument('--poses', type=int, default=None,
                   help='kinematics: sphere poses to visit (default 16)')
    p.add_argument('--points', nargs='+', default=list(DEFAULT_POINTS),
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
    problem = cell_problem(args.robot_cell) if args.robot_cell else ''
    if problem:
        return fail(problem, EXIT_USAGE)
    from cobot_calib_ros.core.robot_port import PortError
    from cobot_calib_ros.ros import spin
    from cobot_calib_ros.ros.robot_calls import RobotCalls
    from cobot_calib_ros.store.cells import ResultsCell
    with ros_node('cobot_calib_check', args.namespace.strip('/')) as node:
        companion = spin.Companion(node, 'clients')
        try:
            robot = RobotCalls(companion)
            absent = robot.absent(SUITE_WAIT)
            if absent:      # every call would wait and fail: say so before anything else
                return fail(f'check {args.what}: {_no_suite(args, absent)}; nothing checked')
            from cobot_calib_ros import paths, store    # seconds of imports: after the refusal
            from cobot_calib_ros.api.move import suite_cell
            from cobot_calib_ros.core import kinematics
            from cobot_calib_ros.core.cell import CellFileError
            from cobot_calib_ros.loaders import load_cell
            try:
                cell = load_cell(paths.cell_file(args.robot_cell or suite_cell(node)))
            except CellFileError as e:
                return fail(str(e), EXIT_USAGE)
            results_cell = (ResultsCell(args.cell, cell.robot) if args.cell
                            else ResultsCell.of(cell, args.namespace))
            repo = store.open(paths.data_dir(args.data_dir), args.db, results_cell)
            model = kinematics.model_for(cell)
            prepare = _user_frame if args.what == 'user-frame' else _kinematics
            try:
                prepared = prepare(args, cell, model, repo)
            except (OSError, KeyError, ValueError) as exc:
                return fail(f'check {args.what}: {exc.args[0] if exc.args else exc}',
                            EXIT_USAGE if isinstance(exc, ValueError) else EXIT_FAILED)
            method, against, run_check, print_details, stale = prepared
            check = run_check(robot)
        except (PortError, ValueError) as exc:
            return fail(f'check stopped: {exc}; nothing stored')
        except KeyboardInterrupt:
            return fail('check interrupted; nothing stored', EXIT_INTERRUPTED)
        finally:
            companion.destroy()          # its thread stops before the session shuts down
    return _report(args, repo, check, method, against, print_details, stale)


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


def _user_frame(args, cell, model, repo):
    """('user_frame', the active frame's id, the check, its printout, the stale results it
    uses) or ValueError/OSError."""
    import numpy as np
    from cobot_calib_ros.core.health_checks import check_user_frame, predicted_points
    from cobot_calib_ros.store.rigs import rig_of
    unknown = [n for n in args.points if cell.marker(n) is None]
    if unknown:
        raise ValueError(f'unknown point(s) {unknown}; the cell has {cell.point_names}')
    active = repo.user_frames.active()
    if active is None:
        raise KeyError(f'no active user frame in the results of cell {repo.cell}; calibrate '
                       'first (cobot-calib teach, or call calibrate_user_frame)')
    the_rig = rig_of(repo, cell, 'active', model)      # what programs move with
    chain = the_rig.chain('tcp')
    p_user = np.array([cell.marker(n).nominal_top for n in args.points])
    predicted = predicted_points(active['inputs'], active['result'], args.points, p_user)
    say(args, f'checking {active["id"]} at {", ".join(args.points)} '
              f'(kinematics {the_rig.active.kinematics_label}, TCP {the_rig.active.tcp_label})')
    stale = the_rig.active.stale_used('tcp', True)
    for line in stale:
        say(args, f'stale: {line.line()}')

    def details(check):
        for name, error in zip(check.names, check.errors):
            print(f'  {name}: {np.linalg.norm(error) * 1e3:.3f} mm  '
                  f'({", ".join(f"{e * 1e3:+.3f}" for e in error)})')
    return ('user_frame', active['id'], lambda robot: check_user_frame(
        robot, chain, predicted, args.points, **_tolerance(args)), details, stale)


def _kinematics(args, cell, model, repo):
    """('kinematics', the active calibration's id or 'nominal', the check, its printout, the
    stale results it uses)."""
    from cobot_calib_ros.core.health_checks import check_kinematics, KINEMATIC_POSES
    from cobot_calib_ros.core.kinematics import plans
    from cobot_calib_ros.store.rigs import rig_of
    if cell.spheres is None:
        raise ValueError(f'cell {cell.name!r} has no spheres (config/cells/iiwa7_close.yaml '
                         'has); give --robot-cell')
    poses = KINEMATIC_POSES if args.poses is None else args.poses
    the_rig = rig_of(repo, cell, 'active', model)
    chain = the_rig.chain('coupling')
    plan, _ = plans.sphere_plan(cell, model, poses)
    against = the_rig.active.kinematics_label
    stale = the_rig.active.stale_of(('kinematics',))
    for line in stale:
        say(args, f'stale: {line.line()}')
    say(args, f'checking the {model.name} model ({against}) on {len(plan)} sphere poses')
    return ('kinematics', against, lambda robot: check_kinematics(
        robot, chain, plan, **_tolerance(args)), lambda check: None, stale)


def _tolerance(args) -> dict[str, float]:
    """The check's tolerance_m if --tolerance-mm is given; else the check's own default."""
    return {} if args.tolerance_mm is None else {'tolerance_m': args.tolerance_mm * 1e-3}


def _report(args, repo, check, method: str, against: str, details, stale=()) -> int:
    import json
    from cobot_calib_ros.core.health_checks import PASS
    from cobot_calib_ros.store.records import check_record
    record = check_record(check, method, against)
    record['stale'] = [s.to_dict() for s in stale]      # core.provenance: one line each
    try:
        repo.checks.save(record)
    except OSError as exc:
        return fail(f'check: {check.message()}; could not store it: {exc}')
    if args.json:
        print(json.dumps(record))
    else:
        details(check)
        print(f'robot time: {check.robot_seconds:.1f} s')
        print(check.message())
        for stale in record['stale']:
            print(f'stale: {stale["message"]}')
        print(f'stored as {record["id"]}')
    return EXIT_OK if check.verdict == PASS else EXIT_FAILED
