"""mock_camera in this process on a private domain: what an image shows and when it says so."""
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.nodes.mock_camera import MockCamera
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import qos

JOINTS_STAMP = (1234, 567_000_000)      # far from now: the clock could not give it


@pytest.fixture
def context():
    with domain_coordinator.domain_id() as domain:
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        yield ctx
        ctx.try_shutdown()


def test_an_image_is_stamped_with_the_joint_states_it_shows(context):
    """Issue 22.9: the image of the joints of a joint_states message carries that message's
    stamp (as a real camera stamps the exposure), not the clock after rendering; on 5252a67 it
    was the clock, later than the joints it showed."""
    cell = load_cell(cell_file('sawyer_close'))
    names = list(kinematics.model_for(cell).joint_names)
    camera = MockCamera(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('rate_hz', value=20.0)])
    node = rclpy.create_node('test_mock_camera', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(camera)
    executor.add_node(node)
    images, infos = [], []
    node.create_subscription(Image, 'wrist_camera/image_raw', images.append,
                             qos_profile_sensor_data)
    node.create_subscription(CameraInfo, 'wrist_camera/camera_info', infos.append,
                             qos_profile_sensor_data)
    joints = JointState(name=names, position=[float(v) for v in cell.home])
    joints.header.stamp.sec, joints.header.stamp.nanosec = JOINTS_STAMP
    publisher = node.create_publisher(JointState, 'joint_states', qos.JOINT_STATES)
    node.create_timer(0.02, lambda: publisher.publish(joints))
    try:
        assert spin_until(node, lambda: len(images) >= 2 and infos, 30.0, executor), \
            'no image from mock_camera'
    finally:
        executor.shutdown(timeout_sec=1.0)
        camera.destroy_node()
        node.destroy_node()
    for msg in images + infos:
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == JOINTS_STAMP
    assert np.frombuffer(bytes(images[0].data), np.uint8).std() > 10, 'a blank image'


def test_nothing_is_rendered_while_nobody_subscribes_to_the_images(context):
    """Issue 23.13: an idle suite rendered 10 images a second nobody used (9 % of a core)."""
    cell = load_cell(cell_file('sawyer_close'))
    names = list(kinematics.model_for(cell).joint_names)
    camera = MockCamera(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('rate_hz', value=20.0)])
    node = rclpy.create_node('test_mock_camera_rest', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(camera)
    executor.add_node(node)
    publisher = node.create_publisher(JointState, 'joint_states', qos.JOINT_STATES)
    joints = JointState(name=names, position=[float(v) for v in cell.home])
    node.create_timer(0.02, lambda: publisher.publish(joints))
    images = []
    try:
        # joint_states flow, 20 ticks a second: none renders, and the camera does not even
        # subscribe to them (1 kHz unread cost it ~2 % of a core, and the robot a reader)
        assert not spin_until(node, lambda: camera._published > 0
                              or publisher.get_subscription_count() > 0, 1.5, executor)
        assert camera._timer.is_canceled()         # not even a timer wakes it at rest
        images_sub = node.create_subscription(Image, 'wrist_camera/image_raw', images.append,
                                              qos_profile_sensor_data)
        assert spin_until(node, lambda: len(images) >= 2, 30.0, executor), 'no image'
        assert publisher.get_subscription_count() == 1
        node.destroy_subscription(images_sub)      # the last viewer leaves: at rest again
        assert spin_until(node, lambda: camera._timer.is_canceled()
                          and publisher.get_subscription_count() == 0, 30.0, executor)
    finally:
        executor.shutdown(timeout_sec=1.0)
        camera.destroy_node()
        node.destroy_node()
