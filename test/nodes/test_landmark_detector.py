"""mock_robot + mock_camera + landmark_detector as processes on a private domain of their own
(cell sawyer_close): the landmarks found agree with the simulation's truth, and bad images are
counted on /diagnostics without stopping the detector.

Own suite, not the session's (test/nodes/conftest.py): only these three nodes, and a second
mock_robot on the session's domain would answer its move_to goals.
"""
from dataclasses import dataclass
import os
import threading
import time

from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.msg import Landmark, Landmarks
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from cobot_calib_ros.api import launcher
from cobot_calib_ros.core.landmarks.pipeline import Pipeline
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import run_action, spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.nodes.landmark_detector import (configure, FrameQueue, Handoff,
                                                     LandmarkDetector, NotConfigured)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import convert
from cobot_calib_ros.sim.camera import SimCamera
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from rosutil import STARTUP_TIMEOUT, STOP_TIMEOUT

NODES = ('mock_robot', 'mock_camera', 'landmark_detector')
STATUS = 'landmark_detector: health'
BORDER_PX = 4                   # a marker this close to the image border may not be found


@dataclass
class Client:
    node: Node
    executor: SingleThreadedExecutor
    suite: launcher.Suite

    def spin_until(self, done, timeout: float) -> bool:
        return spin_until(self.node, done, timeout, self.executor)


@pytest.fixture(scope='module')
def camera_suite(tmp_path_factory):
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path_factory.mktemp('camera_logs'))
        suite.start(launcher.suite_specs('sawyer_close', NODES), env=env)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('test_landmarks', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            yield Client(node, executor, suite)
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
            context.try_shutdown()
            codes = suite.stop(STOP_TIMEOUT)
        assert all(c == 0 for c in codes.values()), f'nodes did not exit cleanly: {codes}'


@pytest.fixture(scope='module')
def truth():
    sim = load_simulation(cell_file('sawyer_close'))
    return SimCamera(sim, SimRobot(sim))


def _logs(suite) -> str:
    return '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)


def move_camera_above(client: Client, camera: SimCamera, xy, height: float) -> np.ndarray:
    """Send the arm so that the camera looks straight down at user (x, y) from ``height`` [m]
    (planned by mock_robot on the nominal model); the joints reached [rad]."""
    sim = camera.sim
    T_user_optical = frames.make_transform(frames.rot_x(np.pi), [*xy, height])
    T_base_tool = (sim.world.T_base_user @ T_user_optical
                   @ frames.invert(sim.cell.camera.T_flange_optical) @ sim.cell.T_flange_tool)
    action = ActionClient(client.node, MoveTo, 'move_to')
    try:
        if not client.spin_until(action.server_is_ready, STARTUP_TIMEOUT):
            pytest.fail(f'move_to not available:\n{_logs(client.suite)}')
        goal = MoveTo.Goal(target_type=MoveTo.Goal.TARGET_POSE,
                           pose=convert.matrix_to_pose(T_base_tool))
        _, result = run_action(client.node, action, goal, 60.0, executor=client.executor)
    finally:
        action.destroy()
    assert result.error_code == MoveTo.Result.SUCCESS, result.message
    return np.array(result.positions)


def landmarks_after(client: Client, t0_ns: int, timeout: float = STARTUP_TIMEOUT) -> Landmarks:
    """The first landmarks message of an image stamped after ``t0_ns`` (system clock)."""
    got = []

    def take(msg: Landmarks) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if stamp > t0_ns:
            got.append(msg)

    sub = client.node.create_subscription(Landmarks, 'landmarks', take, 10)
    try:
        if not client.spin_until(lambda: bool(got), timeout):
            pytest.fail(f'no landmarks within {timeout:.0f} s:\n{_logs(client.suite)}')
    finally:
        client.node.destroy_subscription(sub)
    return got[0]


def fully_in_view(camera: SimCamera, T_optical_marker: np.ndarray, length: float) -> bool:
    half = length / 2 * 1.5            # the marker and some of its white margin
    corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
    points = frames.apply(T_optical_marker, corners)
    if np.any(points[:, 2] <= 0):
        return False
    px = camera.camera.project(points, np.zeros(3), np.zeros(3))
    w, h = camera.camera.width, camera.camera.height
    return bool(np.all((px >= BORDER_PX) & (px <= [w - 1 - BORDER_PX, h - 1 - BORDER_PX])))


def pose_errors(msg: Landmarks, expected: dict) -> dict:
    """(kind, id) -> (translation [mm], rotation [deg]) against the truth."""
    errors = {}
    for mark in msg.landmarks:
        t, r = frames.transform_error(convert.pose_to_matrix(mark.pose.pose),
                                      expected[mark.kind, mark.id])
        errors[mark.kind, mark.id] = (t * 1e3, float(np.degrees(r)))
    return errors


def test_markers_arrive_with_their_ids_and_the_true_poses(camera_suite, truth):
    q = move_camera_above(camera_suite, truth, (0.25, 0.175), 0.40)
    msg = landmarks_after(camera_suite, time.time_ns() + 200_000_000)
    expected = truth.T_optical_targets(q)
    length = truth.sim.cell.landmarks.marker_length
    in_view = sorted(i for (kind, i), T in expected.items()
                     if kind == 'marker' and fully_in_view(truth, T, length))
    assert msg.header.frame_id == 'wrist_camera_optical'
    assert in_view == [0, 1, 2, 3]
    assert sorted(m.id for m in msg.landmarks if m.kind == Landmark.KIND_MARKER) == in_view
    errors = pose_errors(msg, expected)
    print('markers at 0.4 m, error mm / deg:',
          {i: tuple(round(e, 3) for e in err) for i, err in errors.items()})
    for mark in msg.landmarks:
        assert errors[mark.kind, mark.id][0] <= 1.0
        assert len(mark.corners) == 8 and mark.reprojection_error < 0.5
        assert mark.ambiguity_ratio >= 1.0
        cov = np.reshape(mark.pose.covariance, (6, 6))
        assert np.all(np.diag(cov) > 0)


def test_the_board_arrives_with_its_true_pose(camera_suite, truth):
    x, y, _ = truth.sim.cell.landmarks.board_pose
    q = move_camera_above(camera_suite, truth, (x, y), 0.35)
    msg = landmarks_after(camera_suite, time.time_ns() + 200_000_000)
    boards = [m for m in msg.landmarks if m.kind == Landmark.KIND_BOARD]
    assert [b.id for b in boards] == [0]
    board = boards[0]
    errors = pose_errors(msg, truth.T_optical_targets(q))
    print(f'board at 0.35 m: {errors["board", 0][0]:.4f} mm / {errors["board", 0][1]:.4f} deg, '
          f'{len(board.corner_ids)} corners')
    assert errors['board', 0][0] <= 1.0 and errors['board', 0][1] <= 0.1
    assert len(board.corner_ids) == 24 and len(board.corners) == 48
    assert np.isnan(board.ambiguity_ratio)


class DetectorStatus:
    """The detector's latest /diagnostics values (``_level``, ``_message`` besides)."""

    def __init__(self, client: Client) -> None:
        self.values: dict = {}
        self._sub = client.node.create_subscription(DiagnosticArray, '/diagnostics',
                                                    self._take, 10)

    def _take(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == STATUS:
                self.values = dict({kv.key: kv.value for kv in status.values},
                                   _level=status.level, _message=status.message)

    def count(self, key: str) -> int:
        return int(self.values.get(key, 0))


def test_bad_images_are_counted_and_the_detector_keeps_running(camera_suite):
    client = camera_suite
    status = DetectorStatus(client)
    # someone wants landmarks: the detector takes images only then
    wants = client.node.create_subscription(Landmarks, 'landmarks', lambda _: None, 10)
    assert client.spin_until(lambda: bool(status.values), 10.0), _logs(client.suite)
    before = dict(status.values)
    pub = client.node.create_publisher(Image, 'wrist_camera/image_raw',
                                       qos_profile_sensor_data)
    short = Image(height=480, width=752, encoding='mono8', step=752, data=bytes(1000))
    deep = Image(height=480, width=752, encoding='16UC1', step=1504, data=bytes(1504 * 480))
    short.header.frame_id = deep.header.frame_id = 'wrist_camera_optical'
    reasons = ('corrupt_image', 'unsupported_encoding')

    def counted() -> bool:
        return all(status.count(f'failed_{r}') > int(before.get(f'failed_{r}', 0))
                   for r in reasons)

    # best effort, depth 1, and mock_camera's images on the same topic: send each bad image
    # now and then until /diagnostics has counted both
    deadline = time.monotonic() + 15.0
    while not counted() and time.monotonic() < deadline:
        for image in (short, deep):
            pub.publish(image)
            client.spin_until(lambda: False, 0.1)
    client.node.destroy_publisher(pub)
    assert counted(), status.values
    assert status.values['_level'] == DiagnosticStatus.WARN     # failures in the period
    assert 'data' in status.values['last_failure'] or 'encoding' in status.values['last_failure']
    assert not client.suite.failed()
    out = status.count('frames_out')
    landmarks_after(client, time.time_ns(), 10.0)           # still detecting
    assert client.spin_until(lambda: status.count('frames_out') > out, 5.0)
    client.node.destroy_subscription(wants)


# -- configuration and the one-slot queue (no processes) ----------------------------------
def test_the_configuration_defaults_come_from_the_cell():
    config = configure('sawyer_close', '', 0.0, '', 'edges')
    assert (config.dictionary, config.marker_length) == ('DICT_5X5_100', 0.05)
    assert str(config.board).startswith('charuco:squares=7x5')
    assert Pipeline(config.dictionary, config.board).board_ids == set()
    same = configure('sawyer_close', 'DICT_4X4_50', 0.04, '', 'subpix')
    # the board's own markers are not singles
    assert Pipeline(same.dictionary, same.board).board_ids == set(range(17))
    assert configure('sawyer_close', 'none', 0.0, '', 'edges').dictionary is None


@pytest.mark.parametrize('args, words', [
    (('sawyer_close', 'DICT_FOO', 0.0, '', 'edges'), ['unknown marker dictionary', 'DICT_FOO']),
    (('sawyer_close', '', 0.0, '', 'apriltag'), ['apriltag', '2 fps']),
    (('sawyer_close', '', 0.0, 'charuco:squares=7x5', 'edges'), ['board spec', 'lacks']),
    (('sawyer_close', 'none', 0.0, 'none', 'edges'), ['nothing to detect']),
    (('iiwa7_close', '', 0.0, '', 'edges'), ['no marker dictionary']),
])
def test_a_bad_configuration_says_why(args, words):
    with pytest.raises(ValueError) as error:
        configure(*args)
    for word in words:
        assert word in str(error.value)
    assert isinstance(error.value, NotConfigured) == (args[0] == 'iiwa7_close')


def test_the_frame_queue_keeps_the_newest_in_order_and_counts_the_dropped():
    queue = FrameQueue(depth=3)
    for frame in (1, 2, 3, 4, 5):
        queue.put(frame)
    assert [queue.take(0.0) for _ in range(4)] == [3, 4, 5, None]
    assert queue.dropped == 2


def test_the_handoff_between_the_stages_waits_instead_of_dropping():
    handoff = Handoff()
    assert handoff.put(1, 0.0) and not handoff.put(2, 0.05)      # full: waits, then refuses
    taker = threading.Timer(0.05, handoff.take, args=(0.0,))
    taker.start()
    assert handoff.put(3, 5.0)                                    # goes in once 1 is taken
    taker.join()
    assert (handoff.take(0.0), handoff.take(0.0)) == (3, None)


@pytest.mark.parametrize('stage', [FrameQueue, Handoff])
def test_a_closed_stage_ends_a_long_wait_of_its_worker_at_once(stage):
    """The workers wait long at rest (spin.IDLE_WAKE); the node's destroy closes their stages,
    so its stop does not wait one out."""
    slot, got = stage(), []
    worker = threading.Thread(target=lambda: got.append(slot.take(600.0)))
    worker.start()
    slot.close()
    worker.join(timeout=30.0)
    assert not worker.is_alive() and got == [None]
    assert slot.take(600.0) is None                     # and every take after it


def test_an_unknown_dictionary_is_an_error_on_diagnostics_not_a_crash(camera_suite):
    """In this process, in its own namespace (its own topics and status name)."""
    client = camera_suite
    node = LandmarkDetector(context=client.node.context, namespace='bad',
                            parameter_overrides=[Parameter('dictionary', value='DICT_FOO')])
    client.executor.add_node(node)
    try:
        seen = {}

        def take(msg: DiagnosticArray) -> None:
            seen.update({s.name: s for s in msg.status})

        sub = client.node.create_subscription(DiagnosticArray, '/diagnostics', take, 10)
        wants = client.node.create_subscription(Landmarks, 'bad/landmarks', lambda _: None, 10)
        pub = client.node.create_publisher(Image, 'bad/wrist_camera/image_raw',
                                           qos_profile_sensor_data)

        def counted() -> bool:
            status = seen.get('bad/landmark_detector: health')
            values = {kv.key: kv.value for kv in status.values} if status else {}
            return int(values.get('failed_configuration', 0)) > 0

        deadline = time.monotonic() + 10.0
        while not counted() and time.monotonic() < deadline:
            pub.publish(Image(height=2, width=2, encoding='mono8', step=2, data=bytes(4)))
            client.spin_until(lambda: False, 0.2)
        status = seen['bad/landmark_detector: health']
        assert status.level == DiagnosticStatus.ERROR
        assert 'unknown marker dictionary' in status.message and 'DICT_FOO' in status.message
        assert counted()
        client.node.destroy_subscription(sub)
        client.node.destroy_subscription(wants)
        client.node.destroy_publisher(pub)
    finally:
        client.executor.remove_node(node)
        node.destroy_node()


def test_the_detector_takes_images_only_while_someone_wants_landmarks(camera_suite):
    """Issue 23.13: at rest (nobody subscribes to landmarks) the detector does not subscribe
    to the images, so the camera rests too; on e6ccb73 it always took them."""
    client = camera_suite
    node = LandmarkDetector(context=client.node.context, namespace='rest')
    client.executor.add_node(node)
    images = client.node.create_publisher(Image, 'rest/wrist_camera/image_raw',
                                          qos_profile_sensor_data)
    try:
        assert not client.spin_until(lambda: images.get_subscription_count() > 0, 1.5)
        wants = client.node.create_subscription(Landmarks, 'rest/landmarks', lambda _: None,
                                                10)
        assert client.spin_until(lambda: images.get_subscription_count() > 0, 10.0)
        client.node.destroy_subscription(wants)
        assert client.spin_until(lambda: images.get_subscription_count() == 0, 10.0)
    finally:
        client.node.destroy_publisher(images)
        client.executor.remove_node(node)
        node.destroy_node()


def test_images_arriving_while_the_executor_is_busy_are_all_taken():
    """Issue 23.17: with a reader queue of depth 1, every image that arrived while the
    executor was late replaced the previous one in DDS (32 % of 1280 x 800 frames at 100 Hz on
    5252a67). Five images sent while the executor does not spin are all taken afterwards."""
    with domain_coordinator.domain_id() as domain:
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = LandmarkDetector(context=context)
        client = rclpy.create_node('test_burst', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.add_node(client)
        try:
            client.create_subscription(Landmarks, 'landmarks', lambda _: None, 10)
            pub = client.create_publisher(Image, 'wrist_camera/image_raw',
                                          qos_profile_sensor_data)
            assert spin_until(client, lambda: pub.get_subscription_count() > 0, 30.0,
                              executor)
            before = node._counts['frames_in']
            for _ in range(5):                  # the executor is not spinning meanwhile
                pub.publish(Image(height=48, width=64, encoding='mono8', step=64,
                                  data=bytes(64 * 48)))
            spin_until(client, lambda: node._counts['frames_in'] - before >= 5, 10.0, executor)
            assert node._counts['frames_in'] - before == 5
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
            client.destroy_node()
            context.try_shutdown()
