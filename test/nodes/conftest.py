"""The node suite in separate processes on this session's private ROS domain."""
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.calls import CallError, spin_until
from cobot_calib_ros.api.client import wait_for_suite
from machine import STARTUP_TIMEOUT, STOP_TIMEOUT


@pytest.fixture(scope='session')
def trial_data(tmp_path_factory):
    """The suite nodes' data_dir: calibrations and trials (read them with the core stores)."""
    return tmp_path_factory.mktemp('results')


@pytest.fixture(scope='session')
def suite(domain_id, trial_data, tmp_path_factory):
    """The suite (launcher.SUITE: mock_robot, joint_state_monitor, proximity_sensor,
    user_frame_solver, repeatability_trial, kinematic_identifier; + an isolated /iso probe
    node), each its own process, all storing under ``trial_data``."""
    data = trial_data
    # hand_eye_calibrator, tcp_calibrator, camera_calibrator: their tests start their own
    # (fewer processes on the 2 cores)
    nodes = tuple(n for n in launcher.SUITE if n not in ('hand_eye_calibrator',
                                                         'tcp_calibrator', 'camera_calibrator'))
    specs = launcher.suite_specs('sawyer_close', nodes, overrides={
        # motions 2.5 times as long as at the cells' time_scale (0.02): a slow move can be
        # caught moving (test_ingestion); 0.2 took ~25 s more of the node tests' time
        'mock_robot': {'time_scale': '0.05'},
        # images at 5 Hz, not 10: rendering, 0.4 MB messages and detection load the 2 cores
        # the 1 kHz joint_states timing tests share (test_sim_time, test_teach)
        'mock_camera': {'rate_hz': '5.0'},
        'user_frame_solver': {'data_dir': str(data)},
        # the landmark trial's 18 holds a cycle (its default 0.3 s; 0.15 s is 150 samples
        # of the mock's 2e-6 rad joint noise)
        'repeatability_trial': {'data_dir': str(data), 'capture_duration': '0.15'},
        # planned collections from the 30 deg candidate grid (1/6 of the IK of the default)
        'kinematic_identifier': {'data_dir': str(data), 'candidate_tilt_step': '0.5236',
                                 'publish_robot_description': 'true'}})
    specs.append(launcher.NodeSpec('proximity_sensor', namespace='iso'))
    running = launcher.Suite(tmp_path_factory.mktemp('logs'))
    running.start(specs)
    yield running
    codes = running.stop(STOP_TIMEOUT)
    assert all(c == 0 for c in codes.values()), f'nodes did not exit cleanly: {codes}'


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item, nextitem):
    """The session's suite stops after the last test of this worker that uses it, not at the
    end of the session: its idle nodes took ~30 % of a core for the rest of the run (the next
    files are other directories'; a later test that asks for it starts it again)."""
    definitions = item._fixtureinfo.name2fixturedefs.get('suite')
    if definitions and (nextitem is None or 'suite' not in nextitem.fixturenames):
        definitions[-1].finish(item._request)


@pytest.fixture(scope='session')
def ros(suite):
    """A client node in this test process, on the suite's domain."""
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('test_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    node.executor_for_tests = executor
    ready = spin_until(node, lambda: _suite_visible(node), STARTUP_TIMEOUT, executor)
    if not ready:
        logs = '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)
        pytest.fail(f'node suite did not come up in {STARTUP_TIMEOUT} s:\n{logs}')
    try:
        wait_for_suite(node, STARTUP_TIMEOUT, executor)
    except CallError as e:
        logs = '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)
        pytest.fail(f'{e}:\n{logs}')
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def _suite_visible(node) -> bool:
    services = {n for n, _ in node.get_service_names_and_types()}
    return {'/capture_joints', '/probe/average', '/iso/probe/average', '/get_ground_truth',
            '/calibrate_user_frame'} <= services
