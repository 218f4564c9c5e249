"""ros.landmark_watch.LandmarkWatch, the camera port over the ``landmarks`` topic: messages fed
in directly (the subscription only calls on_landmarks), no ROS graph."""
import threading
import time

import numpy as np
import pytest

from cobot_calib_msgs.msg import Landmark, Landmarks

from cobot_calib_ros.core.robot_port import CaptureFailed
from cobot_calib_ros.ros import image_watch
from cobot_calib_ros.ros.landmark_watch import landmarks_to_image, LandmarkWatch

S = 1_000_000_000


def _msg(sec: int, *landmarks: Landmark) -> Landmarks:
    msg = Landmarks(landmarks=list(landmarks))
    msg.header.stamp.sec = sec
    return msg


def _marker(i: int) -> Landmark:
    return Landmark(kind=Landmark.KIND_MARKER, id=i)


def _has(marker_id):
    return lambda image: image.find('marker', marker_id) is not None


def test_a_message_becomes_an_image_of_posed_sightings():
    board = Landmark(kind=Landmark.KIND_BOARD, id=40)
    board.pose.pose.position.x, board.pose.pose.orientation.w = 0.25, 1.0
    board.pose.covariance = [float(k) for k in range(36)]
    image = landmarks_to_image(_msg(10, _marker(3), board))
    assert image.stamp_ns == 10 * S
    assert [(s.kind, s.id) for s in image.sightings] == [('marker', 3), ('board', 40)]
    seen = image.find('board')
    np.testing.assert_allclose(seen.T_optical_target[:3, 3], [0.25, 0, 0])
    assert seen.covariance.shape == (6, 6) and seen.covariance[1, 0] == 6.0


def test_only_images_stamped_after_the_time_count():
    """As hand_eye_calibrator's BoardWatch did: a board seen before the arrival is not one."""
    watch = LandmarkWatch(lambda: 0)
    watch.on_landmarks(_msg(10, _marker(3)))
    with pytest.raises(CaptureFailed, match='no landmarks message'):
        watch.landmarks_after(10 * S, _has(3), 3, 0.05)
    assert watch.landmarks_after(10 * S - 1, _has(3), 3, 0.05).stamp_ns == 10 * S


def test_the_first_image_showing_the_marker_else_the_last_of_max_images():
    watch = LandmarkWatch(lambda: 0)
    for sec, marker in ((11, 1), (12, 2), (13, 5), (14, 5)):
        watch.on_landmarks(_msg(sec, _marker(marker)))
    assert watch.landmarks_after(10 * S, _has(5), 3, 0.05).stamp_ns == 13 * S
    assert watch.landmarks_after(10 * S, _has(7), 3, 0.05).stamp_ns == 13 * S   # 3 looked at
    assert watch.landmarks_after(10 * S, _has(7), 9, 0.05).stamp_ns == 14 * S   # all, timeout


def test_an_image_arriving_while_waiting_is_taken():
    watch = LandmarkWatch(lambda: 0)
    waiting = threading.Event()
    real_wait = watch._cond.wait

    def wait_then_deliver(timeout):
        if not waiting.is_set():
            waiting.set()
            threading.Thread(target=watch.on_landmarks, args=(_msg(20, _marker(2)),)).start()
        return real_wait(timeout)
    watch._cond.wait = wait_then_deliver
    image = watch.landmarks_after(19 * S, _has(2), 3, 10.0)
    assert waiting.is_set() and image.stamp_ns == 20 * S and watch.messages == 1


def test_images_that_keep_coming_without_the_marker_end_at_the_timeout():
    """A stream of images none of which shows the board (hand-eye asks for any number)."""
    watch = LandmarkWatch(lambda: 0)
    for sec in range(1, 40):
        watch.on_landmarks(_msg(sec, _marker(1)))
    clock = iter(range(100))
    import cobot_calib_ros.ros.landmark_watch as module
    real = module.time.monotonic
    module.time.monotonic = lambda: float(next(clock))       # one second per look
    try:
        image = watch.landmarks_after(0, lambda im: im.find('board') is not None, 2 ** 31, 5.0)
    finally:
        module.time.monotonic = real
    assert image.find('board') is None and image.stamp_ns == 4 * S     # looks at 1..4 s of 5


def test_a_chain_that_is_behind_is_waited_for_and_a_silent_one_is_not():
    """Messages keep coming, stamped before the time asked for (camera, detector and DDS
    behind on a busy machine): the wait goes on past its timeout and takes the first image
    stamped after it. Without messages it ends at its timeout and says none came."""
    watch = LandmarkWatch(lambda: 0)
    stamps = iter(range(1, 100))
    stop = threading.Event()

    def behind_by_two_seconds():            # 20 messages a second, one second later each
        while not stop.wait(0.05):
            sec = next(stamps)
            watch.on_landmarks(_msg(sec, _marker(3)))
    feeder = threading.Thread(target=behind_by_two_seconds, daemon=True)
    feeder.start()
    try:
        started = time.monotonic()
        image = watch.landmarks_after(12 * S, _has(3), 1, 0.2)    # 0.6 s after its start
        waited = time.monotonic() - started
    finally:
        stop.set()
        feeder.join()
    assert image.stamp_ns == 13 * S and 0.3 < waited < 5.0, (image.stamp_ns, waited)
    silent = LandmarkWatch(lambda: 0)
    started = time.monotonic()
    with pytest.raises(CaptureFailed, match=r'within 0 s \(none came\)'):
        silent.landmarks_after(0, _has(3), 1, 0.2)
    assert time.monotonic() - started < 1.0


@pytest.fixture
def node():
    """A node in a context of its own, for a watch that subscribes (nothing spins it: the
    tests feed the watch themselves)."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('landmark_watch_test', context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_subscribed_only_during_a_capture_and_a_while_after(node, monkeypatch):
    """Issue 23.13: the detector and the camera rest while nobody subscribes to landmarks, so
    the watch subscribes for a capture and LINGER s after it, not all the time."""
    from cobot_calib_ros.ros import landmark_watch

    monkeypatch.setattr(image_watch, 'WAKE_ALLOWANCE', 0.0)
    watch = LandmarkWatch(lambda: 0, node)
    topics = lambda: [s.topic_name for s in node.subscriptions]     # noqa: E731
    assert '/landmarks' not in topics()
    during = []
    with pytest.raises(CaptureFailed):
        watch.landmarks_after(0, lambda im: during.append(topics()) or False, 1, 0.05)
    watch.on_landmarks(_msg(1, _marker(3)))                 # what the topic would bring
    assert watch.landmarks_after(0, lambda im: during.append(topics()) or True, 1, 0.05)
    assert during == [['/landmarks']]
    watch._release_when_idle()                              # within LINGER: kept
    assert topics() == ['/landmarks']
    monkeypatch.setattr(landmark_watch, 'LINGER', 0.0)
    watch._release_when_idle()
    assert topics() == []


def test_the_first_image_after_subscribing_may_take_the_wake_allowance(node, monkeypatch):
    """Waking the detector and the camera took over 5 s on a loaded machine: the first view of
    a capture failed. The first message after a new subscription gets WAKE_ALLOWANCE s more;
    later ones only their own timeout."""
    monkeypatch.setattr(image_watch, 'WAKE_ALLOWANCE', 10.0)
    watch = LandmarkWatch(lambda: 0, node)
    late = threading.Timer(0.5, watch.on_landmarks, (_msg(1, _marker(3)),))
    late.start()
    try:
        assert watch.landmarks_after(0, lambda im: True, 1, 0.05).stamp_ns == 1_000_000_000
        start = time.monotonic()
        with pytest.raises(CaptureFailed, match='no landmarks message'):
            # awake: its own 0.05 s, and LAG_LOOK s after the last message (_behind)
            watch.landmarks_after(1_000_000_000, lambda im: True, 1, 0.05)
        assert time.monotonic() - start < 5.0
    finally:
        late.cancel()


def test_a_camera_that_never_starts_costs_the_allowance_once(node, monkeypatch):
    """The allowance is counted from the subscription: with no camera at all, the first view
    waits it out and the next ones only their own timeout (a hand-eye capture skips such views
    one after the other)."""
    monkeypatch.setattr(image_watch, 'WAKE_ALLOWANCE', 3.0)
    watch = LandmarkWatch(lambda: 0, node)
    waits = []
    for _ in range(2):
        start = time.monotonic()
        with pytest.raises(CaptureFailed, match='no landmarks message'):
            watch.landmarks_after(0, lambda im: True, 1, 0.05)
        waits.append(time.monotonic() - start)
    assert waits[0] >= 3.0 and waits[1] < 2.5, waits
