"""`cobot-calib user-frame --points FILE`: a user frame from points measured offline (touched with
the pendant, or a laser tracker's), fitted, gated, stored and made active as
calibrate_user_frame does, with no suite (api.user_frame_file)."""
from __future__ import annotations

import json

from cobot_calib_ros.cli.common import (add_robot_options, EXIT_FAILED, EXIT_OK, EXIT_USAGE,
                                        fail, robot_cell, say)
from cobot_calib_ros.cli.db import add_db_options
from cobot_calib_ros.paths import DEFAULT_CELL


def add_parser(subparsers):
    from cobot_calib_ros.core.user_frame import METHODS
    p = subparsers.add_parser(
        'user-frame', help='a user frame from a points file (pendant touches or a tracker)',
        description=__doc__.split('\n\n')[0] + ' Points file: CSV name,user_x,user_y,user_z '
        'and either the joints of each touch [rad] (mapped through the active kinematics and '
        'TCP) or x,y,z [m] measured in the base (or the tracker frame: --base-from-tracker).')
    p.add_argument('--points', required=True, help='the points file (CSV, see above)')
    p.add_argument('--method', choices=METHODS, default='rigid',
                   help='the fit, as calibrate_user_frame\'s (default rigid)')
    p.add_argument('--base-from-tracker', type=float, nargs=6, default=None,
                   metavar=('X', 'Y', 'Z', 'ROLL', 'PITCH', 'YAW'),
                   help='x,y,z are in the tracker frame: the tracker frame\'s pose in the base '
                        '[m, rad] (the base registration)')
    p.add_argument('--kinematics', default='active',
                   help="touched points: the kinematic model their joints go through ('active', "
                        "default; 'nominal'; a calibration id)")
    p.add_argument('--max-rms-mm', type=float, default=1.0,
                   help='the gate: the largest RMS residual accepted [mm] (default 1, as '
                        'user_frame_solver\'s max_rms_error)')
    add_robot_options(p, f'cell file (path or name): the robot, its tool, base and user frame '
                         f'names (default {DEFAULT_CELL}; no layouts or simulation needed)')
    p.add_argument('--no-store', action='store_true', help='fit and gate, store nothing')
    p.add_argument('--json', action='store_true', help='the result as JSON')
    add_db_options(p)
    return p


def run(args) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.api.user_frame_file import calibrate_from_file
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.errors import ErrorCode, Refusal
    from cobot_calib_ros.core.frames import from_xyz_rpy
    from cobot_calib_ros.store.cells import ResultsCell
    if not args.max_rms_mm > 0:
        return fail(f'user-frame: --max-rms-mm must be > 0, got {args.max_rms_mm}', EXIT_USAGE)
    try:
        cell = robot_cell(args, DEFAULT_CELL)
    except (CellFileError, ValueError) as e:
        return fail(f'user-frame: {e}', EXIT_USAGE)
    T = None if args.base_from_tracker is None else from_xyz_rpy(args.base_from_tracker[:3],
                                                                  args.base_from_tracker[3:])
    try:
        repo = store.open(paths.data_dir(args.data_dir), args.db,
                          ResultsCell(args.cell) if args.cell else ResultsCell.of(cell))
        report = calibrate_from_file(repo, cell, args.points, method=args.method,
                                     kinematics=args.kinematics, T_base_tracker=T,
                                     max_rms_error=args.max_rms_mm * 1e-3,
                                     store=not args.no_store)
    except Refusal as e:
        if e.failure.code == ErrorCode.STORAGE_FAILED:
            return fail(f'user-frame: {e}')
        return fail(f'user-frame {args.points}: {e}; nothing stored', EXIT_FAILED)
    except KeyError as e:
        return fail(f'user-frame: --kinematics: {e.args[0]}', EXIT_USAGE)
    except ValueError as e:
        return fail(f'user-frame: {e}', EXIT_USAGE)
    except OSError as e:
        return fail(f'user-frame: could not store the result: {e}; check --data-dir / --db')
    if args.json:
        print(json.dumps(report))
        return EXIT_OK
    through = ', '.join(f'{k} {v}' for k, v in report['measured_through'].items()) or \
        'measured directly'
    state = 'stored and active' if report['active'] else 'stored, NOT active' \
        if report['stored'] else 'not stored (--no-store)'
    say(args, f'user frame {report["id"]} ({report["method"]}, {report["points"]} points, '
              f'{through}): RMS {report["rms_mm"]:.4f} mm, max {report["max_residual_mm"]:.4f} '
              f'mm; {state}')
    return EXIT_OK
