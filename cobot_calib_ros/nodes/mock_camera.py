"""mock_camera: stands in for the wrist camera's driver (simulation only, like mock_robot).

Renders (sim.camera.SimCamera) what the camera on the TRUE robot sees of the cell's fiducials at
the joints of the latest ``joint_states`` and publishes ``wrist_camera/image_raw`` (mono8,
frame_id the cell's camera frame) and ``wrist_camera/camera_info``
(the cell's nominal intrinsics; the images are drawn through the simulation's true lens, ``simulation: camera: intrinsics/distortion``, when it gives one) at ``rate_hz``, sensor-data QoS. It shares no memory
with mock_robot: it loads the same cell file and builds the same true robot (same seed), and
follows the arm through joint_states. Those come at 1 kHz and a frame needs only the newest:
they go to a depth-1 subscription of a hidden helper node that no executor spins, and each
frame takes the newest one from it (handling all 1 kHz in callbacks cost 30 % of a core); that
subscription exists only while someone subscribes to the images (even unread, 1 kHz reliable
joint_states cost the camera ~2 % of a core and mock_robot's writer a second reader). A
cell without a camera (cell: camera:, landmarks:) leaves the node idle, WARN on /diagnostics.
While nobody subscribes to ``wrist_camera/image_raw`` it renders and publishes nothing (as a
driver that streams only to subscribers; landmark_detector subscribes only while someone wants
landmarks), so an idle suite does not render.

Stamps: an image is stamped with the stamp of the joint_states it shows (as a real camera
stamps the exposure), not with the clock after rendering: on a busy machine the newest
joint_states here can be older than the arm, and a consumer that pairs images with the robot by
stamp (hand_eye_calibrator: only images stamped after the arm came to rest) must not take an
image of the arm before it arrived for one after.

Parameters (read at start-up): cell_file, rate_hz (default 10), width and height (0: the
cell's resolution; another one scales the lens to it, e.g. 1280 x 800).

/diagnostics (1 Hz): ``published`` frames, ``render_ms_mean`` over the last second; WARN while
no joint_states have arrived (nothing is published then); 'resting' while nobody subscribes.
"""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, JointState

from cobot_calib_ros import paths
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, OK, WARN
from cobot_calib_ros.ros.images import gray_to_image, model_to_camera_info
from cobot_calib_ros.ros.params import read_once
from cobot_calib_ros.sim.camera import scaled_camera, SimCamera
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

LATEST_ONLY = QoSProfile(depth=1, reliability=qos_profile_sensor_data.reliability)


class MockCamera(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('mock_camera', **kwargs)
        cell_file = read_once(self, 'cell_file', paths.DEFAULT_CELL,
                              'Cell scenario YAML (cell: camera/landmarks, simulation: camera): '
                              'a path or a name in config/cells')
        rate = read_once(self, 'rate_hz', 10.0, 'Image rate [Hz]', 0.1, 200.0)
        width = read_once(self, 'width', 0, "Image width [px]; 0 = the cell's (the lens "
                          'is scaled to it, e.g. 1280 x 800)', 0, 10000)
        height = read_once(self, 'height', 0, "Image height [px]; 0 = the cell's", 0, 10000)
        sim = load_simulation(paths.cell_file(cell_file))
        self._joints: bytes | None = None
        self._published = 0
        self._render_s: list[float] = []
        self._diagnostics = Diagnostics(self, hardware_id='wrist_camera', update=self._diagnose)
        self._camera = None
        if sim.cell.camera is None or sim.cell.landmarks is None:
            self.get_logger().warning(f'cell {sim.cell.name!r} has no camera or no landmarks '
                                      '(cell: camera:, landmarks:); no images')
            return
        robot = SimRobot(sim)          # for its true chain only: same seed, same true robot
        self._joint_names = list(robot.model.joint_names)
        camera = sim.cell.camera.camera_model()
        if width or height:
            camera = scaled_camera(camera, width or camera.width, height or camera.height)
        self._camera = SimCamera(sim, robot, camera)
        self._frame_id = sim.cell.camera.frame_id
        self._info = model_to_camera_info(self._camera.camera, self._frame_id)
        # the frame timer runs only while someone subscribes to the images: at rest it woke
        # the executor 10 times a second for nobody (0.85 % of a core, bench_idle)
        self._image_pub = self.create_publisher(
            Image, 'wrist_camera/image_raw', qos_profile_sensor_data,
            event_callbacks=PublisherEventCallbacks(matched=self._on_matched))
        self._info_pub = self.create_publisher(CameraInfo, 'wrist_camera/camera_info',
                                               qos_profile_sensor_data)
        self._poll = Node(f'_{self.get_name()}_joints', namespace=self.get_namespace(),
                          context=self.context, start_parameter_services=False)
        self._joint_sub = None          # while someone subscribes to the images
        self._timer = self.create_timer(1.0 / rate, self._tick)
        if not self._image_pub.get_subscription_count():
            self._timer.cancel()
        camera = self._camera.camera
        self.get_logger().info(f'{camera.width}x{camera.height} px on {self._frame_id} at '
                               f'{rate:g} Hz, {len(self._camera.targets)} fiducials')

    def destroy_node(self):
        if self._camera is not None:
            self._poll.destroy_node()
        return super().destroy_node()

    def _positions(self) -> tuple[np.ndarray, Time] | None:
        """The arm's joints [rad] from the newest joint_states, in the model's order, and
        that message's stamp."""
        sub = self._joint_sub
        if sub is None:
            sub = self._joint_sub = self._poll.create_subscription(
                JointState, 'joint_states', lambda _: None, LATEST_ONLY, raw=True)
        with sub.handle:                # as an executor takes a message, but only the newest
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
        if taken is not None:
            self._joints = taken[0]
        if self._joints is None:
            return None
        msg = deserialize_message(self._joints, JointState)
        by_name = dict(zip(msg.name, msg.position))
        if not all(n in by_name for n in self._joint_names):
            self.get_logger().warning(f'joint_states lack joints of {self._joint_names}',
                                      throttle_duration_sec=5.0)
            return None
        return np.array([by_name[n] for n in self._joint_names]), msg.header.stamp

    def _tick(self) -> None:
        if not self._image_pub.get_subscription_count():
            self._rest()                            # nobody needs images
            return
        joints = self._positions()
        if joints is None:
            return
        q, stamp = joints
        start = time.perf_counter()
        image = self._camera.render(q)
        self._render_s.append(time.perf_counter() - start)
        self._info.header.stamp = stamp
        self._info_pub.publish(self._info)          # first: a detector needs it for the image
        self._image_pub.publish(gray_to_image(image, self._frame_id, stamp))
        self._published += 1

    def _on_matched(self, info) -> None:
        """A subscriber to the images came or went: frames while there is one."""
        timer = getattr(self, '_timer', None)
        if timer is None:
            return
        if info.current_count > 0 and timer.is_canceled():
            timer.reset()
        elif info.current_count == 0 and not timer.is_canceled():
            timer.cancel()
            self._rest()

    def _rest(self) -> None:
        """Stop following the arm; the next image waits for joint_states newer than now."""
        if self._joint_sub is not None:
            self._poll.destroy_subscription(self._joint_sub)
            self._joint_sub, self._joints = None, None

    def _diagnose(self) -> None:
        times, self._render_s = self._render_s, []
        level, message = OK, 'publishing images'
        if self._camera is None:
            level, message = WARN, 'the cell has no camera or no landmarks: no images'
        elif not self._image_pub.get_subscription_count():
            level, message = OK, 'resting: nobody subscribes to wrist_camera/image_raw'
        elif self._joints is None:
            level, message = WARN, 'no joint_states yet: no image published'
        self._diagnostics.set(
            level, message, published=self._published,
            render_ms_mean=f'{1e3 * float(np.mean(times)):.2f}' if times else 'nan')


def main(args=None) -> None:
    spin.run(MockCamera, args)


if __name__ == '__main__':
    main()
