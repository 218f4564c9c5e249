"""camera_calibrator with mock_robot, joint_state_monitor and mock_camera as processes on a
private domain of their own (cell ur10e_close, temporary data_dir): the ROS translation of the
intrinsics calibration. calibrate_intrinsics over planned views answers with the stored
record's intrinsics, its camera_info YAML and coverage feedback; a bag source is refused with
what to do. The procedures themselves (the mock's TRUE lens recovered, live views, a cancel)
are tested in-process: test/api/test_intrinsics_api.py, test/sim/test_intrinsics_mock.py.
`cobot-calib intrinsics --planned` on a suite: the first-day tests.
"""
from dataclasses import dataclass
import os

from cobot_calib_msgs.action import CalibrateIntrinsics
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from scipy.spatial.transform import Rotation

from cobot_calib_ros import store
from cobot_calib_ros.api import launcher
from cobot_calib_ros.loaders import load_camera_info_yaml
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import run_action, spin_until
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import active_intrinsics
from rosutil import STARTUP_TIMEOUT, STOP_TIMEOUT

NODES = ('mock_robot', 'joint_state_monitor', 'mock_camera', 'camera_calibrator')
VIEWS = 8
CELL = ResultsCell('ur10e_close', 'ur10e')


@dataclass
class Client:
    node: Node
    executor: SingleThreadedExecutor
    suite: launcher.Suite
    data_dir: str
    env: dict


def _user_frame() -> str:
    T = load_simulation(cell_file('ur10e_close')).world.T_base_user
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler('xyz')
    return ' '.join(f'{v:.6f}' for v in (*T[:3, 3], *rpy))


@pytest.fixture(scope='module')
def camera_suite(tmp_path_factory):
    data = tmp_path_factory.mktemp('intrinsics_data')
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path_factory.mktemp('intrinsics_logs'))
        suite.start(launcher.suite_specs('ur10e_close', NODES, overrides={
            'camera_calibrator': {'data_dir': str(data), 'user_frame': _user_frame()}}),
            env=env)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('test_camera_calibrator', context=context)
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


def test_planned_views_answer_with_the_stored_intrinsics_and_a_bag_is_refused(camera_suite):
    client = camera_suite
    action = ActionClient(client.node, CalibrateIntrinsics, 'calibrate_intrinsics')
    feedback = []
    try:
        if not spin_until(client.node, action.server_is_ready, STARTUP_TIMEOUT,
                          client.executor):
            pytest.fail(f'calibrate_intrinsics not available:\n{_logs(client.suite)}')
        _, refused = run_action(client.node, action,
                                CalibrateIntrinsics.Goal(source='/no/such/run.mcap'), 60.0,
                                executor=client.executor)
        _, result = run_action(client.node, action,
                               CalibrateIntrinsics.Goal(views=VIEWS, planned=True), 300.0,
                               feedback=lambda m: feedback.append(m.feedback),
                               executor=client.executor)
    finally:
        action.destroy()
    assert refused.error_code == CalibrateIntrinsics.Result.INVALID_GOAL
    assert 'cobot-calib intrinsics BAG' in refused.message
    assert result.error_code == CalibrateIntrinsics.Result.SUCCESS, \
        f'{result.message}\n{_logs(client.suite)}'
    k = result.camera_info.k
    assert abs(k[0] / 620.0 - 1) < 5e-3          # what mock_camera draws (truth = nominal)
    assert result.active and result.views_used == VIEWS and result.rms_px < 0.1
    assert len(feedback) == VIEWS and feedback[-1].views == VIEWS
    assert feedback[-1].total == VIEWS and feedback[0].coverage < feedback[-1].coverage
    assert load_camera_info_yaml(result.yaml_path).K[0, 0] == k[0]
    repo = store.open(client.data_dir, cell=CELL)
    np.testing.assert_array_equal(active_intrinsics(repo, 'wrist_camera_optical').K.ravel(), k)
    record = repo.intrinsics.get(result.calibration_id)
    assert record['result']['rms_px'] == result.rms_px
    assert record['result']['yaml_path'] == result.yaml_path


def test_landmark_detector_poses_with_the_active_intrinsics(tmp_path):
    """landmark_detector takes the cell camera's active intrinsics record instead of the
    camera_info it receives (parameter intrinsics: active, the default), for images of its
    size; with intrinsics: camera_info, or another size, camera_info's K and D hold."""
    from rclpy.parameter import Parameter
    from cobot_calib_ros.core.landmarks.camera import CameraModel
    from cobot_calib_ros.core.landmarks.intrinsics import Coverage, IntrinsicsFit
    from cobot_calib_ros.nodes.landmark_detector import LandmarkDetector
    from cobot_calib_ros.ros.images import model_to_camera_info
    from cobot_calib_ros.store.records import IntrinsicsRecord
    calibrated = CameraModel(752, 480, [[628.0, 0, 380.1], [0, 627.2, 236.9], [0, 0, 1]],
                             [-0.15, 0.12, 0.0003, -0.0004, -0.05], 'plumb_bob',
                             'wrist_camera_optical')
    fit = IntrinsicsFit(calibrated, 0.03, {}, (), 0.031,
                        Coverage(np.ones((4, 4), bool), 1.0, (), (), 40.0), 20, {})
    repo = store.open(tmp_path, cell=CELL)
    assert repo.intrinsics.save_and_activate(IntrinsicsRecord.from_fit(
        fit, camera='wrist_camera_optical', source='test', board='', views=[]))
    nominal = load_simulation(cell_file('ur10e_close')).cell.camera.camera_model()
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for source, size, expected in (('active', (752, 480), 628.0),
                                       ('camera_info', (752, 480), 620.0),
                                       ('active', (640, 480), 620.0)):
            node = LandmarkDetector(context=context, parameter_overrides=[
                Parameter('cell_file', value=str(cell_file('ur10e_close'))),
                Parameter('data_dir', value=str(tmp_path)),
                Parameter('intrinsics', value=source)])
            try:
                info = model_to_camera_info(CameraModel(*size, nominal.K, nominal.D),
                                            'wrist_camera_optical')
                node._on_info(info)
                assert node._camera.K[0, 0] == expected, (source, size)
            finally:
                node.destroy_node()
    finally:
        context.try_shutdown()


def test_landmark_detector_follows_a_new_active_intrinsics_without_a_restart(tmp_path):
    """Issue 36.1: a new intrinsics calibration made active while landmark_detector runs is
    used from the next camera_info on (its timer looks at the active set: the callback is
    called here as the timer calls it), as kinematic_identifier follows kinematics."""
    from rclpy.parameter import Parameter
    from cobot_calib_ros.core.landmarks.camera import CameraModel
    from cobot_calib_ros.core.landmarks.intrinsics import Coverage, IntrinsicsFit
    from cobot_calib_ros.nodes.landmark_detector import LandmarkDetector
    from cobot_calib_ros.ros.images import model_to_camera_info
    from cobot_calib_ros.store.records import IntrinsicsRecord
    repo = store.open(tmp_path, cell=CELL)

    def activate(fx: float, wall_ns: int) -> None:
        lens = CameraModel(752, 480, [[fx, 0, 380.1], [0, fx, 236.9], [0, 0, 1]],
                           [-0.15, 0.12, 0.0003, -0.0004, -0.05], 'plumb_bob',
                           'wrist_camera_optical')
        fit = IntrinsicsFit(lens, 0.03, {}, (), 0.031,
                            Coverage(np.ones((4, 4), bool), 1.0, (), (), 40.0), 20, {})
        assert repo.intrinsics.save_and_activate(IntrinsicsRecord.from_fit(
            fit, camera='wrist_camera_optical', source='test', board='', views=[],
            wall_ns=wall_ns))
    nominal = load_simulation(cell_file('ur10e_close')).cell.camera.camera_model()
    info = model_to_camera_info(CameraModel(752, 480, nominal.K, nominal.D),
                                'wrist_camera_optical')
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = LandmarkDetector(context=context, parameter_overrides=[
            Parameter('cell_file', value=str(cell_file('ur10e_close'))),
            Parameter('data_dir', value=str(tmp_path))])
        try:
            node._on_info(info)
            assert node._camera.K[0, 0] == 620.0          # none active: camera_info's
            activate(628.0, 1)
            node._follow_intrinsics()
            node._on_info(info)                             # the same camera_info again
            assert node._camera.K[0, 0] == 628.0
            activate(633.0, 2)
            node._follow_intrinsics()
            node._on_info(info)
            assert node._camera.K[0, 0] == 633.0
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()
