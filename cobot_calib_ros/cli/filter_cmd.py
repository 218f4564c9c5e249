"""`cobot-calib filter --targets FILE.csv --out FILE.csv`: a program's pose targets corrected for
a controller that keeps its nominal kinematics (core.kinematics.program_filter)."""
from __future__ import annotations

import json
from pathlib import Path

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail, say
from cobot_calib_ros.cli.db import add_db_options
from cobot_calib_ros.paths import DEFAULT_CELL


def add_parser(subparsers):
    from cobot_calib_ros.core.kinematics.program_filter import FORMAT_NAMES
    p = subparsers.add_parser(
        'filter', help='correct pose targets for a controller with nominal kinematics',
        description='Solve each target with the calibrated model, write the pose the nominal '
                    'model reaches at those joints (what the controller must be given) and the '
                    'joints. Targets: CSV name,x,y,z,qx,qy,qz,qw (tool pose, m, unit '
                    "quaternion), or name and a controller's values (--format). Nothing is "
                    'written unless every target can be reached; each one that cannot is '
                    'named.')
    p.add_argument('--targets', required=True, help='the program: CSV name,x,y,z,qx,qy,qz,qw')
    p.add_argument('--out', required=True, help='the filtered program (CSV: the same columns, '
                                                'then the joints [rad])')
    p.add_argument('--format', choices=FORMAT_NAMES, default='csv',
                   help="the pose columns, in and out: csv x,y,z,qx,qy,qz,qw [m] (default), or "
                        "a controller's values as `export` prints them (kuka X,Y,Z,A,B,C "
                        "[mm, deg], abb x,y,z,q1..q4 [mm], fanuc X,Y,Z,W,P,R, ur x,y,z,rx,ry,rz "
                        "[m, rad], yaskawa X,Y,Z,Rx,Ry,Rz)")
    p.add_argument('--frame', choices=('base', 'user'), default='base',
                   help="the targets' frame: the robot base, or the active user frame of the "
                        "cell's results (default base); the output is in the same frame")
    p.add_argument('--kinematics', default='active',
                   help="the calibrated model: 'active' (the robot's active kinematic "
                        "calibration, default), a calibration id, or its <id>.json file")
    p.add_argument('--tool', choices=('tcp', 'flange'), default='tcp',
                   help="the targets' tool: the cell's tool centre point (default) or the flange")
    p.add_argument('--robot-cell', default=DEFAULT_CELL,
                   help='cell file (path or name): the robot, its tool and home pose')
    p.add_argument('--json', action='store_true', help='the summary as one JSON line')
    add_db_options(p)
    return p


def run(args) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core import rig
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.core.kinematics.program_filter import (filter_targets, filtered_csv,
                                                                parse_targets)
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.cells import ResultsCell
    from cobot_calib_ros.store.files import atomic_write_text
    from cobot_calib_ros.store.rigs import active_set
    try:
        cell = load_cell(paths.cell_file(args.robot_cell))
        model = model_for(cell)
        targets = parse_targets(Path(args.targets).read_text(encoding='utf-8'), args.targets,
                                args.format)
    except (CellFileError, ValueError) as exc:
        return fail(f'filter: {exc}', EXIT_USAGE)
    except (OSError, UnicodeDecodeError) as exc:
        return fail(f'filter: --targets {args.targets}: cannot read ({exc})', EXIT_USAGE)
    try:
        repo = store.open(paths.data_dir(args.data_dir), args.db,
                          ResultsCell(args.cell) if args.cell else ResultsCell.of(cell))
        calibrated_rig = rig.Rig(cell, active_set(repo, cell, args.kinematics, model=model),
                                 model)
        record = calibrated_rig.active.kinematics
        if record is None:
            raise ValueError(f'no active kinematic calibration of the {model.name} in '
                             f'{repo.root}; identify one first, or give --kinematics ID or '
                             'FILE.json')
        calibrated = calibrated_rig.chain(args.tool)
        nominal = calibrated_rig.nominal_chain(args.tool)
        T_base_frame = calibrated_rig.T_base_user() if args.frame == 'user' else None
    except ValueError as exc:
        return fail(f'filter: {exc}', EXIT_USAGE)
    except OSError as exc:
        return fail(f'filter: {exc}')
    stale = calibrated_rig.active.stale_used(args.tool, args.frame == 'user')
    for line in stale:
        say(args, f'filter: stale: {line.line()}')
    result = filter_targets(targets, calibrated, nominal, cell.home, T_base_frame)
    if result.unreachable:
        for unreachable in result.unreachable:
            fail(f'filter: {unreachable.line()}')
        return fail(f'filter: {len(result.unreachable)} of {len(targets)} targets cannot be '
                    f'reached; nothing written to {args.out}', EXIT_FAILED)
    try:
        atomic_write_text(Path(args.out), filtered_csv(result.filtered, model.joint_names,
                                                          args.format))
    except OSError as exc:
        return fail(f'filter: --out {args.out}: {exc}')
    largest_mm = max(f.correction_m for f in result.filtered) * 1e3
    largest_mrad = max(f.correction_rad for f in result.filtered) * 1e3
    if args.json:
        print(json.dumps({'targets': len(targets), 'calibration': record.id,
                          'tool_record': calibrated_rig.active.tool_label(args.tool),
                          'stale': [s.to_dict() for s in stale],
                          'frame': args.frame, 'out': args.out,
                          'largest_correction_mm': largest_mm,
                          'largest_correction_mrad': largest_mrad}))
    else:
        say(args, f'filtered {len(targets)} targets with {record.id} ({args.frame} frame, '
                  f'tool {args.tool}): largest correction {largest_mm:.3f} mm, '
                  f'{largest_mrad:.3f} mrad -> {args.out}')
    return EXIT_OK
