"""`cobot-calib intrinsics`: a camera's intrinsics from images of a ChArUco board (a folder of
images or a bag), written as the ROS camera_info YAML and, for a cell, stored as its camera's
intrinsics record (active when its gate passes: the detector, hand-eye and landmark paths then
use it instead of the nominal CameraInfo). No ROS graph is needed. With --planned or --live
instead of SOURCE: camera_calibrator's calibrate_intrinsics on the running suite (the arm moves
the camera through planned views, or the user moves the board in front of it).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail, print_message

EPILOG = """\
examples:
  cobot-calib intrinsics shots/ \\
      --board charuco:squares=7x5,square=0.03,marker=0.022,dict=DICT_4X4_50
  cobot-calib intrinsics run1/ --cell ur10e_close --model rational_polynomial --json
  cobot-calib intrinsics --planned --views 54          # on the running suite

SOURCE: a folder of images (png, jpg, ...) or a rosbag2 bag (its --topic of sensor_msgs/Image).
--model: plumb_bob (k1 k2 p1 p2 k3), rational_polynomial (k1..k6, p1 p2) or equidistant
  (fisheye k1..k4). Errors are RMS reprojection errors [px]; held out: each view's error
  when the intrinsics are fitted without it (k-fold).
"""


def add_parser(subparsers):
    from cobot_calib_ros.bags.images import DEFAULT_TOPIC
    from cobot_calib_ros.core.landmarks.intrinsics import MODELS
    p = subparsers.add_parser(
        'intrinsics', help='camera intrinsics from board images (folder or bag); camera_info '
                           'YAML and record', description=__doc__.strip(), epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('source', metavar='SOURCE', nargs='?', help='a folder of images or a bag')
    live = p.add_mutually_exclusive_group()
    live.add_argument('--planned', action='store_true', help='on the running suite: the arm '
                      'moves the camera through --views planned views (camera_calibrator)')
    live.add_argument('--live', action='store_true', help='on the running suite: --views '
                      'views of the live topic while you move the board (camera_calibrator)')
    p.add_argument('--views', type=int, default=0, help='--planned / --live: views to take '
                   '(default 20; >= 4)')
    p.add_argument('--model', choices=MODELS, default='plumb_bob',
                   help='distortion model (default plumb_bob)')
    p.add_argument('--board', metavar='SPEC', help="the ChArUco board (default: the cell's)")
    p.add_argument('--cell', metavar='NAME', help='the cell whose camera this is: its board '
                   'and camera frame are the defaults, the result is stored as its record')
    p.add_argument('--camera-name', metavar='NAME', help="camera_name in the YAML and the "
                   "record's camera (default: the cell's camera frame, else 'camera')")
    p.add_argument('--topic', default=DEFAULT_TOPIC, help=f'image topic of a bag (default '
                   f'{DEFAULT_TOPIC})')
    p.add_argument('--every', type=int, default=1, metavar='N',
                   help="a bag's every N-th image only (default 1)")
    p.add_argument('--output', metavar='YAML', help='the camera_info YAML to write (default: '
                   "<data dir>/intrinsics/<record id>.yaml with --cell, else ./<camera>.yaml)")
    p.add_argument('--data-dir', help='results root (default $COBOT_CALIB_DATA or '
                   '~/.ros/cobot_calib)')
    p.add_argument('--db', metavar='URL', help='results database (default the data dir\'s)')
    p.add_argument('--json', action='store_true', help='one JSON object')
    return p


def run(args) -> int:
    from cobot_calib_ros import paths
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.core.landmarks.targets import BoardSpec
    from cobot_calib_ros.loaders import load_cell
    if args.planned or args.live:
        if args.source:
            return fail('give SOURCE or --planned / --live, not both', EXIT_USAGE)
        return _on_the_suite(args)
    if not args.source:
        return fail('give SOURCE (a folder of images or a bag), or --planned / --live',
                    EXIT_USAGE)
    if args.every < 1:
        return fail(f'bad --every {args.every}: 1 or more', EXIT_USAGE)
    cell = None
    if args.cell:
        try:
            cell = load_cell(paths.cell_file(args.cell))
        except CellFileError as e:
            return fail(f'bad --cell: {e}', EXIT_USAGE)
    spec_text = args.board or (cell.landmarks.board if cell and cell.landmarks else '')
    if not spec_text:
        return fail('no board: give --board SPEC or a --cell whose landmarks: have a board',
                    EXIT_USAGE)
    try:
        spec = BoardSpec.parse(spec_text)
    except ValueError as e:
        return fail(f'bad --board: {e}', EXIT_USAGE)
    camera_name = args.camera_name or (cell.camera.frame_id if cell and cell.camera
                                       else 'camera')
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.core.errors import Refusal
    from cobot_calib_ros.core.landmarks.intrinsics_capture import fit_views
    from cobot_calib_ros.core.landmarks.intrinsics_views import detect_views
    try:
        views, skipped, size = detect_views(_images(args), spec)
    except (ValueError, OSError, BagError, Refusal) as e:
        return fail(f'intrinsics: {e}', EXIT_USAGE)
    if size is None:
        return fail(f'intrinsics: {args.source}: no images', EXIT_FAILED)
    run = fit_views(views, skipped, size, args.model, camera_name)
    if not run:
        cause = run.code.name
        if args.json:
            print_message({'error': cause, 'message': run.message, 'views': len(views),
                           'skipped': dict(skipped)}, True)
        return fail(f'intrinsics refused ({cause}): {run.message}; '
                    f'{_what_was_read(views, skipped)}')
    return _report(args, cell, run, spec)


SKIPS_SHOWN = 5     # skipped images named in a refusal


def _what_was_read(views, skipped) -> str:
    """How many images were read, how many showed the board, and why the first others did
    not (what the detector found in them)."""
    line = f'{len(views) + len(skipped)} images read, {len(views)} with the board'
    if skipped:
        line += ('; skipped: ' + '; '.join(f'{name}: {why}' for name, why in
                                           skipped[:SKIPS_SHOWN])
                 + (f' (and {len(skipped) - SKIPS_SHOWN} more)' if len(skipped) > SKIPS_SHOWN
                    else ''))
        if not views:
            line += '; images of another board? check --board (squares, dict)'
    return line


def _images(args):
    source = Path(args.source)
    if not source.exists():
        raise OSError(f'{source}: no such folder or bag (give a folder of images or a rosbag2 '
                      'bag)')
    if source.is_dir() and not (source / 'metadata.yaml').exists() and not any(
            source.glob('*.mcap')) and not any(source.glob('*.db3')):
        from cobot_calib_ros.loaders.images import folder_images
        return folder_images(source)
    from cobot_calib_ros.bags.images import bag_images
    return bag_images(source, args.topic, args.every)


def _report(args, cell, run, spec) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.api.intrinsics import store_run
    from cobot_calib_ros.store.cells import ResultsCell
    fit, views, skipped = run.fit, run.views, run.skipped
    data_dir = paths.data_dir(args.data_dir)
    yaml_path = Path(args.output) if args.output else \
        None if cell is not None else Path(f'{fit.camera.name}.yaml')
    repo = None if cell is None else store.open(data_dir, args.db, ResultsCell.of(cell))
    outcome = store_run(run, source=str(args.source), board=str(spec), repo=repo,
                        data_dir=data_dir, yaml_path=yaml_path)
    if not outcome:
        return fail(f'intrinsics: {outcome.message}', EXIT_FAILED)
    record = outcome.record
    stored = {} if cell is None else {'record': record.id, 'active': outcome.active,
                                      'not_active_because': outcome.not_active_because}
    K = fit.camera.K
    out = {'camera': fit.camera.name, 'model': fit.model,
           'image_size': [fit.camera.width, fit.camera.height],
           'fx': float(K[0, 0]), 'fy': float(K[1, 1]), 'cx': float(K[0, 2]),
           'cy': float(K[1, 2]), 'distortion': [float(d) for d in fit.camera.D],
           'rms_px': round(fit.rms_px, 4),
           'heldout_rms_px': record.result.heldout_rms_px and round(fit.heldout_rms_px, 4),
           'views': len(views), 'views_used': fit.views_used,
           'outlier_views': list(fit.outlier_views),
           'skipped': {name: why for name, why in skipped},
           'coverage': round(fit.coverage.fraction, 3), 'missing': fit.coverage.message,
           'gate_problem': fit.gate_problem, 'yaml_path': record.result.yaml_path, **stored}
    if args.json:
        print_message(out, True)
    else:
        print(f'{fit.camera.name}: {fit.model}, {fit.camera.width}x{fit.camera.height} px, '
              f'{fit.views_used} of {len(views)} views ({len(skipped)} images skipped)')
        print(f'  fx {K[0, 0]:.3f}  fy {K[1, 1]:.3f}  cx {K[0, 2]:.3f}  cy {K[1, 2]:.3f} px')
        print('  distortion ' + ' '.join(f'{d:.6g}' for d in fit.camera.D))
        print(f'  rms {fit.rms_px:.4f} px, held out {fit.heldout_rms_px:.4f} px')
        if fit.outlier_views:
            print(f'  outlier views (dropped): {", ".join(fit.outlier_views)}')
        print(f'  coverage {100 * fit.coverage.fraction:.0f} % of the image'
              + (f'; {fit.coverage.message}' if fit.coverage.message else ''))
        print(f'  gate: {fit.gate_problem or "passes"}')
        print(f'  wrote {record.result.yaml_path}')
        if stored:
            state = 'active' if stored['active'] else \
                f'not active: {outcome.not_active_because}'
            print(f'  stored {record.id} for cell {cell.name}, {state}')
    return EXIT_OK


def _on_the_suite(args) -> int:
    """calibrate_intrinsics on the running suite; prints its result."""
    from cobot_calib_msgs.action import CalibrateIntrinsics
    from cobot_calib_ros.api.intrinsics import calibrate_on_suite
    from cobot_calib_ros.cli.common import EXIT_INTERRUPTED, ros_node, say
    from cobot_calib_ros.ros.calls import CallError, Interrupted
    if args.views and args.views < 4:
        return fail(f'--views {args.views}: need at least 4 (default 20)', EXIT_USAGE)

    def feedback(msg) -> None:
        fb = msg.feedback
        say(args, f'  {fb.views}/{fb.total} views, {100 * fb.coverage:.0f} % of the image'
            + (f'; {fb.missing}' if fb.missing else ''))

    goal = CalibrateIntrinsics.Goal(model=args.model, views=args.views, planned=args.planned)
    with ros_node('cobot_calib_intrinsics') as node:
        try:
            result = calibrate_on_suite(node, goal, feedback)
        except CallError as e:
            return fail(f'intrinsics calibration failed: {e}', EXIT_FAILED)
        except Interrupted as e:        # Ctrl-C: the goal is cancelled, nothing stored
            return fail(f'intrinsics calibration cancelled (Ctrl-C): {e.message}',
                        EXIT_INTERRUPTED)
    k = list(result.camera_info.k)
    out = {'error_code': result.error_code, 'message': result.message,
           'calibration_id': result.calibration_id, 'fx': k[0], 'fy': k[4], 'cx': k[2],
           'cy': k[5], 'distortion': list(result.camera_info.d), 'rms_px': result.rms_px,
           'heldout_rms_px': result.heldout_rms_px, 'views_used': result.views_used,
           'outlier_views': list(result.outlier_views), 'yaml_path': result.yaml_path,
           'active': result.active}
    if args.json:
        print_message(out, True)
    if result.error_code != 0:          # REJECTED: stored, not active; the rest: nothing
        return fail(f'intrinsics calibration failed: {result.message}', EXIT_FAILED)
    if not args.json:
        print(result.message)
    return EXIT_OK
