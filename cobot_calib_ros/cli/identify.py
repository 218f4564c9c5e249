"""`cobot-calib identify`: kinematic identification from sphere coupling (second paper).

``--source mock``: on the node suite (a private one unless --attach), collect_sphere_data
brings the coupling onto each sphere in the pose grid, two laser-tracker sets are measured for
validation (in the calibrated volume and spread over the workspace, 125 each as the paper's
Table 4), then identify_kinematics identifies, validates, stores and activates the result.
``--source PATH``: identified offline by api.identification.identify_source (loaders.sources
recognises a measurement CSV with its sidecar, a MUKCa folder, a bag or a collection folder);
``--attach`` with a collection folder identifies it on the running suite instead.
``--measurement KIND``: any arm from its URDF (or a DH table) and a measurement file, held out.
This module parses the arguments and prints (cli/identify_report.py).
"""
from __future__ import annotations

import contextlib
import math

from cobot_calib_ros.api.identification import DEFAULT_FOLDS
from cobot_calib_ros.cli.common import (cell_problem, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK,
                                        EXIT_USAGE, fail, say)
from cobot_calib_ros.cli.identify_report import print_report, verdict_line
from cobot_calib_ros.core.kinematics.identification.gates import (MAX_DEVIATION_M,
                                                                   MAX_DEVIATION_RAD)
from cobot_calib_ros.paths import DEFAULT_CELL

CELLS = {'iiwa7': 'iiwa7_close', 'sawyer': DEFAULT_CELL,   # --robot: its default cell
         'ur10e': 'ur10e_close'}
MODELS = ('offsets', 'full', 'mdh', 'offsets+compliance', 'full+compliance',
          'mdh+compliance')


def add_parser(subparsers):
    p = subparsers.add_parser(
        'identify', help='identify the robot\'s kinematic errors from sphere coupling',
        description=__doc__.split('\n\n')[0] + ' Collects on the mock robot, identifies, '
                    'validates against a laser tracker and stores a calibrated model.')
    p.add_argument('--robot', choices=sorted(CELLS), default=None,
                   help='robot of the default cell (iiwa7 -> iiwa7_close, sawyer -> '
                        'sawyer_close, ur10e -> ur10e_close); default iiwa7')
    p.add_argument('--cell', default=None, help='cell file (path or name); overrides --robot. '
                   'A measurement file\'s result is stored under this cell (its robot must '
                   'be the --urdf arm), else under the arm\'s name')
    p.add_argument('--source', default='mock',
                   help='mock (collect now), a collection folder, a bag with '
                        '/cobot_calib/captures, a MUKCa data folder or a measurement file')
    p.add_argument('--solver', default='lm', choices=('lm', 'nelder-mead'))
    p.add_argument('--loss', default='soft_l1', choices=('soft_l1', 'linear', 'huber'))
    p.add_argument('--max-configs', type=int, default=0,
                   help='sphere poses to collect/use, an even subset (default all: 3 x 625 '
                        'on 7-joint robots)')
    p.add_argument('--hold', type=float, default=0.05,
                   help='[s] joints averaged per pose (default 0.05; the paper held 1 s)')
    p.add_argument('--planned', action='store_true',
                   help='plan the sphere poses: each chosen from a wider grid by how much it '
                        'lowers the predicted error in the calibrated volume, with a stopping '
                        'rule; prints the prediction after every pose')
    p.add_argument('--max-poses', type=int, default=0,
                   help='--planned: at most this many poses (default 50)')
    p.add_argument('--target-mm', type=float, default=0.0,
                   help='--planned: stop once the predicted max error in the calibrated '
                        'volume is at most this [mm] (default: off)')
    p.add_argument('--min-gain', type=float, default=0.0,
                   help='--planned: stop once the predicted max error falls by less than this '
                        'fraction per pose over 10 poses, e.g. 0.01 (default: off)')
    p.add_argument('--validation-configs', type=int, default=125,
                   help='laser-tracker configurations per validation set (0: none)')
    p.add_argument('--dry-run', '--no-store', dest='dry_run', action='store_true',
                   help='identify and validate, store nothing (every source; without it a '
                        'result that passes its gate is stored, written back as URDF (and a '
                        'UR arm\'s kinematics YAML) and made active)')
    from cobot_calib_ros.cli.db import DATA_DIR_HELP
    p.add_argument('--data-dir', default=None, help=DATA_DIR_HELP + '; offline sources')
    p.add_argument('--db', default=None, help='database URL (default $COBOT_CALIB_DB, else the '
                                              'folder store of the data dir); offline sources')
    p.add_argument('--urdf', default=None,
                   help='the robot\'s URDF (MUKCa data: default iiwa14.urdf beside the folder)')
    p.add_argument('--ball', type=float, nargs=3, default=(0.0, 0.0, 0.04), metavar=('X', 'Y', 'Z'),
                   help='MUKCa data: nominal ball centre in tool0 [m] (default 0 0 0.04)')
    p.add_argument('--resume', nargs='?', const='', default=None, metavar='ID',
                   help='carry on the sphere collection ID (default: the newest unfinished one '
                        'of the robot) from its last stored pose, then validate and identify')
    p.add_argument('--attach', action='store_true',
                   help='use the suite running on ROS_DOMAIN_ID instead of starting one')
    p.add_argument('--json', action='store_true')
    _measurement_arguments(p)
    return p


def _measurement_arguments(p) -> None:
    p.add_argument('--measurement', choices=('spheres', 'points', 'pose', 'plane'),
                   default=None, help='identify offline from --source, a measurement file '
                   '(CSV + YAML sidecar, README "Measurement files") or a MUKCa folder')
    p.add_argument('--base-link', default=None,
                   help='--urdf: the chain\'s first link (default: the sidecar\'s frames.base)')
    p.add_argument('--tip-link', default=None,
                   help='--urdf: the chain\'s last link (default: the sidecar\'s frames.tip)')
    p.add_argument('--dh', default=None, help='a DH table (YAML) instead of --urdf')
    p.add_argument('--model', choices=MODELS, default=None,
                   help='error model: offsets (one per joint, any robot), full (--urdf: '
                        'every joint origin; its default), mdh (--dh: every DH row; its '
                        'default); +compliance adds a joint deflection in proportion to its '
                        'gravity torque')
    p.add_argument('--max-deviation-mm', type=float, default=MAX_DEVIATION_M * 1e3,
                   metavar='MM', help='the most a length of the model may move from nominal '
                   f'[mm] (default {MAX_DEVIATION_M * 1e3:g}); a determined parameter that ends '
                   'there is refused (one the data do not determine is held at nominal)')
    p.add_argument('--max-deviation-mrad', type=float, default=MAX_DEVIATION_RAD * 1e3,
                   metavar='MRAD', help='the same for angles [mrad] (default '
                   f'{MAX_DEVIATION_RAD * 1e3:g}; a zero offset may move 350 mrad)')
    held = p.add_mutually_exclusive_group()
    held.add_argument('--folds', type=int, default=None, metavar='K',
                      help=f'k-fold validation, row i in fold i %% K (default {DEFAULT_FOLDS})')
    held.add_argument('--leave-out', default=None, metavar='COLUMN',
                      help='hold out one group (a value of COLUMN) at a time')


def run(args) -> int:
    if args.max_configs < 0 or args.validation_configs < 0 or not args.hold > 0:
        return fail('--max-configs and --validation-configs must be >= 0, --hold > 0 [s]',
                    EXIT_USAGE)
    problem = cell_problem(args.cell) if args.cell else None
    if problem is not None:
        return fail(f'identify: {problem.message}', EXIT_USAGE)
    if args.max_poses < 0 or args.target_mm < 0 or not 0 <= args.min_gain < 1:
        return fail('--max-poses and --target-mm must be >= 0, --min-gain in [0, 1)',
                    EXIT_USAGE)
    if (args.max_poses or args.target_mm or args.min_gain) and not args.planned:
        return fail('--max-poses, --target-mm and --min-gain apply to --planned; add it',
                    EXIT_USAGE)
    if args.planned and args.max_configs:
        return fail('--planned chooses its poses; drop --max-configs (or use --max-poses)',
                    EXIT_USAGE)
    if args.source != 'mock' or args.measurement:
        from cobot_calib_ros.loaders import sources
        try:
            kind = sources.recognise(args.source)
        except ValueError as e:
            return fail(f'identify: --source {e}; or mock (collect now)', EXIT_USAGE)
        if not (args.attach and kind == sources.COLLECTION) or args.measurement:
            return offline(args)
    cell = args.cell or CELLS[args.robot or 'iiwa7']
    from cobot_calib_ros.api import identification, launcher
    from cobot_calib_ros.ros.calls import CallError, Interrupted
    from cobot_calib_ros.ros import interrupts
    resume, collected = '', False
    if args.resume is not None:
        try:
            resume, collected = identification.resumable(args.resume, cell)
        except ValueError as e:
            return fail(f'identify --resume: {e}', EXIT_USAGE)
    suite = contextlib.nullcontext() if args.attach else launcher.private_suite(
        cell, say=lambda text: say(args, text))
    try:
        with interrupts.deferred(), suite:
            client = identification.IdentifyClient()
            try:
                report = identification.identify_on_suite(
                    client, say=lambda text: say(args, text), source=args.source,
                    solver=args.solver, loss=args.loss, max_configs=args.max_configs,
                    hold=args.hold, validation_configs=args.validation_configs,
                    dry_run=args.dry_run, resume=resume, collected=collected,
                    planned=args.planned, max_poses=args.max_poses, target_mm=args.target_mm,
                    min_gain=args.min_gain)
            finally:
                client.close()
    except identification.CollectionStopped as e:
        return fail(f'identify stopped (Ctrl-C): {e.message}; the poses measured so far are '
                    f'stored: resume with: {_resume_command(args, e.collection_id)}',
                    EXIT_INTERRUPTED)
    except Interrupted as e:
        return fail(f'identify stopped (Ctrl-C): {e.message}', EXIT_INTERRUPTED)
    except (CallError, identification.IdentificationFailed) as e:
        hint = f'; then resume with: {_resume_command(args, e.collection_id)}' if getattr(
            e, 'collection_id', '') else ''
        return fail(f'identify failed: {e}{hint}')
    report['unseen'] = _suite_unseen(cell, report['dropped'])
    print_report(report, args.json)
    return EXIT_OK


def _suite_unseen(cell: str, dropped: list[dict]) -> list[dict]:
    """What the suite's sphere coupling (one point on the tool) cannot see, on the cell's
    model (core writeback.unseen; the stored record names the same)."""
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.core.kinematics.identification.writeback import unseen
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    try:
        model = model_for(load_cell(cell_file(cell)))
    except ValueError:           # checked before the suite ran; an attached suite's own cell
        return []
    return unseen(model, 'spheres', 1, dropped)


def offline(args) -> int:
    """--source PATH identified offline (api.identification.identify_source), printed; exit 1
    with one line for what the gates refuse, 2 for input that does not fit."""
    from cobot_calib_ros.api.identification import identify_source, IdentificationFailed
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.core.errors import Refusal
    for flag, value in (('--max-deviation-mm', args.max_deviation_mm),
                        ('--max-deviation-mrad', args.max_deviation_mrad)):
        if not (math.isfinite(value) and value > 0.0):
            return fail(f'identify: {flag} must be a finite number > 0, got {value}', EXIT_USAGE)
    from cobot_calib_ros.loaders import sources
    measured = args.measurement or sources.recognise(args.source) in (
        sources.MEASUREMENT_FILE, sources.MUKCA)
    try:
        report = identify_source(
            args.source, cell=args.cell if measured else args.cell or CELLS[args.robot or 'iiwa7'],
            data_dir=args.data_dir, db=args.db,
            measurement=args.measurement, urdf=args.urdf, base_link=args.base_link,
            tip_link=args.tip_link, dh=args.dh, model=args.model, folds=args.folds,
            leave_out=args.leave_out, ball=args.ball, solver=args.solver, loss=args.loss,
            max_configs=args.max_configs, store=not args.dry_run,
            max_deviation=(args.max_deviation_mm * 1e-3, args.max_deviation_mrad * 1e-3))
    except Refusal as e:
        return fail(f'identify {args.source}: {e}', EXIT_FAILED)
    except (BagError, IdentificationFailed) as e:
        return fail(f'identify: {e}', EXIT_FAILED)
    except ValueError as e:
        return fail(f'identify: {e}', EXIT_USAGE)
    except OSError as e:
        return fail(f'identify: could not store the result: {e}; check --data-dir / --db')
    print_report(report, args.json)
    if not report['verdict']['passed']:
        return fail(f'identify {args.source}: {verdict_line(report)}', EXIT_FAILED)
    return EXIT_OK


def _resume_command(args, collection_id: str) -> str:
    robot = f' --cell {args.cell}' if args.cell else f' --robot {args.robot}' if args.robot \
        else ''
    return f'cobot-calib identify{robot}{" --attach" if args.attach else ""} --resume ' \
        f'{collection_id}'
