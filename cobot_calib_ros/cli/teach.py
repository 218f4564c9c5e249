"""`cobot-calib teach`: calibrate the user frame the way the first paper's operators do.

For each point the operator is told which marker to touch, guides the tool tip onto it (hand
guiding, or jogging from the pendant), holds still and confirms with Enter (or a call to the
``~/confirm`` service of this command's node, ``/cobot_calib_teach/confirm``); the joints are
captured by ``joint_state_monitor``. Then ``calibrate_user_frame`` maps the captures through
the solver's kinematic model and fits the frame, and the result is printed with residuals
(the session itself: api.teach).

On the mock robot (it offers ``get_ground_truth``) the operator's hand guiding is simulated:
before each confirmation the mock is sent a ``move_to`` TOUCH of the point.
"""
from __future__ import annotations

import json

from cobot_calib_ros.api.teach import NODE_NAME, TeachError, TeachSession
from cobot_calib_ros.cli.common import (EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, fail, ros_node,
                                        say)
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.paths import DEFAULT_CELL


def add_parser(subparsers):
    p = subparsers.add_parser(
        'teach', help='calibrate the user frame by touching points (Enter or ~/confirm)',
        description=__doc__.split('\n\n')[0] + ' Uses the suite on the exported ROS_DOMAIN_ID.')
    p.add_argument('--points', nargs='+', metavar='P', help='cell points to touch, in order '
                   '(default: every point of the cell layout)')
    p.add_argument('--method', default='rigid',
                   help='three_point | five_point_lsq | rigid | robust (default rigid)')
    p.add_argument('--cell', default=DEFAULT_CELL, help='cell YAML path or name')
    p.add_argument('--layout', default='', help='marker layout of the cell (default: its own)')
    p.add_argument('--hold', type=float, default=0.5, help='capture window per point [s]')
    p.add_argument('--simulate-touch', choices=('auto', 'yes', 'no'), default='auto',
                   help='send the mock a TOUCH before each confirmation (auto: when the '
                        'suite has get_ground_truth, i.e. the mock robot)')
    p.add_argument('--timeout', type=float, default=600.0,
                   help='[s] to wait for each confirmation')
    p.add_argument('--json', action='store_true', help='print the result as one JSON object')
    return p


def run(args) -> int:
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    problem = options_problem(args)
    if problem is not None:
        return fail(f'{problem.message}; nothing was touched', EXIT_USAGE)
    try:
        cell = load_cell(cell_file(args.cell), args.layout or None)
        cell.require('teach (its points are the layout\'s markers; a points file: '
                     'cobot-calib user-frame --points)', 'layouts')
    except CellFileError as e:
        return fail(str(e), EXIT_USAGE)
    names = args.points or cell.point_names
    unknown = [n for n in names if cell.marker(n) is None]
    if unknown:
        return fail(f'unknown point(s) {unknown}; the cell has {cell.point_names}', EXIT_USAGE)
    with ros_node(NODE_NAME) as node:
        session = TeachSession(node, args, cell, lambda text: say(args, text))
        try:
            return report(args, *session.run(names))
        except TeachError as e:
            return fail(f'teach stopped: {e}')
        except KeyboardInterrupt:
            return fail('teach interrupted; nothing was stored', EXIT_INTERRUPTED)


def options_problem(args) -> Failure | None:
    """None if --method, --hold and --timeout can be used, else an INVALID_INPUT Failure saying
    why not: checked before the first touch, not after the last."""
    import math
    from cobot_calib_ros.core.user_frame import METHODS
    from cobot_calib_ros.core.user_frame.landmarks import LANDMARK_METHODS
    if args.method not in METHODS:
        why = ('measures the frame with the wrist camera, not from touches (cobot-calib call '
               f'calibrate_user_frame "{{method: {args.method}}}")'
               if args.method in LANDMARK_METHODS else 'is not a method')
        return Failure(ErrorCode.INVALID_INPUT,
                       f'--method {args.method} {why}; teach can use: {", ".join(METHODS)}')
    for option, value in (('--hold', args.hold), ('--timeout', args.timeout)):
        if not (math.isfinite(value) and value > 0.0):
            return Failure(ErrorCode.INVALID_INPUT, f'{option} {value:g}: give a time > 0 [s]')
    return None


def report(args, res, captures) -> int:
    """Print the calibration (or why it was refused); the exit code."""
    from cobot_calib_msgs.srv import CalibrateUserFrame
    from cobot_calib_ros.ros.types import to_dict
    if res.error_code != CalibrateUserFrame.Response.SUCCESS:
        return fail(f'calibration refused (code {res.error_code}): {res.message}; the '
                    'captures were not stored, teach again')
    if args.json:
        print(json.dumps({'calibration': to_dict(res.calibration),
                          'joint_captures': [to_dict(c) for c in captures],
                          'message': res.message}))
    else:
        _print_result(args, res.calibration)
    return EXIT_OK


def _print_result(args, cal) -> None:
    t, r = cal.transform.transform.translation, cal.transform.transform.rotation
    say(args, f'\ncalibration {cal.id} ({cal.method}): stored and published on user_frame '
              'and /tf_static')
    say(args, f'  {cal.transform.header.frame_id} -> {cal.transform.child_frame_id}: '
              f'xyz ({t.x * 1e3:.3f}, {t.y * 1e3:.3f}, {t.z * 1e3:.3f}) mm, '
              f'quaternion xyzw ({r.x:.6f}, {r.y:.6f}, {r.z:.6f}, {r.w:.6f})')
    say(args, f'  residual RMS {cal.rms_residual * 1e3:.4f} mm, max '
              f'{cal.max_residual * 1e3:.4f} mm')
    for p in cal.residuals:
        flag = '  (outlier, not used)' if p.outlier else ''
        say(args, f'    {p.name}: {p.residual_norm * 1e3:.4f} mm{flag}')

