"""`cobot-calib teach`: calibrate the user frame the way the first paper's operators do.

For each point the operator is told which marker to touch, guides the tool tip onto it (hand
guiding, or jogging from the pendant), holds still and confirms with Enter (or a call to the
``~/confirm`` service of this command's node, ``/cobot_calib_teach/confirm``); the joints are
captured by ``joint_state_monitor``. Then ``calibrate_user_frame`` maps the captures through
the solver's kinematic model and fits the frame, and the result is printed with residuals.

On the mock robot (it offers ``get_ground_truth``) the operator's hand guiding is simulated:
before each confirmation the mock is sent a ``move_to`` TOUCH of the point.
"""
from __future__ import annotations

import json
import select
import sys
import time

from cobot_calib_ros.cli.common import (EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, fail, ros_node,
                                        say)
from cobot_calib_ros.ros import interrupts

NODE_NAME = 'cobot_calib_teach'


def add_parser(subparsers):
    p = subparsers.add_parser(
        'teach', help='calibrate the user frame by touching points (Enter or ~/confirm)',
        description=__doc__.split('\n\n')[0] + ' Uses the suite on the exported ROS_DOMAIN_ID.')
    p.add_argument('--points', nargs='+', metavar='P', help='cell points to touch, in order '
                   '(default: every point of the cell layout)')
    p.add_argument('--method', default='rigid',
                   help='three_point | five_point_lsq | rigid | robust (default rigid)')
    p.add_argument('--cell', default='sawyer_close', help='cell YAML path or name')
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
    from cobot_calib_ros.core.cell import CellFileError, load_cell
    from cobot_calib_ros.paths import cell_file
    try:
        cell = load_cell(cell_file(args.cell), args.layout or None)
    except CellFileError as e:
        return fail(str(e), EXIT_USAGE)
    names = args.points or cell.point_names
    unknown = [n for n in names if cell.marker(n) is None]
    if unknown:
        return fail(f'unknown point(s) {unknown}; the cell has {cell.point_names}', EXIT_USAGE)
    with ros_node(NODE_NAME) as node:
        session = TeachSession(node, args, cell)
        try:
            return session.run(names)
        except TeachError as e:
            return fail(f'teach stopped: {e}')
        except KeyboardInterrupt:
            return fail('teach interrupted; nothing was stored', EXIT_INTERRUPTED)


class TeachError(RuntimeError):
    """The session cannot go on; the message says what to check."""


class TeachSession:
    """One teach run on one rclpy node: confirmations, captures, the final calibration."""

    def __init__(self, node, args, cell) -> None:
        from cobot_calib_msgs.srv import CalibrateUserFrame, CaptureJoints, GetGroundTruth
        from rclpy.executors import SingleThreadedExecutor
        from std_srvs.srv import Trigger
        self.node, self.args, self.cell = node, args, cell
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self._confirmed = False
        node.create_service(Trigger, '~/confirm', self._on_confirm)
        self.capture = node.create_client(CaptureJoints, 'capture_joints')
        self.calibrate = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        self.truth = node.create_client(GetGroundTruth, 'get_ground_truth')
        self._stdin_open = True

    def say(self, text: str) -> None:
        say(self.args, text)

    def run(self, names: list[str]) -> int:
        from cobot_calib_ros.api.client import spin_until
        for client in (self.capture, self.calibrate):
            if not spin_until(self.node, client.service_is_ready, 10.0, self.executor):
                raise TeachError(f'{client.srv_name} is not available; is the suite up '
                                 '(cobot-calib up) on this ROS_DOMAIN_ID?')
        simulate = self._simulate_touch()
        captures = [self._teach_point(name, i, len(names), simulate)
                    for i, name in enumerate(names)]
        return self._calibrate(names, captures)

    def _simulate_touch(self) -> bool:
        from cobot_calib_ros.api.client import spin_until
        if self.args.simulate_touch != 'auto':
            return self.args.simulate_touch == 'yes'
        return spin_until(self.node, self.truth.service_is_ready, 5.0, self.executor)

    # -- one point ------------------------------------------------------------------------
    def _teach_point(self, name: str, index: int, count: int, simulate: bool):
        x, y, z = self.cell.marker(name).nominal_top * 1e3
        self.say(f'[{index + 1}/{count}] {name}: guide the tool tip onto the top-face centre '
                 f'of marker {name} (user frame x {x:.1f} mm, y {y:.1f} mm, z {z:.1f} mm), '
                 f'hold still, then press Enter (or call /{NODE_NAME}/confirm)')
        if simulate:
            self._simulated_touch(name)
            self.say(f'      (mock robot: the operator\'s hand guided the tool onto {name})')
        self._wait_for_confirmation()
        return self._capture(name)

    def _simulated_touch(self, name: str) -> None:
        from cobot_calib_msgs.action import MoveTo
        from rclpy.action import ActionClient
        from cobot_calib_ros.api.client import CallError, run_action
        client = ActionClient(self.node, MoveTo, 'move_to')
        try:
            _, result = run_action(self.node, client, MoveTo.Goal(
                target_type=MoveTo.Goal.TARGET_TOUCH, point_name=name), 60.0,
                executor=self.executor)
        except CallError as e:
            raise TeachError(f'simulated touch of {name}: {e}')
        finally:
            client.destroy()
        if result.error_code != MoveTo.Result.SUCCESS:
            raise TeachError(f'simulated touch of {name}: {result.message}')

    def _on_confirm(self, request, response):
        self._confirmed = True
        response.success, response.message = True, 'confirmed'
        return response

    def _wait_for_confirmation(self) -> None:
        self._confirmed = False
        deadline = time.monotonic() + self.args.timeout
        while not self._confirmed:
            interrupts.check()
            if time.monotonic() > deadline:
                raise TeachError(f'no confirmation within {self.args.timeout:.0f} s')
            self.executor.spin_once(timeout_sec=0.02)
            self._read_enter()

    def _read_enter(self) -> None:
        if not self._stdin_open or not select.select([sys.stdin], [], [], 0.0)[0]:
            return
        line = sys.stdin.readline()
        if line == '':
            self._stdin_open = False
            self.say(f'      (standard input closed: waiting for /{NODE_NAME}/confirm)')
        elif line.strip().lower() in ('q', 'quit'):
            raise TeachError('quit by the operator; nothing was stored')
        else:
            self._confirmed = True

    def _capture(self, name: str):
        from cobot_calib_msgs.srv import CaptureJoints
        from sensor_msgs.msg import JointState
        from cobot_calib_ros.api.client import call_service, CallError
        try:
            res = call_service(self.node, self.capture,
                               CaptureJoints.Request(duration=self.args.hold),
                               self.args.hold + 10.0, self.executor)
        except CallError as e:
            raise TeachError(f'capture at {name}: {e}')
        if res.error_code != CaptureJoints.Response.SUCCESS:
            raise TeachError(f'capture at {name}: {res.message}')
        self.say(f'      captured {res.sample_count} samples, largest joint spread '
                 f'{max(res.std) * 1e6:.1f} urad')
        return JointState(name=list(res.name), position=list(res.position))

    # -- the calibration ------------------------------------------------------------------
    def _calibrate(self, names: list[str], captures) -> int:
        from cobot_calib_msgs.srv import CalibrateUserFrame
        from cobot_calib_ros.api.client import call_service, CallError, to_dict
        request = CalibrateUserFrame.Request(method=self.args.method, point_names=names,
                                             joint_captures=captures)
        try:
            res = call_service(self.node, self.calibrate, request, 60.0, self.executor)
        except CallError as e:
            raise TeachError(str(e))
        if res.error_code != CalibrateUserFrame.Response.SUCCESS:
            return fail(f'calibration refused (code {res.error_code}): {res.message}; the '
                        'captures were not stored, teach again')
        if self.args.json:
            print(json.dumps({'calibration': to_dict(res.calibration),
                              'joint_captures': [to_dict(c) for c in captures],
                              'message': res.message}))
        else:
            self._print_result(res.calibration)
        return EXIT_OK

    def _print_result(self, cal) -> None:
        t, r = cal.transform.transform.translation, cal.transform.transform.rotation
        self.say(f'\ncalibration {cal.id} ({cal.method}): stored and published on user_frame '
                 'and /tf_static')
        self.say(f'  {cal.transform.header.frame_id} -> {cal.transform.child_frame_id}: '
                 f'xyz ({t.x * 1e3:.3f}, {t.y * 1e3:.3f}, {t.z * 1e3:.3f}) mm, '
                 f'quaternion xyzw ({r.x:.6f}, {r.y:.6f}, {r.z:.6f}, {r.w:.6f})')
        self.say(f'  residual RMS {cal.rms_residual * 1e3:.4f} mm, max '
                 f'{cal.max_residual * 1e3:.4f} mm')
        for p in cal.residuals:
            flag = '  (outlier, not used)' if p.outlier else ''
            self.say(f'    {p.name}: {p.residual_norm * 1e3:.4f} mm{flag}')

