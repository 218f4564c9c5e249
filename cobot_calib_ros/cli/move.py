"""`cobot-calib move --xyz X Y Z --rpy R P Y`: move a tool to a pose, solved with the calibrated
model (api.move: the suite solves, move_to gets joints)."""
from __future__ import annotations

import json

from cobot_calib_ros.cli.common import (EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail, ros_node, say)
from cobot_calib_ros.cli.db import add_db_options


def add_parser(subparsers):
    from cobot_calib_ros.core.rig import TOOLS
    p = subparsers.add_parser(
        'move', help='move a tool to a pose with the calibrated kinematics',
        description='Solve the pose of a tool (in the base or a user frame) with the active '
                    'kinematic calibration (or the nominal model, or a given one) and send '
                    'the joints to move_to: the controller\'s own nominal model is bypassed, '
                    'so the tool lands where the calibration says.')
    p.add_argument('--xyz', type=float, nargs=3, required=True, metavar=('X', 'Y', 'Z'),
                   help='tool position in the frame [m]')
    p.add_argument('--rpy', type=float, nargs=3, required=True, metavar=('R', 'P', 'Y'),
                   help='tool orientation in the frame: roll pitch yaw [rad] (fixed axes x y z)')
    p.add_argument('--frame', choices=('base', 'user'), default='base',
                   help='the pose\'s frame: the robot base (default) or a user frame')
    p.add_argument('--user-frame', default='', metavar='ID',
                   help='with --frame user: the user frame calibration id (default: the '
                        'active one)')
    p.add_argument('--tool', choices=TOOLS, default='tcp',
                   help='the tool whose pose is given: the cell\'s tcp (default), the flange, '
                        'the wrist camera (its optical frame; the active hand-eye) or the '
                        'sphere coupling (its identified centre)')
    p.add_argument('--kinematics', default='active',
                   help="'active' (the robot's active kinematic calibration, nominal if none; "
                        "default), 'nominal', a calibration id, or its <id>.json file")
    p.add_argument('--speed-scale', type=float, default=0.0,
                   help='0..1 of the joint velocity limits (0: the robot\'s default)')
    p.add_argument('--robot-cell', default='',
                   help="cell file (path or name); default: the running suite's "
                        '(its user_frame_solver\'s cell_file)')
    p.add_argument('--namespace', default='', help="the suite's namespace (up --namespace)")
    p.add_argument('--dry-run', action='store_true',
                   help='solve and print the joints, do not move')
    p.add_argument('--json', action='store_true', help='the outcome as one JSON line')
    add_db_options(p)
    return p


def run(args) -> int:
    import math
    import numpy as np
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.api import move
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.frames import from_xyz_rpy
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.store.cells import ResultsCell
    if not all(math.isfinite(v) for v in (*args.xyz, *args.rpy)):
        return fail('move: --xyz and --rpy take finite numbers [m, rad]', EXIT_USAGE)
    if args.user_frame and args.frame != 'user':
        return fail('move: --user-frame goes with --frame user', EXIT_USAGE)
    if not 0.0 <= args.speed_scale <= 1.0:
        return fail(f'move: --speed-scale {args.speed_scale}: give 0..1', EXIT_USAGE)
    T_frame_tool = from_xyz_rpy(args.xyz, args.rpy)
    with ros_node('cobot_calib_move', args.namespace.strip('/')) as node:
        try:
            cell = load_cell(paths.cell_file(args.robot_cell or move.suite_cell(node)))
            repo = store.open(paths.data_dir(args.data_dir), args.db,
                              ResultsCell(args.cell, cell.robot) if args.cell
                              else ResultsCell.of(cell, args.namespace))
            seed = move.current_joints(node, model_for(cell).joint_names)
            solved = move.solve(cell, repo, T_frame_tool, seed, frame=args.frame,
                                frame_id=args.user_frame, tool=args.tool,
                                kinematics=args.kinematics)
        except (CellFileError, ValueError) as exc:
            return fail(f'move: {exc}', EXIT_USAGE)
        except (OSError, CallError) as exc:
            return fail(f'move: {exc}')
        where = f'user frame {solved.user_frame}' if solved.user_frame else 'base'
        summary = {**solved.summary(), 'frame': where, 'tool': args.tool,
                   'positions': solved.q.tolist(), 'moved': False}
        for stale in solved.stale:
            say(args, f'stale: {stale.line()}')
        tool = f' ({solved.tool_record})' if solved.tool_record else ''
        say(args, f'{args.tool}{tool} to {where} xyz {list(args.xyz)} rpy {list(args.rpy)} '
                  f'with the {solved.kinematics} model: joints '
                  f'[{", ".join(f"{v:.6f}" for v in solved.q)}] rad')
        if not args.dry_run:
            try:
                result = move.move_joints(node, solved.q, args.speed_scale)
            except CallError as exc:
                return fail(f'move: {exc}')
            if result.error_code != result.SUCCESS:
                return fail(f'move: move_to: {result.message}', EXIT_FAILED)
            summary.update(moved=True, duration=result.duration,
                           reached=np.asarray(result.positions).tolist())
            say(args, f'reached ({result.message}, {result.duration:.2f} s)')
    if args.json:
        print(json.dumps(summary))
    return EXIT_OK
