"""`cobot-calib replay BAG --check`: replay a teach bag through the suite, compare the frame.

A teach bag (bags/make_sample_bags.py) holds ``/joint_states``, the teach's captures as marks
on ``/cobot_calib/captures`` (cobot_calib_msgs/CaptureMark, ros.marks: header.stamp = end of
the hold, target = point name, the captured mean joints; the sample bag's JointState marks are
read through bags.mark_converter) and the live ``/user_frame``;
next to it ``expected.yaml`` (T_base_user, rms_residual, method, kinematics, point_names).

The check starts joint_state_monitor and user_frame_solver on a private ROS_DOMAIN_ID
(``use_sim_time: true``, a temporary data_dir), replays ``/joint_states`` and the marks with
``/clock`` (bags.player.BagPlayer), collects the marks as they arrive over DDS, then calls
``calibrate_user_frame`` (the expected method and kinematics) with the replayed captures as
``joint_captures`` and compares the frame with expected.yaml: translation within TOL_M and
rotation within TOL_RAD.

Two modes:
- default (the solver path): the recorded capture means, replayed over DDS, go through the
  solver's kinematic model and fit. Deterministic: the frame comes out bit for bit (0 m, 0 rad
  on the sample bag), at any --rate (max: about 5 s in all).
- ``recapture``: each hold is averaged again by joint_state_monitor's ``capture_joints`` from
  the REPLAYED joint_states on sim time: the request goes out when the replayed /clock (1 kHz
  by default here) reaches the hold's start (mark stamp minus ``hold_s``), with that start
  in the request: capture_joints averages the window the recording held, however late the
  request arrives (it opened its window on arrival until session 20; a run at twice the
  usual CPU per test, 1,931 tests in 16 min, then put the frame 1.3e-6 rad off and the check
  failed). Needs a finite rate.
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import threading
import time
from typing import Callable

import numpy as np

from cobot_calib_ros.api import replay_harness
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import transform_error
from cobot_calib_ros.ros.marks import CAPTURES_TOPIC
from cobot_calib_ros.ros.time import header_ns, ns_to_stamp, s_to_ns

EXPECTED_FILE = 'expected.yaml'
TOL_M = 1e-6
TOL_RAD = 1e-6
SERVICE_TIMEOUT = replay_harness.SERVICE_TIMEOUT
MARKS_TIMEOUT = 10.0     # [s] after play for the last marks to arrive
MARKS_WINDOW = 50        # marks out at most (the check's subscription holds 100)


CheckError = replay_harness.CheckError


def is_teach_bag(bag) -> bool:
    """A bag this check applies to: joint states and the capture marks."""
    return '/joint_states' in bag.topics and CAPTURES_TOPIC in bag.topics


def matrix(calibration) -> list[list[float]]:
    """UserFrameCalibration.matrix (row-major 16) as a 4x4 list."""
    m = [float(v) for v in calibration.matrix]
    return [m[4 * i:4 * i + 4] for i in range(4)]


def write_expected(path: Path, data: dict, comment: str = '') -> None:
    """expected.yaml of a sample bag (every check's); ``comment``: more header lines."""
    import yaml
    with open(path, 'w') as out:
        out.write('# expected result of replaying this bag: cobot-calib replay BAG --check\n'
                  + ''.join(f'# {line}\n' for line in comment.splitlines()))
        yaml.safe_dump(data, out, sort_keys=False, default_flow_style=None, width=100)


def expected_text(bag_path: str | os.PathLike, file_name: str) -> tuple[Path, str]:
    """(path, text) of the expected-result file ``file_name`` beside a bag (``bag_path``: its
    folder or a file in it); CheckError when unreadable."""
    folder = Path(bag_path)
    if not folder.is_dir():
        folder = folder.parent
    path = folder / file_name
    try:
        return path, path.read_text()
    except OSError as exc:
        raise CheckError(f'{path}: cannot read the expected result: {exc.strerror}') from None


def load_expected(bag_path: str | os.PathLike) -> tuple[Path, dict]:
    """(path, mapping) of the bag's expected.yaml; CheckError when unreadable or not YAML."""
    import yaml
    path, text = expected_text(bag_path, EXPECTED_FILE)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CheckError(f'{path}: not YAML: {exc}') from None
    return path, data if isinstance(data, dict) else {}


def read_expected(bag_path: str | os.PathLike) -> tuple[Path, dict]:
    """A frame check's expected.yaml: T_base_user as a 4x4 array."""
    path, data = load_expected(bag_path)
    if 'T_base_user' not in data:
        raise CheckError(f'{path}: no T_base_user in it')
    T = np.array(data['T_base_user'], dtype=float)
    if T.shape != (4, 4):
        raise CheckError(f'{path}: T_base_user must be 4x4')
    data['T_base_user'] = T
    return path, data


@dataclass
class CheckResult(replay_harness.Verdict):
    code: ErrorCode                 # replay_harness.Verdict: SUCCESS or IMPLAUSIBLE_FIT
    translation_m: float
    rotation_rad: float
    T_replayed: np.ndarray
    T_expected: np.ndarray
    rms_replayed: float
    marks: int
    wall_s: float


def run_check(bag_path: str, rate: float = 0.0, say: Callable[[str], None] = print,
              clock_hz: float = 40.0, recapture: bool = False) -> CheckResult:
    """Replay ``bag_path`` through the nodes and compare; see the module doc."""
    from cobot_calib_ros.bags.reader import open_bag
    expected_path, expected = read_expected(bag_path)
    started = time.monotonic()
    with open_bag(bag_path) as bag:
        if CAPTURES_TOPIC not in bag.topics or not bag.topics[CAPTURES_TOPIC].count:
            raise CheckError(f'{bag.path}: no {CAPTURES_TOPIC} marks to re-run')
        for warning in bag.warnings:
            say(f'warning: {warning}')
        holds = [header_ns(bag.deserialize(m.rawdata, m.msgtype))
                 for m in bag.messages([CAPTURES_TOPIC])]
        T, rms, marks = _replay_and_calibrate(bag, expected, rate, clock_hz, say, recapture,
                                              holds)
    dt, dr = transform_error(T, expected['T_base_user'])
    code = replay_harness.verdict(dt < TOL_M and dr < TOL_RAD)
    say(f'replayed {marks} captures from {bag_path}; {expected.get("method", "rigid")} frame '
        f'vs {expected_path}: translation differs by {dt:.3e} m (tolerance {TOL_M:g}), '
        f'rotation by {dr:.3e} rad (tolerance {TOL_RAD:g})')
    return CheckResult(code, dt, dr, T, expected['T_base_user'], rms, marks,
                       time.monotonic() - started)


def _replay_and_calibrate(bag, expected: dict, rate: float, clock_hz: float, say,
                          recapture: bool, holds: list[int]):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from cobot_calib_msgs.msg import CaptureMark
    from cobot_calib_msgs.srv import CalibrateUserFrame

    from cobot_calib_ros import paths
    from cobot_calib_ros.api.launcher import NodeSpec
    from cobot_calib_ros.bags.player import FlowControl
    from cobot_calib_ros.ros.calls import call_service, CallError

    kinematics = str(expected.get('kinematics', 'nominal'))
    wanted = len(holds)

    def specs(tmp: Path) -> list:
        return [NodeSpec('joint_state_monitor',
                         {'expected_rate_hz': str(expected.get('joint_states_hz', 1000.0))}),
                NodeSpec('user_frame_solver', {
                    'cell_file': str(paths.cell_file(expected.get('cell', paths.DEFAULT_CELL))),
                    'kinematics': kinematics, 'data_dir': str(tmp / 'data')})]
    with replay_harness.replay_suite(specs, 'cobot_calib_replay_check', say,
                                     data_dir=True) as harness:
        node = harness.node
        marks: list[CaptureMark] = []
        node.create_subscription(CaptureMark, CAPTURES_TOPIC, marks.append,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        calibrate = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        harness.wait_for(calibrate.service_is_ready, 'calibrate_user_frame')
        played: dict = {}
        recaptured = None
        # the marks are counted as they come back, so play() ends when all are in
        flow = FlowControl(MARKS_WINDOW, lambda: len(marks), frozenset([CAPTURES_TOPIC]))
        with harness.playing(bag, ['/joint_states', CAPTURES_TOPIC], rate, clock_hz,
                             waits_for='joint_state_monitor', flow=flow) as player:
            def play() -> None:
                try:
                    played['result'] = player.play()
                except Exception as exc:  # noqa: BLE001 - reported by the caller
                    played['error'] = exc
            playing = threading.Thread(target=play, daemon=True)
            playing.start()
            if recapture:
                recaptured = _recapture(node, holds, float(expected.get('hold_s', 0.5)),
                                        playing, say)
            playing.join()
            replay_harness.drain(lambda: len(marks), lambda: len(marks) >= wanted,
                                 MARKS_TIMEOUT)
        if 'error' in played:
            raise CheckError(f'replay failed: {played["error"]}')
        result = played['result']
        say(f'replayed {result.published} messages in {result.wall_s:.2f} s '
            f'({result.speed:.1f}x real time), {len(marks)}/{wanted} captures received')
        if len(marks) < wanted:
            raise CheckError(f'only {len(marks)} of {wanted} {CAPTURES_TOPIC} marks arrived')
        if recaptured is not None:
            for mark, again in zip(marks, recaptured):
                worst = max(abs(a - b) for a, b in zip(mark.position_rad, again.position))
                say(f'  {mark.target}: re-captured {again.name and len(again.name)} '
                    f'joints, largest difference from the recorded mean {worst:.3e} rad')
                mark.joint_names, mark.position_rad = list(again.name), list(again.position)
        names = [m.target for m in marks]
        if expected.get('point_names') and names != list(expected['point_names']):
            raise CheckError(f'the bag\'s captures are {names}, expected.yaml has '
                             f'{expected["point_names"]}')
        request = CalibrateUserFrame.Request(
            method=str(expected.get('method', 'rigid')), point_names=names,
            kinematics=kinematics,
            joint_captures=[JointState(name=list(m.joint_names), position=list(m.position_rad))
                            for m in marks])
        try:
            res = call_service(node, calibrate, request, 60.0, harness.executor)
        except CallError as exc:
            raise CheckError(str(exc)) from None
        if res.error_code != CalibrateUserFrame.Response.SUCCESS:
            raise CheckError(f'calibrate_user_frame refused (code {res.error_code}): '
                             f'{res.message}')
        return (np.array(matrix(res.calibration)), float(res.calibration.rms_residual),
                len(marks))


def _recapture(node, holds: list[int], hold_s: float, playing, say) -> list:
    """capture_joints over each recorded hold window, on the replayed /clock: the request goes
    out when ROS time reaches the window's start (its end stamp minus the hold)."""
    from cobot_calib_msgs.srv import CaptureJoints
    from sensor_msgs.msg import JointState
    client = node.create_client(CaptureJoints, 'capture_joints')
    deadline = time.monotonic() + SERVICE_TIMEOUT
    while not client.service_is_ready():
        if time.monotonic() > deadline:
            raise CheckError('capture_joints did not come up')
        time.sleep(0.01)
    out = []
    for end_ns in holds:
        start_ns = end_ns - s_to_ns(hold_s)
        while node.get_clock().now().nanoseconds < start_ns:
            if not playing.is_alive():
                raise CheckError('the replay ended before a hold window started; '
                                 'use a finite --rate for --recapture')
            time.sleep(0.0005)
        future = client.call_async(CaptureJoints.Request(duration=hold_s,
                                                         start=ns_to_stamp(start_ns)))
        deadline = time.monotonic() + 30.0
        while not future.done():
            if time.monotonic() > deadline:
                raise CheckError('capture_joints did not answer')
            time.sleep(0.002)
        res = future.result()
        if res.error_code != CaptureJoints.Response.SUCCESS:
            raise CheckError(f'capture_joints on the replay: {res.message}')
        out.append(JointState(name=list(res.name), position=list(res.position)))
    return out


def format_matrix(T: np.ndarray) -> str:
    return '\n'.join('    [' + ', '.join(f'{v: .9f}' for v in row) + ']' for row in T)
