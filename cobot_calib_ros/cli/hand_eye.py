"""`cobot-calib hand-eye`: calibrate the wrist camera's hand-eye on the running suite."""
from __future__ import annotations

import json

from cobot_calib_ros.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, fail, ros_node,
                                        say)


def add_parser(subparsers):
    p = subparsers.add_parser(
        'hand-eye', help='calibrate the wrist camera (hand_eye_calibrator, calibrate_hand_eye)',
        description='Send a calibrate_hand_eye goal to the running suite and wait for it: the '
                    'robot views the cell\'s ChArUco board from VIEWS poses; the result '
                    '(flange -> optical frame) is stored and made active, and the landmark '
                    'methods use it from then on. The board is found by the active user-frame '
                    'calibration: calibrate the user frame with points first.')
    p.add_argument('--views', type=int, default=0, help='views to take (default 12; >= 3)')
    p.add_argument('--against-truth', metavar='CELL', default=None,
                   help="mock robot only: print the error against its true hand-eye, and the "
                        "CELL file's nominal one's (a path or name, e.g. sawyer_close)")
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    return p


def run(args) -> int:
    from geometry_msgs.msg import TransformStamped
    from cobot_calib_ros.ros.calls import CallError, Interrupted
    from cobot_calib_ros.api.hand_eye import calibrate_hand_eye, error_against_truth
    from cobot_calib_ros.core import frames
    from cobot_calib_ros.ros import convert
    if args.views and args.views < 3:
        return fail(f'--views {args.views}: need at least 3 (default 12)', 2)

    def feedback(msg) -> None:
        fb = msg.feedback
        say(args, f'  view {fb.view_index + 1}/{fb.total}: board '
            f'{"seen" if fb.board_seen else "not seen"} ({fb.used} used, {fb.skipped} skipped)')

    with ros_node('cobot_calib_hand_eye') as node:
        try:
            result = calibrate_hand_eye(node, args.views, feedback=feedback)
            if result.error_code != 0:
                return fail(f'hand-eye calibration failed: {result.message}', EXIT_FAILED)
            X = convert.transform_to_matrix(TransformStamped(transform=result.t_flange_optical))
            out = {'calibration_id': result.calibration_id, 'views_used': result.views_used,
                   'views_skipped': result.views_skipped,
                   'residual_mm': result.residual_mm, 'residual_mrad': result.residual_mrad,
                   'T_flange_optical': X.tolist(),
                   'rotvec_rad': frames.to_vector(X)[3:].tolist()}
            if args.against_truth:
                from cobot_calib_ros.loaders import load_cell
                from cobot_calib_ros import paths
                cell = load_cell(paths.cell_file(args.against_truth))
                if cell.camera is None:
                    return fail(f'cell {cell.name!r} has no camera: no nominal hand-eye', 2)
                error = error_against_truth(node, X, cell.camera.T_flange_optical)
                out.update(error_mm=error.position_m * 1e3, error_mrad=error.rotation_rad * 1e3,
                           nominal_error_mm=error.nominal_position_m * 1e3,
                           nominal_error_mrad=error.nominal_rotation_rad * 1e3)
        except CallError as e:
            return fail(f'hand-eye calibration failed: {e}', EXIT_FAILED)
        except Interrupted as e:       # Ctrl-C: the goal is cancelled, nothing stored
            return fail(f'hand-eye calibration cancelled (Ctrl-C): {e.message}',
                        EXIT_INTERRUPTED)
    if args.json:
        print(json.dumps(out))
    else:
        print(f'hand-eye {out["calibration_id"]}: {out["views_used"]} views used '
              f'({out["views_skipped"]} skipped), residual {out["residual_mm"]:.3f} mm / '
              f'{out["residual_mrad"]:.3f} mrad')
        print(f'  translation {X[:3, 3].round(5).tolist()} m, rotation vector '
              f'{[round(v, 5) for v in out["rotvec_rad"]]} rad')
        if 'error_mm' in out:
            print(f'  error against the truth: {out["error_mm"]:.3f} mm / '
                  f'{out["error_mrad"]:.3f} mrad (nominal: {out["nominal_error_mm"]:.3f} mm / '
                  f'{out["nominal_error_mrad"]:.3f} mrad)')
    return EXIT_OK
