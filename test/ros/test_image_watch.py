"""ros.image_watch.ImageWatch, the image port over ``wrist_camera/image_raw``: the first image
after subscribing may take WAKE_ALLOWANCE s more (a camera that streams only to subscribers
starts when discovery has matched the new subscription), later ones only their own timeout."""
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
