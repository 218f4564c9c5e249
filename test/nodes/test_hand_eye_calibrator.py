"""hand_eye_calibrator with mock_robot, joint_state_monitor, mock_camera and landmark_detector as
processes on a private domain of their own (cell sawyer_close, temporary data_dir): the ROS
translation of the hand-eye calibration. calibrate_hand_eye's result is the stored record's
(the transform in [m], the residual fields in mm / mrad), published latched on ``hand_eye``;
a goal with too few views is refused. The procedure itself (the TRUE hand-eye recovered, a
cancel, views that do not fit their noise rejected) is tested in-process:
test/api/test_hand_eye_api.py and test/core/landmarks/test_hand_eye_capture.py.

Own suite, not the session's (test/nodes/conftest.py): a second mock_robot on the session's
domain would answer its move_to goals.
"""
from dataclasses import dataclass
import os

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
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros import store
from cobot_calib_ros.store.cells import ResultsCell
from rosutil import STARTUP_TIMEOUT, STOP_TIMEOUT

NODES = ('mock_robot', 'joint_state_monitor', 'mock_camera', 'landmark_detector',
         'hand_eye_calibrator')
CELL = ResultsCell('sawyer_close', 'sawyer')      # the node's results (no namespace)
# Where the views are planned: the user frame roughly as a user-frame calibration knows it
# (the truth is 0.35 -0.05 0 / 0.002 -0.0015 0.03): a few mm and mrad off on purpose.
USER_FRAME = '0.352 -0.048 0.0 0.0 0.0 0.03'
VIEWS = 6


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


def test_the_result_is_the_stored_record_published_and_a_bad_goal_is_refused(hand_eye_suite):
    """With a kinematic calibration active the flange poses come from it and the record names
    it; the action's fields are the record's; a goal of 2 views is refused (INVALID_GOAL)."""
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
        _, refused = run_action(client.node, action, CalibrateHandEye.Goal(views=2), 60.0,
                                executor=client.executor)
        _, result = run_action(client.node, action,
                               CalibrateHandEye.Goal(views=VIEWS, hold=0.1), 300.0,
                               feedback=lambda m: feedback.append(m.feedback),
                               executor=client.executor)
        assert result.error_code == CalibrateHandEye.Result.SUCCESS, \
            f'{result.message}\n{_logs(client.suite)}'
        spin_until(client.node, lambda: bool(latched), 10.0, client.executor)
    finally:
        client.node.destroy_subscription(sub)
        action.destroy()
    assert refused.error_code == CalibrateHandEye.Result.INVALID_GOAL
    assert refused.message.startswith('views must be 3..200'), refused.message

    t, r = result.t_flange_optical.translation, result.t_flange_optical.rotation
    X = frames.from_pose([t.x, t.y, t.z], [r.x, r.y, r.z, r.w])
    sigma = np.sqrt(np.diag(np.array(result.covariance).reshape(6, 6)))
    assert result.views_used + result.views_skipped == VIEWS and result.views_used >= 4
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    assert len(feedback) == VIEWS and feedback[-1].view_index == VIEWS - 1
    history = store.open(client.data_dir, cell=CELL).hand_eye
    record = history.get(result.calibration_id)
    assert record is not None and history.active()['id'] == result.calibration_id
    np.testing.assert_allclose(record['result']['T_flange_optical'], X, atol=1e-9)
    assert result.residual_mm == pytest.approx(record['result']['residual_mm'], abs=1e-12)
    assert result.residual_mrad == pytest.approx(record['result']['residual_mrad'], abs=1e-12)
    assert 1e-3 < result.residual_mm < 1.0          # mm in the _mm field, metres in X
    assert frames.transform_error(X, sim.camera.T_flange_optical)[0] < 1e-3
    assert len(record['inputs']['joints']) == result.views_used
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
