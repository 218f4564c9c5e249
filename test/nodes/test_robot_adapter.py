"""The suite through robot_adapter: mock_robot in driver mode (joint_states + FollowJointTrajectory
only, as a ros2_control arm), as `cobot-calib up --robot-interface driver` starts it (issue 18).

Its own suite on a ROS domain of its own (domain_coordinator): mock_robot, robot_adapter,
joint_state_monitor, proximity_sensor, user_frame_solver, repeatability_trial.
"""
import json
import os
import subprocess
import sys

from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.srv import GetGroundTruth
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import JointState
from visualization_msgs.msg import Marker, MarkerArray

from cobot_calib_ros import store
from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.client import wait_for_suite
from cobot_calib_ros.core.user_frame import LIMIT_FACTOR
from cobot_calib_ros.core import rig
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import convert, qos
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import call_service, run_action, spin_until
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.trials import TrialStore
from foxglove_ws import FoxgloveClient
from proc_lines import Lines
from rosutil import STARTUP_TIMEOUT, STOP_TIMEOUT

NODES = ('mock_robot', 'joint_state_monitor', 'proximity_sensor', 'user_frame_solver',
         'repeatability_trial')


@pytest.fixture(scope='module')
def driver_suite(tmp_path_factory):
    """(client node, env for CLI processes, data dir) of the suite in driver mode."""
    data = tmp_path_factory.mktemp('driver_results')
    with domain_coordinator.domain_id() as domain:
        env = {**os.environ, 'ROS_DOMAIN_ID': str(domain)}
        specs = launcher.suite_specs('sawyer_close', NODES, overrides={
            'mock_robot': {'time_scale': '0.2'},
            'user_frame_solver': {'data_dir': str(data)},
            'repeatability_trial': {'data_dir': str(data)},
            # its own results: the compensation test's calibration is the adapter's alone
            'robot_adapter': {'data_dir': str(data / 'adapter')}}, robot_interface='driver')
        assert [s.name for s in specs][:2] == ['mock_robot', 'robot_adapter']
        suite = launcher.Suite(tmp_path_factory.mktemp('driver_logs'))
        suite.start(specs, env=env)
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('driver_test_client', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        node.executor_for_tests = executor
        try:
            wait_for_suite(node, STARTUP_TIMEOUT, executor)
            yield node, env, data
        finally:
            node.destroy_node()
            rclpy.try_shutdown(context=context)
            codes = suite.stop(STOP_TIMEOUT)
            logs = '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)
            assert all(c == 0 for c in codes.values()), f'unclean exit {codes}:\n{logs}'


def cli(env, *args, timeout=120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', *args],
                          capture_output=True, text=True, timeout=timeout, env=env)


def set_fault(node, fault: str) -> None:
    client = node.create_client(SetParameters, '/mock_robot/set_parameters')
    request = SetParameters.Request(parameters=[
        Parameter('driver_fault', value=fault).to_parameter_msg()])
    try:
        result = call_service(node, client, request, 10.0, node.executor_for_tests)
    finally:
        node.destroy_client(client)
    assert result.results[0].successful


def test_the_mock_offers_only_what_a_ros2_control_driver_offers(driver_suite):
    node, _, _ = driver_suite
    trajectory = '/joint_trajectory_controller/follow_joint_trajectory/_action/send_goal'

    def services(name: str) -> set[str]:
        try:
            return {n for n, _ in node.get_service_names_and_types_by_node(name, '/')}
        except Exception:  # noqa: BLE001 - NodeNameNonExistentError: not discovered yet
            return set()
    assert spin_until(node, lambda: trajectory in services('mock_robot') and
                      '/move_to/_action/send_goal' in services('robot_adapter'), 30.0,
                      node.executor_for_tests)
    assert not any('move_to' in n for n in services('mock_robot')), \
        'the driver-mode mock must not serve move_to'


@pytest.fixture(scope='module')
def demo(driver_suite) -> dict:
    """`cobot-calib demo --json --attach` on the driver suite: its report; its calibrations
    stay active (the markers test reads them)."""
    _, env, _ = driver_suite
    out = cli(env, 'demo', '--json', '--attach', timeout=180)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_demo_through_the_adapter_is_as_accurate_as_through_move_to(demo):
    """Must-show 1: the same bands test_user_frame_demo pins for the move_to interface."""
    result = demo
    methods = {m['name']: m for m in result['methods']}
    rigid = methods['rigid']
    assert result['noise_sigma_mm'] == pytest.approx(0.03588, abs=5e-5)
    assert rigid['frame_error_noise_mm'] < LIMIT_FACTOR * result['estimation_limit_mm']
    assert rigid['frame_error_noise_mrad'] < LIMIT_FACTOR * result['estimation_limit_mrad']
    assert 0.05 < rigid['frame_error_systematic_mm'] < 0.6
    # robot sent to each marker through the frame, via FollowJointTrajectory: five < three
    assert rigid['point_error_max_mm'] < methods['three_point']['point_error_max_mm']
    assert rigid['point_error_max_mm'] < 0.3


def test_markers_of_the_calibration_reach_a_foxglove_client_through_view(driver_suite, demo):
    """Must-show 3: `cobot-calib view` streams the latched MarkerArray (ros2msg/cdr) to a
    WebSocket client after a calibration (the demo's)."""
    node, env, _ = driver_suite
    from cobot_calib_msgs.msg import UserFrameCalibration
    frames = []
    sub = node.create_subscription(UserFrameCalibration, 'user_frame', frames.append, qos.LATCHED)
    spin_until(node, lambda: frames, 10.0, node.executor_for_tests)
    node.destroy_subscription(sub)
    assert frames, 'no calibration latched on user_frame'
    view = subprocess.Popen([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'view',
                             '--port', '0', 'cobot_calib/markers'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        lines = Lines(view.stdout)
        line = lines.wait_for('view: ws://127.0.0.1:', 30.0)
        assert line is not None, ''.join(lines.seen)
        port = int(line.split('ws://127.0.0.1:')[1].split()[0])
        client = FoxgloveClient('127.0.0.1', port)
        try:
            channel, data = client.message('/cobot_calib/markers', 30.0)
        except TimeoutError as e:
            view.terminate()
            pytest.fail(f'{e}; view printed:\n{"".join(lines.seen)}{lines.leftover()}'
                        f'{view.communicate(timeout=10)[0]}')
        finally:
            client.close()
    finally:
        view.terminate()
        view.wait(10)
    assert (channel['encoding'], channel['schemaEncoding'], channel['schemaName']) == (
        'cdr', 'ros2msg', 'visualization_msgs/msg/MarkerArray')
    markers = deserialize_message(data, MarkerArray).markers
    assert markers[0].action == Marker.DELETEALL
    markers = [m for m in markers if m.action == Marker.ADD]
    points = next(m for m in markers if m.ns == 'user_frame/points')
    measured = [(r.point_base.x, r.point_base.y, r.point_base.z) for r in frames[-1].residuals]
    np.testing.assert_allclose([(p.x, p.y, p.z) for p in points.points], measured)
    arrows = [m for m in markers if m.ns == 'user_frame/residuals']
    assert len(arrows) == len(measured) == 5
    axes = [m for m in markers if m.ns == 'user_frame/frame']
    T = np.array(frames[-1].matrix).reshape(4, 4)
    np.testing.assert_allclose([axes[0].points[0].x, axes[0].points[0].y], T[:2, 3])


def test_a_three_cycle_trial_completes_through_the_adapter(driver_suite):
    _, env, data = driver_suite
    out = cli(env, 'trial', '--method', 'rigid', '--cycles', '3', '--json')
    assert out.returncode == 0, out.stdout + out.stderr
    stored = TrialStore(data).load(json.loads(out.stdout)['trial_id'])
    assert stored.meta['status'] == 'done'
    assert np.isfinite(stored.distances).all() and stored.distances.shape == (5, 3)


@pytest.mark.parametrize('fault, words', [
    ('reject', 'rejected the trajectory goal'),
    ('abort', 'aborted the move (PATH_TOLERANCE_VIOLATED'),
    ('ring', 'the arm did not settle within 5.0 s after the move: right_j0 still moved'),
])
def test_a_misbehaving_driver_gives_one_clear_error_and_no_half_trial(driver_suite, fault,
                                                                     words):
    """Must-show 4: the trial's first move fails; no reading is stored for it."""
    node, env, data = driver_suite
    set_fault(node, fault)
    try:
        out = cli(env, 'trial', '--method', 'reference', '--cycles', '2')
    finally:
        set_fault(node, '')
    assert out.returncode != 0
    failed = [line for line in (out.stdout + out.stderr).splitlines() if 'failed' in line]
    assert len(failed) == 1 and words in failed[0], out.stdout + out.stderr
    trial_id = failed[0].split()[1]                     # 'trial <id> failed: ...'
    stored = TrialStore(data).load(trial_id)
    assert stored is None or not np.isfinite(stored.distances).any()


def test_a_canceled_move_to_stops_the_driver_short_of_its_target(driver_suite):
    node, _, _ = driver_suite
    latest = []

    def keep(msg) -> None:
        latest[:] = [msg]
    sub = node.create_subscription(JointState, 'joint_states', keep, qos.JOINT_STATES)
    client = ActionClient(node, MoveTo, 'move_to')
    executor = node.executor_for_tests
    try:
        assert spin_until(node, lambda: latest and client.server_is_ready(), 10.0, executor)
        start = np.array(latest[0].position)
        target = start.copy()
        target[0] += 0.5                       # 0.5 rad at 0.05 of 1 rad/s: 10 s (2 s real)
        sent = client.send_goal_async(MoveTo.Goal(
            target_type=MoveTo.Goal.TARGET_JOINTS, positions=target.tolist(),
            speed_scale=0.05))
        assert spin_until(node, lambda: sent.done(), 10.0, executor)
        handle = sent.result()
        assert handle.accepted
        assert spin_until(node, lambda: abs(latest[0].position[0] - start[0]) > 0.01, 10.0,
                          executor)
        canceling = handle.cancel_goal_async()
        result = handle.get_result_async()
        assert spin_until(node, lambda: canceling.done() and result.done(), 15.0, executor)
        assert result.result().result.error_code == MoveTo.Result.CANCELED
        spin_until(node, lambda: False, 0.3, executor)
        stopped = latest[0].position[0]
        assert start[0] + 0.01 < stopped < target[0] - 0.05     # stopped on the way
    finally:
        client.destroy()
        node.destroy_subscription(sub)


def test_a_pose_goal_is_solved_with_the_active_kinematic_calibration(driver_suite):
    """Issue 29.1: the adapter (the suite's IK over a ros2_control arm) solves a pose with the
    active calibration; with an exact one the TCP lands on the target by the mock's truth (the
    true arm at the joints reached), where the nominal model misses it."""
    node, _, data = driver_suite
    truth = call_service_once(node, GetGroundTruth, 'get_ground_truth')
    cell = load_cell(cell_file('sawyer_close'))
    model = model_for(cell)
    true_params = np.array(truth.true_parameters)
    target = fk(rig.Rig(cell, model=model).chain('tcp'), cell.home + 0.15)
    # the mock's truth: its true arm and its TRUE tool (0.25 mm / 3.6 mrad off the cell's),
    # which the active TCP (an exact one) gives the adapter
    true_tool = convert.transform_to_matrix(truth.t_flange_tool_true)
    true_tcp = model.chain(true_params, tool=true_tool)
    repo = store.open(data / 'adapter', cell=ResultsCell.of(cell))
    record = {'id': 'k-true', 'robot': model.name, 'stamp_ns': 1, 'method': 'test',
              'inputs': {}, 'result': {'parameter_names': list(model.parameter_names),
                                       'params': true_params.tolist()}}
    assert repo.tcp.save_and_activate({
        'id': 'tcp-true', 'stamp_ns': 1, 'method': 'tcp-test', 'tool': cell.tool_frame,
        'inputs': {}, 'result': {'T_flange_tool': true_tool.tolist(),
                                 'orientation_method': 'zx'}})
    client = ActionClient(node, MoveTo, 'move_to')
    errors = {}
    try:
        for label in ('nominal', 'compensated'):      # none stored yet: nominal
            if label == 'compensated':
                repo.kinematics.save_and_activate(record)
            _, home = run_action(node, client, MoveTo.Goal(
                target_type=MoveTo.Goal.TARGET_JOINTS, positions=cell.home.tolist()), 60.0,
                executor=node.executor_for_tests)
            assert home.error_code == MoveTo.Result.SUCCESS, home.message
            _, result = run_action(node, client, MoveTo.Goal(
                target_type=MoveTo.Goal.TARGET_POSE, pose=convert.matrix_to_pose(target)), 60.0,
                executor=node.executor_for_tests)
            assert result.error_code == MoveTo.Result.SUCCESS, result.message
            reached = fk(true_tcp, np.array(result.positions))
            errors[label] = float(np.linalg.norm(reached[:3, 3] - target[:3, 3]))
    finally:
        client.destroy()
        repo.kinematics.retire('k-true')
        repo.tcp.retire('tcp-true')
    assert errors['compensated'] < 1e-6 and errors['nominal'] > 1e-4, errors


def call_service_once(node, srv_type, name):
    client = node.create_client(srv_type, name)
    try:
        return call_service(node, client, srv_type.Request(), 10.0, node.executor_for_tests)
    finally:
        node.destroy_client(client)
