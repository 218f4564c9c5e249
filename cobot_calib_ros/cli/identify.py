"""`cobot-calib identify`: kinematic identification from sphere coupling (second paper).

``--source mock``: on the node suite (a private one unless --attach), collect_sphere_data
brings the coupling onto each sphere in the pose grid, two laser-tracker sets are measured for
validation (in the calibrated volume and spread over the workspace, 125 each as the paper's
Table 4), then identify_kinematics identifies, validates, stores and activates the result.
``--source FOLDER``: a collection folder written by collect_sphere_data (identified by the
suite), or a folder of MUKCa sphere-socket data (``<location>/hole_{0,1}.csv``), identified
offline with one location held out at a time.
``--measurement KIND``: any arm from its URDF (or a DH table) and a measurement file, offline
and held out (cli/identify_measured.py).
"""
from __future__ import annotations

import contextlib
import json
from pathlib import Path

from cobot_calib_ros.api.identification import PAPER_RATIO_PERCENT
from cobot_calib_ros.cli import identify_measured
from cobot_calib_ros.cli.common import (cell_problem, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK,
                                        EXIT_USAGE, fail, say)
from cobot_calib_ros.paths import DEFAULT_CELL

CELLS = {'iiwa7': 'iiwa7_close', 'sawyer': DEFAULT_CELL,   # --robot: its default cell
         'ur10e': 'ur10e_close'}


def add_parser(subparsers):
    p = subparsers.add_parser(
        'identify', help='identify the robot\'s kinematic errors from sphere coupling',
        description=__doc__.split('\n\n')[0] + ' Collects on the mock robot, identifies, '
                    'validates against a laser tracker and stores a calibrated model.')
    p.add_argument('--robot', choices=sorted(CELLS), default=None,
                   help='robot of the default cell (iiwa7 -> iiwa7_close, sawyer -> '
                        'sawyer_close, ur10e -> ur10e_close); default iiwa7')
    p.add_argument('--cell', default=None, help='cell file (path or name); overrides --robot')
    p.add_argument('--source', default='mock',
                   help='mock (collect now), a collection folder, a bag with '
                        '/cobot_calib/captures, or a MUKCa data folder')
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
                   help='--planned: at most this many poses (default 100)')
    p.add_argument('--target-mm', type=float, default=0.0,
                   help='--planned: stop once the predicted max error in the calibrated '
                        'volume is at most this [mm] (default: off)')
    p.add_argument('--min-gain', type=float, default=0.0,
                   help='--planned: stop once the predicted max error falls by less than this '
                        'fraction per pose over 10 poses, e.g. 0.01 (default: off)')
    p.add_argument('--validation-configs', type=int, default=125,
                   help='laser-tracker configurations per validation set (0: none)')
    p.add_argument('--dry-run', action='store_true', help='identify and validate, store nothing')
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
    identify_measured.add_arguments(p)
    return p


def run(args) -> int:
    if args.max_configs < 0 or args.validation_configs < 0 or not args.hold > 0:
        return fail('--max-configs and --validation-configs must be >= 0, --hold > 0 [s]',
                    EXIT_USAGE)
    problem = cell_problem(args.cell) if args.cell else ''
    if problem:
        return fail(f'identify: {problem}', EXIT_USAGE)
    if args.max_poses < 0 or args.target_mm < 0 or not 0 <= args.min_gain < 1:
        return fail('--max-poses and --target-mm must be >= 0, --min-gain in [0, 1)',
                    EXIT_USAGE)
    if (args.max_poses or args.target_mm or args.min_gain) and not args.planned:
        return fail('--max-poses, --target-mm and --min-gain apply to --planned; add it',
                    EXIT_USAGE)
    if args.planned and args.max_configs:
        return fail('--planned chooses its poses; drop --max-configs (or use --max-poses)',
                    EXIT_USAGE)
    if args.measurement:
        return identify_measured.run(args)
    if args.source != 'mock':
        folder = Path(args.source).expanduser()
        if not folder.is_dir():
            return fail(f'--source {args.source}: not mock and not a folder; give mock, a '
                        'collection folder or a MUKCa data folder', EXIT_USAGE)
        if any(folder.glob('*/hole_0.csv')):
            return _mukca(args, folder)
        if (folder / 'metadata.yaml').is_file() or any(folder.glob('*.mcap')):
            return _bag(args, folder)
        if not (folder / 'collection.yaml').is_file():
            return fail(f'{folder}: not a collection folder (collection.yaml), a bag '
                        '(metadata.yaml) or MUKCa data (<location>/hole_0.csv)', EXIT_USAGE)
    cell = args.cell or CELLS[args.robot or 'iiwa7']
    from cobot_calib_ros.api import identification, launcher
    from cobot_calib_ros.ros.calls import CallError, Interrupted
    from cobot_calib_ros.ros import interrupts
    resume, collected = '', False
    if args.resume is not None:
        try:
            resume, collected = _resumable(args.resume, cell)
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
    _print(args, report)
    return EXIT_OK


def _resume_command(args, collection_id: str) -> str:
    robot = f' --cell {args.cell}' if args.cell else f' --robot {args.robot}' if args.robot \
        else ''
    return f'cobot-calib identify{robot}{" --attach" if args.attach else ""} --resume ' \
        f'{collection_id}'


def _resumable(given: str, cell: str) -> tuple[str, bool]:
    """(collection id, complete?) for --resume [ID]: the given id, else the newest unfinished
    sphere collection of the cell's robot in the data dir ($COBOT_CALIB_DATA, the suite's
    default). An id not in this data dir is sent as it is (an attached suite may store
    elsewhere). ValueError when there is nothing to resume."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.files import check_id
    collections = store.open(paths.data_dir('')).collections
    if given:
        stored = collections.load(check_id(given))
        return given, stored is not None and stored.meta['status'] == 'done'
    robot = load_cell(paths.cell_file(cell)).robot
    for meta in collections.list_collections():
        if meta['source'] == 'spheres' and meta['robot'] == robot and meta['status'] != 'done':
            return meta['id'], False
    raise ValueError(f'no unfinished {robot} sphere collection in {collections.directory}; give '
                     'its id (--resume ID)')


def _print(args, report: dict) -> None:
    if args.json:
        print(json.dumps(report, indent=2))
        return
    print(f'\n{report["message"]}')
    verdict = identify_measured.verdict_of(report)     # a suite's report has none: passed
    print('gate: passed (converged, every deviation within its bound, validation no worse '
          'than nominal)' if verdict.passed else f'gate: {verdict.line()}')
    spheres = report.get('collections', {}).get('spheres', {})
    if 'robot_s' in spheres:
        print(f'robot time of the sphere collection: {spheres["robot_s"]:.1f} s '
              f'({spheres["robot_s_at_paper_hold"]:.1f} s at the paper\'s 1 s hold)')
    if 'stop_reason' in spheres:
        print(f'planned collection stopped on {spheres["stop_reason"]}')
    print(f'dropped (not identifiable or tied to the world frame): '
          f'{", ".join(report["dropped_parameters"])}')
    _print_parameters(report['identified'])
    for key, title in (('validation', 'calibrated volume'),
                       ('validation_workspace', 'workspace spread')):
        rows = report[key]
        if not rows:
            continue
        print(f'\nabsolute error, laser tracker, {title} ({rows["nominal"]["count"]} '
              'configurations) [mm]   (the paper\'s Table 5)')
        print(f'{"":<12}{"mean":>9}{"std":>9}{"min":>9}{"max":>9}')
        for name in ('calibrated', 'nominal'):
            r = rows[name]
            print(f'{name:<12}{r["mean_mm"]:9.3f}{r["std_mm"]:9.3f}{r["min_mm"]:9.3f}'
                  f'{r["max_mm"]:9.3f}')
        print(f'max calibrated / nominal: {rows["ratio_max_percent"]:.1f} % (paper, on its '
              f'spread: {PAPER_RATIO_PERCENT} %)')
    if report['calibration_id']:
        print(f'\nstored and active: {report["calibration_id"]}\n  {report["yaml_path"]}\n'
              f'  {report["urdf_path"]}')


def _print_parameters(identified: list[dict]) -> None:
    """Each parameter as its deviation from nominal (as the paper's tables) and absolute, in
    mm (lengths) or mrad (angles); the ± is one standard deviation of the identified value."""
    width = max([14] + [len(p['name']) + 1 for p in identified])    # URDF joint names are long
    print(f'\n{"parameter":<{width}}{"deviation":>16}{"std":>12}{"nominal":>16}{"identified":>16}')
    for p in identified:
        length = not p['name'].startswith(('alpha', 'theta', 'roll', 'pitch', 'yaw'))
        unit = 'mm' if length else 'mrad'
        value, nominal, std = (p[k] * 1e3 for k in ('value', 'nominal', 'std'))
        print(f'{p["name"]:<{width}}{value - nominal:>+11.4f} {unit:<4}{std:>7.4f} {unit:<4}'
              f'{nominal:>11.4f} {unit:<4}{value:>11.4f} {unit}')


def _bag(args, folder: Path) -> int:
    """A recorded sphere session (api.identification.identify_from_bag)."""
    from cobot_calib_ros.api.identification import identify_from_bag
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.core.errors import Refusal
    try:
        report, outcome = identify_from_bag(folder, args.cell or CELLS[args.robot or 'iiwa7'],
                                            solver=args.solver, loss=args.loss,
                                            max_configs=args.max_configs)
    except BagError as e:
        return fail(f'identify: {e}')
    except Refusal as e:
        return fail(f'identify {folder}: {e}', EXIT_FAILED)
    except (KeyError, ValueError) as e:
        return fail(str(e) if str(folder) in str(e) else f'{folder}: {e}', EXIT_FAILED)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print(args, report)
        print(f'\n{outcome.table}')
    if not outcome.verdict.passed:
        return fail(f'identify {folder}: {outcome.verdict.line()}', EXIT_FAILED)
    return EXIT_OK


def _mukca(args, folder: Path) -> int:
    """Real MUKCa sphere-socket data: the measurement path (spheres, one location held out at
    a time; MUKCa's metric is the held-out mean distance of the ball centre from its socket's
    centroid), with its gates."""
    args.measurement = 'spheres'
    return identify_measured.run(args)
