"""core.landmarks.intrinsics_capture.ImagePort over ROS: the camera's ``wrist_camera/image_raw``.

Subscribed from the first image asked for until :meth:`ImageWatch.release` (the end of a
capture: a camera driver that streams only to subscribers, mock_camera, rests otherwise); the
newest KEEP messages are kept, converted to mono8 when taken. The clock is the node's (ROS
time), as the images' stamps are. The first image after subscribing may take WAKE_ALLOWANCE s
more; a wait goes on past its timeout while images keep coming stamped before the time it asks
for (behind: LAG_ALLOWANCE). Both rules hold for ros.landmark_watch too.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
import threading
import time

import numpy as np
from numpy.typing import NDArray
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from cobot_calib_ros.core.robot_port import CaptureFailed
from cobot_calib_ros.ros.images import image_to_gray, ImageMessageError
from cobot_calib_ros.ros.time import stamp_to_ns

KEEP = 4
TOPIC = 'wrist_camera/image_raw'
# [s] added to the wait for the first image after subscribing: a camera that streams only to
# subscribers starts when discovery has matched the new subscription, and on two loaded cores
# (load 10-20, a test run) that took over 5 s; the first view of a capture failed
WAKE_ALLOWANCE = 15.0
# [s] a wait for an image stamped after a time goes on up to this much longer while messages
# keep coming (one within LAG_LOOK s), all stamped before it: the camera, the detector and DDS
# are behind on a busy machine, the images are not missing. A hand-eye capture skipped two views
# in a row ("no landmarks message of an image stamped after ... within 5 s") in a test run on
# two saturated cores; views before and after saw the board.
LAG_ALLOWANCE = 15.0
LAG_LOOK = 1.0


def wake_deadline() -> float:
    """The end of a new subscription's WAKE_ALLOWANCE (monotonic [s]), taken when subscribing;
    0.0 once a message has come."""
    return time.monotonic() + WAKE_ALLOWANCE


def image_wait(timeout: float, woken_by: float) -> float:
    """How long [s] to wait for an image: ``timeout``, or until ``timeout`` after ``woken_by``
    (:func:`wake_deadline`) when that is later. Counted from the subscription, so a camera that
    never starts costs WAKE_ALLOWANCE once, not at every view."""
    return max(timeout, woken_by + timeout - time.monotonic())


class StampedWait:
    """One wait, under its watch's condition, for a message stamped after a time: ``timeout``
    s (longer for a new subscription's first message: image_wait), and up to LAG_ALLOWANCE s
    more while messages keep coming (one within LAG_LOOK s), all stamped before that time."""

    def __init__(self, timeout: float, woken_by: float) -> None:
        timeout = image_wait(timeout, woken_by)
        self.start = time.monotonic()
        self._deadline = self.start + timeout
        self._lag_end = self._deadline + LAG_ALLOWANCE

    def over(self, arrived: float | None, found: bool = False) -> bool:
        """Whether to stop looking: the timeout has passed and something was ``found``, or
        the chain is not behind (``arrived``: time.monotonic() of the newest message, None
        if none came)."""
        now = time.monotonic()
        behind = now < self._lag_end and arrived is not None and now - arrived <= LAG_LOOK
        return now >= self._deadline and (found or not behind)

    def pause(self, cond: threading.Condition) -> None:
        """Until a message comes (notified), the timeout, or the next look while behind."""
        remaining = self._deadline - time.monotonic()
        cond.wait(remaining if remaining > 0 else LAG_LOOK / 4)

    def said(self, arrived: float | None, more: str = '') -> str:
        """How long it waited and what came (and ``more`` on that), for a failure message."""
        now = time.monotonic()
        came = 'none came' if arrived is None else f'the newest came {now - arrived:.1f} s ago'
        return f'within {now - self.start:.0f} s ({came}{more})'


class ImageWatch:
    """The image port on ``node`` (a spin.Companion's node: its executor delivers the images
    while a caller blocks in :meth:`image_after` on another thread)."""

    def __init__(self, now_ns: Callable[[], int], node) -> None:
        self._now_ns, self._node = now_ns, node
        self._cond = threading.Condition()
        self._images: deque[Image] = deque(maxlen=KEEP)
        self._sub = None
        self._woken_by = 0.0        # wake_deadline() of the subscription until an image came
        self._arrived = None        # time.monotonic() of the newest image

    def release(self) -> None:
        """Unsubscribe (until the next image asked for)."""
        with self._cond:
            sub, self._sub = self._sub, None
            self._images.clear()
        if sub is not None:
            self._node.destroy_subscription(sub)

    def now_ns(self) -> int:
        return self._now_ns()

    def _on_image(self, msg: Image) -> None:
        with self._cond:
            self._woken_by = 0.0
            self._arrived = time.monotonic()
            self._images.append(msg)
            self._cond.notify_all()

    def image_after(self, t_ns: int, timeout: float) -> tuple[int, NDArray[np.uint8]]:
        if self._sub is None:
            self._woken_by = wake_deadline()
            self._sub = self._node.create_subscription(Image, TOPIC, self._on_image,
                                                       qos_profile_sensor_data)
        with self._cond:
            wait = StampedWait(timeout, self._woken_by)
            while True:
                msg = next((m for m in self._images if stamp_to_ns(m.header.stamp) > t_ns),
                           None)
                if msg is not None or wait.over(self._arrived):
                    break
                wait.pause(self._cond)
            if msg is None:
                raise CaptureFailed(f'no image on {TOPIC} stamped after {t_ns * 1e-9:.3f} s '
                                    f'{wait.said(self._arrived)}; is the camera driver '
                                    '(mock_camera) up?')
        try:
            return stamp_to_ns(msg.header.stamp), np.ascontiguousarray(image_to_gray(msg))
        except ImageMessageError as e:
            raise CaptureFailed(f'image refused: {e}') from None
