"""`cobot-calib check user-frame`: a quick health check of the active user frame on the
running suite (core.health_checks): touch a few markers, compare with where the frame and its
calibration's residuals put them, print the robot time and the verdict, store the check as a
result of the cell. Exit 0: pass, 1: recalibrate (or the check could not run)."""
from __future__ import annotations

import json

from cobot_calib_ros.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                                        fail, ros_node, say)
from cobot_calib_ros.cli.db import add_db_options
from cobot_calib_ros.paths import DEFAULT_CELL

DEFAULT_POINTS = ('P1', 'P3', 'P5')


def add_parser(subparsers):
    p = subparsers.add_parser('check', help='quick health check of the active user frame '
                                            '(a few touches, far less robot time than a '
                                            'calibration)')
    p.add_argument('what', choices=['user-frame'], help='what to check')
    p.add_argument('--points', nargs='+', default=list(DEFAULT_POINTS),
                   help='cell points to touch (default P1 P3 P5)')
    p.add_argument('--tolerance-mm', type=float, default=0.2,
                   help='largest point error that passes [mm] (default 0.2, the drift WARN)')
    p.add_argument('--robot-cell', default=DEFAULT_CELL, help='cell YAML path or name '
                   '(its markers and tool)')
    p.add_argument('--namespace', default='', help="the suite's namespace (up --namespace)")
    p.add_argument('--json', action='store_true', help='the stored check as one JSON line')
    add_db_options(p)
    return p


def run(args) -> int:
    import numpy as np
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core import kinematics
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.health_checks import check_user_frame, PASS, predicted_points
    from cobot_calib_ros.core.robot_port import PortError
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.kinematics import chain_of
    from cobot_calib_ros.store.records import check_record
    try:
        cell = load_cell(paths.cell_file(args.robot_cell))
    except CellFileError as e:
        return fail(str(e), EXIT_USAGE)
    unknown = [n for n in args.points if cell.marker(n) is None]
    if unknown or len(args.points) < 1:
        return fail(f'unknown point(s) {unknown}; the cell has {cell.point_names}', EXIT_USAGE)
    repo = store.open(paths.data_dir(args.data_dir), args.db, args.cell or (
        args.namespace.strip('/').replace('/', '.') or None))
    try:
        active = repo.user_frames.active()
        model = kinematics.model_for(cell)
        kinematic = repo.kinematics.resolve(active.get('kinematics') or 'nominal', model.name) \
            if active else None
    except (OSError, KeyError) as exc:
        return fail(f'check: {exc}')
    if active is None:
        return fail('check: no active user frame in this cell\'s results; calibrate first '
                    '(cobot-calib teach, or call calibrate_user_frame)')
    chain = chain_of(kinematic, model, cell.tool_offset)
    p_user = np.array([cell.marker(n).nominal_top for n in args.points])
    predicted = predicted_points(active['inputs'], active['result'], args.points, p_user)
    say(args, f'checking {active["id"]} at {", ".join(args.points)} '
              f'(kinematics {active.get("kinematics") or "nominal"})')
    from cobot_calib_ros.ros import spin
    from cobot_calib_ros.ros.robot_calls import RobotCalls
    with ros_node('cobot_calib_check', args.namespace.strip('/')) as node:
        robot = RobotCalls(spin.Companion(node, 'clients'))
        try:
            check = check_user_frame(robot, chain, predicted, args.points,
                                     args.tolerance_mm * 1e-3)
        except PortError as exc:
            return fail(f'check stopped: {exc}; nothing stored')
        except KeyboardInterrupt:
            return fail('check interrupted; nothing stored', EXIT_INTERRUPTED)
    record = check_record(check, 'user_frame', active['id'])
    try:
        repo.checks.save(record)
    except OSError as exc:
        return fail(f'check: {check.message()}; could not store it: {exc}')
    if args.json:
        print(json.dumps(record))
    else:
        for name, error in zip(check.names, check.errors):
            print(f'  {name}: {np.linalg.norm(error) * 1e3:.3f} mm  '
                  f'({", ".join(f"{e * 1e3:+.3f}" for e in error)})')
        print(f'robot time: {check.robot_seconds:.1f} s')
        print(check.message())
        print(f'stored as {record["id"]}')
    return EXIT_OK if check.verdict == PASS else EXIT_FAILED
