"""hand_eye_calibrator with mock_robot, joint_state_monitor, mock_camera and landmark_detector as
processes on a private domain of their own (cell sawyer_close, temporary data_dir):
calibrate_hand_eye over 12 views recovers the simulation's TRUE hand-eye, stores the record and
publishes it latched on ``hand_eye``.

Own suite, not the session's (test/nodes/conftest.py): a second mock_robot on the session's
domain would answer its move_to goals.
"""
from dataclasses import dataclass
import os
import select
import signal
import subprocess
import time

from cobot_calib_msgs.action import CalibrateHandEye
from geometry_msgs.msg import TransformStamped
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import run_action, spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import qos
from cobot_calib_ros.ros.time import stamp_to_ns
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros import store
from cobot_calib_ros.store.cells import ResultsCell
from rosutil import cli_command, STARTUP_TIMEOUT, STOP_TIMEOUT

NODES = ('mock_robot', 'joint_state_monitor', 'mock_camera', 'landmark_detector',
         'hand_eye_calibrator')
CELL = ResultsCell('sawyer_close', 'sawyer')      # the node's results (no namespace)
# Where the views are planned: the user frame roughly as a user-frame calibration knows it
# (the truth is 0.35 -0.05 0 / 0.002 -0.0015 0.03): a few mm and mrad off on purpose.
USER_FRAME = '0.352 -0.048 0.0 0.0 0.0 0.03'
# Bounds on the error against the true hand-eye. Through the nominal kinematics it was
# 0.124-0.127 mm / 0.30-0.50 mrad in four runs, 0.31-0.41 mrad in-process over 20 noise draws
# (nominal hand-eye: 1.64 mm / 8.13 mrad off). Through a calibrated kinematics (issue 36
# must-show 4): in-process 0.009-0.010 mm / 0.08-0.10 mrad through the exact one, 0.024 mm /
# 0.10-0.12 mrad through one identified on the sim's spheres (bench/bench_hand_eye.py
# hand_eye_calibrated_error_*).
CALIBRATED_MAX_ERROR_MM = 0.05
CALIBRATED_MAX_ERROR_MRAD = 0.3


@dataclass
class Client:
    node: Node
    executor: SingleThreadedExecutor
    suite: launcher.Suite
    data_dir: str
    env: dict


@pytest.fixture(scope='module')
def hand_eye_suite(tmp_path_factory):
    data = tmp_path_factory.mktemp('hand_eye_data')
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path_factory.mktemp('hand_eye_logs'))
        suite.start(launcher.suite_specs('sawyer_close', NODES, overrides={
            'hand_eye_calibrator': {'data_dir': str(data), 'user_frame': USER_FRAME}}),
            env=env)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('test_hand_eye', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            yield Client(node, executor, suite, str(data), env)
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
            context.try_shutdown()
            codes = suite.stop(STOP_TIMEOUT)
        assert all(c == 0 for c in codes.values()), f'nodes did not exit cleanly: {codes}'


def _logs(suite) -> str:
    return '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)


def test_ctrl_c_cancels_the_calibration_and_nothing_is_stored(hand_eye_suite):
    """Issue 22.2: `cobot-calib hand-eye --views 40`, SIGINT after the first view: the goal is
    cancelled at the next view, the CLI says so and exits 130, nothing is stored, activated or
    published (on 5252a67 the server took all 40 views and made the result active)."""
    client = hand_eye_suite
    history = store.open(client.data_dir, cell=CELL).hand_eye
    ids_before, active_before = history.ids(), history.active()
    latched = []
    sub = client.node.create_subscription(TransformStamped, 'hand_eye', latched.append,
                                          qos.LATCHED)
    action = ActionClient(client.node, CalibrateHandEye, 'calibrate_hand_eye')
    try:
        if not spin_until(client.node, action.server_is_ready, STARTUP_TIMEOUT,
                          client.executor):
            pytest.fail(f'calibrate_hand_eye not available:\n{_logs(client.suite)}')
        started_ns = client.node.get_clock().now().nanoseconds
        proc = subprocess.Popen(cli_command('hand-eye', '--views', '40'), env=client.env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        lines = _lines_until(proc, 'view 1/40', STARTUP_TIMEOUT)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        # The goal has ended (its message is in err) and a publication would have come before
        # its result; the spin delivers what is queued, a window for a wrong one, not a wait.
        spin_until(client.node, lambda: False, 1.0, client.executor)
    finally:
        client.node.destroy_subscription(sub)
        action.destroy()
    out = ''.join(lines) + out
    assert proc.returncode == 130, f'{out}\n{err}'
    assert 'Traceback' not in out + err
    assert err.startswith('hand-eye calibration cancelled (Ctrl-C): cancelled at view '), err
    assert err.strip().endswith('of 40; nothing stored or published'), err
    views = [line for line in out.splitlines() if line.strip().startswith('view ')]
    assert 1 <= len(views) <= 3, f'views went on after the Ctrl-C:\n{out}'
    assert history.ids() == ids_before and history.active() == active_before
    assert not [m for m in latched if stamp_to_ns(m.header.stamp) > started_ns], \
        'a hand-eye was published after the cancelled goal started'


def _lines_until(proc: subprocess.Popen, text: str, timeout: float) -> list[str]:
    """stdout lines of ``proc`` up to the first one containing ``text``."""
    lines, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if select.select([proc.stdout], [], [], 0.2)[0]:
            lines.append(proc.stdout.readline())
            if text in lines[-1]:
                return lines
    proc.kill()
    out, err = proc.communicate()
    pytest.fail(f'no {text!r} within {timeout} s:\n{"".join(lines)}{out}\n{err}')


def test_calibrate_hand_eye_recovers_the_true_hand_eye(hand_eye_suite):
    """Issue 36.3 / must-show 4: with a kinematic calibration active (an exact one: the mock's
    true arm) the flange poses come from it, and the hand-eye is within 0.05 mm / 0.3 mrad of
    the truth (0.12 mm / 0.47 mrad through the nominal kinematics); its record names it."""
    client = hand_eye_suite
    from cobot_calib_ros.core.kinematics import model_for
    sim = load_simulation(cell_file('sawyer_close'))
    model = model_for(sim.cell)
    assert store.open(client.data_dir, cell=CELL).kinematics.save_and_activate({
        'id': 'k-true', 'robot': model.name, 'stamp_ns': 1, 'method': 'test', 'inputs': {},
        'result': {'parameter_names': list(model.parameter_names),
                   'params': sim.true_parameters(model).tolist()}})
    action = ActionClient(client.node, CalibrateHandEye, 'calibrate_hand_eye')
    latched = []
    sub = client.node.create_subscription(TransformStamped, 'hand_eye', latched.append,
                                          qos.LATCHED)
    feedback = []
    try:
        if not spin_until(client.node, action.server_is_ready, STARTUP_TIMEOUT,
                          client.executor):
            pytest.fail(f'calibrate_hand_eye not available:\n{_logs(client.suite)}')
        t0 = time.monotonic()
        _, result = run_action(client.node, action, CalibrateHandEye.Goal(views=0, hold=0.1),
                               300.0, feedback=lambda m: feedback.append(m.feedback),
                               executor=client.executor)
        seconds = time.monotonic() - t0
        assert result.error_code == CalibrateHandEye.Result.SUCCESS, \
            f'{result.message}\n{_logs(client.suite)}'
        spin_until(client.node, lambda: bool(latched), 10.0, client.executor)
    finally:
        client.node.destroy_subscription(sub)
        action.destroy()

    t, r = result.t_flange_optical.translation, result.t_flange_optical.rotation
    X = frames.from_pose([t.x, t.y, t.z], [r.x, r.y, r.z, r.w])
    err_m, err_rad = frames.transform_error(X, sim.camera.T_flange_optical)
    nom_m, nom_rad = frames.transform_error(sim.cell.camera.T_flange_optical,
                                            sim.camera.T_flange_optical)
    sigma = np.sqrt(np.diag(np.array(result.covariance).reshape(6, 6)))
    print(f'\nhand-eye: {result.views_used} views used, {result.views_skipped} skipped, '
          f'{seconds:.1f} s; residual RMS {result.residual_mm:.4f} mm / '
          f'{result.residual_mrad:.4f} mrad')
    print(f'hand-eye error against the truth: {err_m * 1e3:.4f} mm / {err_rad * 1e3:.4f} mrad '
          f'(nominal: {nom_m * 1e3:.3f} mm / {nom_rad * 1e3:.3f} mrad); 1-sigma xyz '
          f'{np.round(sigma[:3] * 1e3, 4)} mm, rxyz {np.round(sigma[3:] * 1e3, 4)} mrad')
    assert result.views_used >= 10
    assert result.views_used + result.views_skipped == 12
    assert err_m * 1e3 <= CALIBRATED_MAX_ERROR_MM
    assert err_rad * 1e3 <= CALIBRATED_MAX_ERROR_MRAD
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    assert len(feedback) == 12 and feedback[-1].view_index == 11

    history = store.open(client.data_dir, cell=CELL).hand_eye
    record = history.get(result.calibration_id)
    assert record is not None and history.active()['id'] == result.calibration_id
    np.testing.assert_allclose(record['result']['T_flange_optical'], X, atol=1e-9)
    assert len(record['inputs']['joints']) == result.views_used
    assert record['kinematics'] == 'k-true'
    assert record['measured_through'] == {'kinematics': 'k-true', 'intrinsics': 'nominal'}
    assert 'measured through the nominal intrinsics' in result.message   # not calibrated here

    assert latched, 'nothing latched on hand_eye'
    msg = latched[-1]
    assert msg.header.frame_id == 'flange' and msg.child_frame_id == 'wrist_camera_optical'
    tt = msg.transform.translation
    np.testing.assert_allclose([tt.x, tt.y, tt.z], X[:3, 3], atol=1e-9)


def test_user_frame_parameter():
    from cobot_calib_ros.nodes.job_node import parse_user_frame
    assert parse_user_frame('  ') is None
    np.testing.assert_allclose(parse_user_frame('0.35, -0.05 0 0 0 0.03'),
                               frames.from_xyz_rpy([0.35, -0.05, 0], [0, 0, 0.03]))
    for bad in ('1 2 3', 'a b c d e f', '0 0 0 0 0 nan'):
        with pytest.raises(ValueError, match='x y z roll pitch yaw'):
            parse_user_frame(bad)


@pytest.fixture
def busy_neighbour(tmp_path_factory):
    """A second suite on another domain working beside the first (issue 22.9): the same five
    nodes, its robot moving through 100-view hand-eye calibrations (`cobot-calib hand-eye`),
    its camera rendering and its detector detecting; running once its first view is done."""
    data = tmp_path_factory.mktemp('neighbour_data')
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path_factory.mktemp('neighbour_logs'))
        suite.start(launcher.suite_specs('sawyer_close', NODES, overrides={
            'hand_eye_calibrator': {'data_dir': str(data), 'user_frame': USER_FRAME}}),
            env=env)
        # one calibration after the other (one may fail under the load: the next starts)
        loop = ' '.join(cli_command('hand-eye', '--views', '100'))
        load = subprocess.Popen(['sh', '-c', f'while :; do {loop}; done'], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            _lines_until(load, 'view 1/100', 2 * STARTUP_TIMEOUT)
            yield suite
        finally:
            os.killpg(load.pid, signal.SIGTERM)        # the loop and its client; then its suite
            load.communicate(timeout=60)
            suite.stop()


RUNS_BESIDE = 2      # hand-eye runs beside the busy neighbour (13 of 28 went wrong on 5252a67)


def test_a_hand_eye_beside_a_busy_suite_is_right_or_rejected(hand_eye_suite, busy_neighbour):
    """Issue 22.9: with a second suite working beside it, a result is within 1 mm / 3 mrad of
    the mock's true hand-eye (GetGroundTruth) and active, or it is rejected: stored as rejected
    (history.rejected()), not active, not published, the active hand-eye unchanged. A run the
    load ends otherwise (a starved joint capture: CAPTURE_FAILED) stores nothing."""
    client = hand_eye_suite
    action = ActionClient(client.node, CalibrateHandEye, 'calibrate_hand_eye')
    latched = []
    sub = client.node.create_subscription(TransformStamped, 'hand_eye', latched.append,
                                          qos.LATCHED)
    outcomes = []
    try:
        assert spin_until(client.node, action.server_is_ready, STARTUP_TIMEOUT, client.executor)
        for _ in range(RUNS_BESIDE):
            outcomes.append(_run_and_check(client, action, latched))
    finally:
        client.node.destroy_subscription(sub)
        action.destroy()
        for outcome in outcomes:
            print(f'\nbeside a busy suite: {outcome}')
    assert any(o.startswith(('right', 'rejected')) for o in outcomes), outcomes


def _run_and_check(client, action, latched) -> str:
    """One calibration, checked as the test above says; what it gave, in one line."""
    from cobot_calib_ros.api.hand_eye import error_against_truth
    Result = CalibrateHandEye.Result
    before = store.open(client.data_dir, cell=CELL).hand_eye
    ids_before, active_before, published_before = before.ids(), before.active(), len(latched)
    _, result = run_action(client.node, action, CalibrateHandEye.Goal(views=12, hold=0.1),
                           300.0, executor=client.executor)
    history = store.open(client.data_dir, cell=CELL).hand_eye
    if result.error_code not in (Result.SUCCESS, Result.SOLVER_FAILED) or \
            not result.calibration_id:
        assert history.ids() == ids_before and history.active() == active_before, result.message
        return f'failed ({result.error_code}), nothing stored: {result.message}'
    t, r = result.t_flange_optical.translation, result.t_flange_optical.rotation
    X = frames.from_pose([t.x, t.y, t.z], [r.x, r.y, r.z, r.w])
    nominal = load_simulation(cell_file('sawyer_close')).cell.camera.T_flange_optical
    error = error_against_truth(client.node, X, nominal, client.executor)
    line = (f'residual {result.residual_mm:.4f} mm, {error.position_m * 1e3:.4f} mm / '
            f'{error.rotation_rad * 1e3:.4f} mrad from the truth, {result.views_used} views '
            f'used, {result.views_skipped} skipped')
    if result.error_code == Result.SUCCESS:
        assert error.position_m < 1e-3 and error.rotation_rad < 3e-3, line
        assert history.active()['id'] == result.calibration_id
        assert spin_until(client.node, lambda: len(latched) > published_before, 10.0,
                          client.executor), 'a right result was not published'
        return f'right: {line}'
    assert 'rejected' in result.message and 'not made active' in result.message, result.message
    record = history.get(result.calibration_id)
    assert record is not None and record['gate_problem']
    assert history.rejected()[result.calibration_id] == record['gate_problem']
    assert not history.activate(result.calibration_id)     # not even when asked for by id
    assert history.active() == active_before and len(latched) == published_before
    return f'rejected: {line}'
