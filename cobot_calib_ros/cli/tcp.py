"""`cobot-calib tcp`: calibrate the tool centre point on the running suite (tcp_calibrator)
and print it as a pendant does: the TCP in the flange frame, mean and max residual."""
from __future__ import annotations

import json
import math

from cobot_calib_ros.cli.common import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                                        fail, ros_node, say)

METHODS = ('none', 'z', 'zx')


def add_parser(subparsers):
    p = subparsers.add_parser(
        'tcp', help='calibrate the tool centre point (tcp_calibrator, calibrate_tcp)',
        description='Send a calibrate_tcp goal to the running suite and wait for it: the tool '
                    'tip is brought to one fixed point of the cell from ORIENTATIONS tilted '
                    'approaches (on the mock by its simulated operator; on a real cell guide '
                    'the arm and call tcp_calibrator/confirm_touch for each), plus elongator '
                    'points for the orientation. The TCP is stored for its tool and made active '
                    'if its residual is explained by the touch noise.')
    p.add_argument('--tool', default='', help="the tool's name (default: the cell's tool)")
    p.add_argument('--point', default='', help="the fixed point (default: the cell's first)")
    p.add_argument('--orientations', type=int, default=0,
                   help='approaches of the point (default 6; at least 4)')
    p.add_argument('--tilt-deg', type=float, default=0.0,
                   help='tilt of the approaches from the first [deg] (default 30)')
    p.add_argument('--orientation', choices=METHODS, default='none',
                   help='none: position only (4-point); z: + an elongator point along the '
                        "tool's z (5-point); zx: + one along x (6-point)")
    p.add_argument('--elongation-mm', type=float, default=0.0,
                   help='distance of the elongator points [mm] (default 50)')
    p.add_argument('--hold', type=float, default=0.0,
                   help="joints averaged over this hold at each touch [s] (default: the node's)")
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    return p


def run(args) -> int:
    from cobot_calib_msgs.action import CalibrateTcp
    from geometry_msgs.msg import TransformStamped
    from cobot_calib_ros.api.tcp import calibrate_tcp
    from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
    from cobot_calib_ros.ros import convert
    from cobot_calib_ros.ros.calls import CallError, Interrupted
    if args.orientations and args.orientations < 4:
        return fail(f'tcp: --orientations {args.orientations}: need at least 4 (default 6)',
                    EXIT_USAGE)
    if args.tilt_deg < 0 or args.elongation_mm < 0 or args.hold < 0:
        return fail('tcp: --tilt-deg, --elongation-mm and --hold must not be negative',
                    EXIT_USAGE)
    goal = CalibrateTcp.Goal(
        tool=args.tool, point_name=args.point, orientations=args.orientations,
        tilt=math.radians(args.tilt_deg), orientation=METHODS.index(args.orientation),
        elongation=args.elongation_mm * 1e-3, hold=args.hold)

    def feedback(msg) -> None:
        fb = msg.feedback
        residual = f', residual {fb.residual_mm:.3f} mm' if fb.residual_mm else ''
        say(args, f'  touch {fb.touch_index + 1}/{fb.total}{residual}')

    with ros_node('cobot_calib_tcp') as node:
        try:
            result = calibrate_tcp(node, goal, feedback=feedback)
        except CallError as e:
            return fail(f'TCP calibration failed: {e}', EXIT_FAILED)
        except Interrupted as e:
            return fail(f'TCP calibration cancelled (Ctrl-C): {e.message}', EXIT_INTERRUPTED)
    if not result.calibration_id:       # nothing solved: no figures to show
        return fail(f'TCP calibration failed: {result.message}', EXIT_FAILED)
    T = convert.transform_to_matrix(TransformStamped(transform=result.t_flange_tool))
    p = result.fixed_point
    out = {'calibration_id': result.calibration_id, 'tool': result.tool,
           'active': result.active, 'xyz_mm': [float(v) * 1e3 for v in T[:3, 3]],
           'rpy_deg': [math.degrees(a) for a in rpy_from_matrix(T[:3, :3])],
           'mean_residual_mm': result.mean_residual_mm,
           'max_residual_mm': result.max_residual_mm, 'condition': result.condition,
           'orientations_used': result.orientations_used,
           'fixed_point_mm': [p.x * 1e3, p.y * 1e3, p.z * 1e3],
           'T_flange_tool': T.tolist(), 'message': result.message}
    if args.json:
        print(json.dumps(out))
    else:
        x, y, z = out['xyz_mm']
        a, b, c = out['rpy_deg']
        print(f'TCP of {result.tool}: {result.calibration_id} '
              f'({"active" if result.active else "NOT active"})')
        print(f'  X {x:.3f}  Y {y:.3f}  Z {z:.3f} mm   roll {a:.3f}  pitch {b:.3f}  '
              f'yaw {c:.3f} deg')
        print(f'  mean error {result.mean_residual_mm:.3f} mm, max error '
              f'{result.max_residual_mm:.3f} mm ({result.orientations_used} approaches, '
              f'condition {result.condition:.1f})')
        if not result.active:
            print(f'  {result.message}')
    return EXIT_OK if result.error_code == CalibrateTcp.Result.SUCCESS else EXIT_FAILED
