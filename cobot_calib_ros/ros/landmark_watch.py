"""core.robot_port.CameraPort over ROS: the ``landmarks`` topic of landmark_detector.

Each cobot_calib_msgs/Landmarks message (one image: its header stamp, the markers and the board
posed in the optical frame) becomes a core.robot_port.LandmarkImage. The newest KEEP images are
kept, so a caller blocked in :meth:`LandmarkWatch.landmarks_after` (on its own thread) sees the
images that arrive on the subscriber's thread (a spin.Companion's) after the time it names.
The clock is the node's (ROS time: use_sim_time works), as the images' stamps are.

It subscribes only while a capture is on (a landmarks_after call, and LINGER s after the last
one, so the views of one capture follow each other without a new subscription): landmark_detector
and the camera rest while nobody subscribes (issue 23). Waking them (discovery matches the new
subscription, the detector subscribes to the images, the camera starts) can take seconds on a
loaded machine: the first image after subscribing gets image_watch.WAKE_ALLOWANCE s more,
counted from the subscription (image_watch.image_wait). A wait for an image stamped after a
time goes on past its timeout while messages keep coming stamped before it (the chain is behind,
not silent): both rules are image_watch.StampedWait's.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
import threading
import time

from cobot_calib_msgs.msg import Landmark, Landmarks
import numpy as np
from rclpy.clock import Clock, ClockType

from cobot_calib_ros.core.robot_port import CaptureFailed, LandmarkImage, Sighting
from cobot_calib_ros.ros import convert
from cobot_calib_ros.ros.image_watch import StampedWait, wake_deadline
from cobot_calib_ros.ros.time import stamp_to_ns

KEEP = 60           # images kept (2 s at 30 fps): more than arrive during one capture
LINGER = 10.0       # [s] subscribed after the last capture ended (released within 2 LINGER)
KINDS = {Landmark.KIND_MARKER: 'marker', Landmark.KIND_BOARD: 'board'}


def landmarks_to_image(msg: Landmarks) -> LandmarkImage:
    """One Landmarks message as the camera port gives it (unknown kinds left out)."""
    return LandmarkImage(stamp_to_ns(msg.header.stamp), tuple(
        Sighting(KINDS[lm.kind], int(lm.id), convert.pose_to_matrix(lm.pose.pose),
                 np.array(lm.pose.covariance, dtype=float).reshape(6, 6))
        for lm in msg.landmarks if lm.kind in KINDS))


class LandmarkWatch:
    """The camera port: ``node`` (if given) subscribes ``landmarks`` to :meth:`on_landmarks`;
    ``now_ns`` is the clock the images are stamped in."""

    def __init__(self, now_ns: Callable[[], int], node=None) -> None:
        self._now_ns = now_ns
        self._cond = threading.Condition()
        self._images: deque[LandmarkImage] = deque(maxlen=KEEP)
        self.messages = 0
        self._node = node
        self._sub = None
        self._capturing = 0                 # landmarks_after calls in progress
        self._arrived = None                # time.monotonic() of the newest message
        self._woken_by = 0.0                # image_watch.wake_deadline() until a message came
        self._idle_since = time.monotonic()
        if node is not None:
            # a look every LINGER s, not every second (robot_calls.MOVE_CLIENT_LINGER: why)
            node.create_timer(LINGER, self._release_when_idle,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))    # wall time

    def _subscribe(self) -> None:
        with self._cond:
            self._capturing += 1
            if self._sub is not None or self._node is None:
                return
            self._woken_by = wake_deadline()
            self._sub = self._node.create_subscription(Landmarks, 'landmarks',
                                                       self.on_landmarks, 10)

    def _done(self) -> None:
        with self._cond:
            self._capturing -= 1
            self._idle_since = time.monotonic()

    def _release_when_idle(self) -> None:
        """Unsubscribe LINGER s after the last capture (the node's executor thread)."""
        with self._cond:
            if self._sub is None or self._capturing or \
                    time.monotonic() - self._idle_since < LINGER:
                return
            sub, self._sub = self._sub, None
        self._node.destroy_subscription(sub)

    def now_ns(self) -> int:
        return self._now_ns()

    def on_landmarks(self, msg: Landmarks) -> None:
        image = landmarks_to_image(msg)
        with self._cond:
            self._woken_by = 0.0
            self._arrived = time.monotonic()
            self.messages += 1
            self._images.append(image)
            self._cond.notify_all()

    def landmarks_after(self, t_ns: int, wanted: Callable[[LandmarkImage], bool],
                        max_images: int, timeout: float) -> LandmarkImage:
        """See core.robot_port.CameraPort; images are taken in stamp order."""
        self._subscribe()
        try:
            return self._landmarks_after(t_ns, wanted, max_images, timeout)
        finally:
            self._done()

    def _landmarks_after(self, t_ns: int, wanted: Callable[[LandmarkImage], bool],
                         max_images: int, timeout: float) -> LandmarkImage:
        seen, last, after = 0, None, t_ns
        with self._cond:
            wait = StampedWait(timeout, self._woken_by)
            while seen < max_images:
                if wait.over(self._arrived, found=last is not None):
                    break
                image = next((im for im in self._images if im.stamp_ns > after), None)
                if image is None:
                    wait.pause(self._cond)
                    continue
                seen, last, after = seen + 1, image, image.stamp_ns
                if wanted(image):
                    break
            if last is None:
                stamped = '' if not self._images else (
                    f', stamped {(t_ns - self._images[-1].stamp_ns) * 1e-9:.3f} s before that '
                    'time')
                raise CaptureFailed(
                    f'no landmarks message of an image stamped after {t_ns * 1e-9:.3f} s '
                    f'{wait.said(self._arrived, stamped)}; are mock_camera / the camera driver '
                    'and landmark_detector up?')
        return last
