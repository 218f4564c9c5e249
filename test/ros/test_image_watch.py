"""ros.image_watch.ImageWatch, the image port over ``wrist_camera/image_raw``: the first image
after subscribing may take WAKE_ALLOWANCE s more (a camera that streams only to subscribers
starts when discovery has matched the new subscription), later ones only their own timeout, and
LAG_ALLOWANCE s more while images keep coming stamped too early (a camera that is behind)."""
import threading
import time

import pytest
import rclpy
from rclpy.context import Context
from sensor_msgs.msg import Image

from cobot_calib_ros.core.robot_port import CaptureFailed
from cobot_calib_ros.ros import image_watch
from cobot_calib_ros.ros.image_watch import ImageWatch


def _image(sec: int) -> Image:
    msg = Image(height=2, width=3, encoding='mono8', step=3, data=bytes(range(6)))
    msg.header.stamp.sec = sec
    return msg


def test_the_first_image_after_subscribing_may_take_the_wake_allowance(monkeypatch):
    monkeypatch.setattr(image_watch, 'WAKE_ALLOWANCE', 10.0)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('image_watch_wake_test', context=context)
    late = None
    try:
        watch = ImageWatch(lambda: 0, node)
        late = threading.Timer(0.5, watch._on_image, (_image(1),))   # what the topic brings
        late.start()
        stamp, gray = watch.image_after(0, 0.05)
        assert stamp == 1_000_000_000 and gray.tolist() == [[0, 1, 2], [3, 4, 5]]
        start = time.monotonic()
        with pytest.raises(CaptureFailed, match='no image on'):
            watch.image_after(stamp, 0.05)                          # awake: its own 0.05 s
        assert time.monotonic() - start < 5.0
    finally:
        if late is not None:
            late.cancel()
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_camera_that_is_behind_is_waited_for():
    """Images keep coming stamped before the time asked for: the wait goes on past its 0.2 s
    (LAG_ALLOWANCE) and takes the first image stamped after it."""
    watch = ImageWatch(lambda: 0, node=None)
    watch._sub = object()                   # subscribed: image_after does not subscribe
    stamps, stop = iter(range(1, 100)), threading.Event()

    def behind_by_two_seconds() -> None:   # 20 images a second, one second later each
        while not stop.wait(0.05):
            watch._on_image(_image(next(stamps)))
    feeder = threading.Thread(target=behind_by_two_seconds, daemon=True)
    feeder.start()
    try:
        started = time.monotonic()
        stamp, _ = watch.image_after(12_000_000_000, 0.2)          # 0.6 s after its start
        waited = time.monotonic() - started
    finally:
        stop.set()
        feeder.join()
    assert stamp == 13_000_000_000 and 0.3 < waited < 5.0, (stamp, waited)
