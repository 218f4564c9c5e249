"""Image / CameraInfo messages <-> numpy and CameraModel (ros/images.py)."""
import cv2
import numpy as np
import pytest
from sensor_msgs.msg import Image

from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.ros.images import (camera_info_to_model, gray_to_image, image_to_gray,
                                        ImageMessageError, model_to_camera_info)

GRAY = np.arange(12 * 5, dtype=np.uint8).reshape(5, 12)


def test_mono8_round_trip():
    msg = gray_to_image(GRAY, 'cam')
    assert (msg.encoding, msg.step, msg.header.frame_id) == ('mono8', 12, 'cam')
    np.testing.assert_array_equal(image_to_gray(msg), GRAY)


@pytest.mark.parametrize('encoding', ['bgr8', 'rgb8'])
def test_colour_images_with_row_padding(encoding):
    bgr = np.random.default_rng(0).integers(0, 256, (5, 12, 3), dtype=np.uint8)
    pixels = bgr if encoding == 'bgr8' else bgr[:, :, ::-1]
    rows = np.zeros((5, 40), np.uint8)
    rows[:, :36] = pixels.reshape(5, 36)
    msg = Image(height=5, width=12, encoding=encoding, step=40, data=rows.tobytes())
    np.testing.assert_array_equal(image_to_gray(msg), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))


@pytest.mark.parametrize('fields, reason', [
    (dict(encoding='16UC1', step=24, data=bytes(120)), 'unsupported_encoding'),
    (dict(encoding='mono8', step=12, data=bytes(59)), 'corrupt_image'),
    (dict(encoding='mono8', step=10, data=bytes(50)), 'corrupt_image'),
    (dict(encoding='mono8', height=0, step=12, data=b''), 'empty_image'),
])
def test_bad_images_say_why(fields, reason):
    msg = Image(**dict(dict(height=5, width=12), **fields))
    with pytest.raises(ImageMessageError) as error:
        image_to_gray(msg)
    assert error.value.reason == reason


def test_camera_info_round_trip():
    K = np.array([[620.0, 0, 377.3], [0, 621.0, 238.6], [0, 0, 1]])
    camera = CameraModel(752, 480, K, [-0.11, 0.09, 0.0004, -0.0006, -0.03])
    msg = model_to_camera_info(camera, 'cam')
    assert msg.p[2] == 377.3 and msg.p[3] == 0.0
    back = camera_info_to_model(msg)
    np.testing.assert_array_equal(back.K, K)
    np.testing.assert_array_equal(back.D, camera.D)
    assert (back.width, back.height, back.name) == (752, 480, 'cam')
