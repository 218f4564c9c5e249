"""Camera-info files: ROS camera_calibration YAML, a CameraInfo message, OpenCV FileStorage."""
from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.core.landmarks.camera import CameraInfoError, CameraModel
from cobot_calib_ros.loaders import load_camera_info_yaml

TUTORIAL = Path(__file__).resolve().parents[2] / 'data' / 'opencv-aruco-tutorial'

ROS_YAML = """\
image_width: 752
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [700.1, 0, 375.2, 0, 699.8, 241.3, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28, 0.07, 0.0002, 0.0001, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [600, 0, 370, 0, 0, 600, 240, 0, 0, 0, 1, 0]
"""


def test_ros_camera_calibration_yaml_uses_k_and_d_not_p(tmp_path):
    path = tmp_path / 'camera.yaml'
    path.write_text(ROS_YAML)
    cam = load_camera_info_yaml(path)
    assert (cam.width, cam.height, cam.name, cam.distortion_model) == \
        (752, 480, 'narrow_stereo', 'plumb_bob')
    np.testing.assert_allclose(cam.K, [[700.1, 0, 375.2], [0, 699.8, 241.3], [0, 0, 1]])
    np.testing.assert_allclose(cam.D, [-0.28, 0.07, 0.0002, 0.0001, 0])
    assert cam.size_problem((480, 752, 3)) is None
    assert '640x480' in cam.size_problem((480, 640)).message


def test_camera_info_message_echo(tmp_path):
    path = tmp_path / 'info.yaml'
    path.write_text('header:\n  frame_id: cam_optical\nheight: 480\nwidth: 752\n'
                    'distortion_model: rational_polynomial\nd: [0.1, 0.01, 0, 0, 0, 0, 0, 0]\n'
                    'k: [700.0, 0.0, 376.0, 0.0, 700.0, 240.0, 0.0, 0.0, 1.0]\n---\n')
    cam = load_camera_info_yaml(path)
    assert (cam.width, cam.height, cam.distortion_model, len(cam.D)) == \
        (752, 480, 'rational_polynomial', 8)


def test_opencv_filestorage_files_of_the_tutorial():
    cam = load_camera_info_yaml(TUTORIAL / 'tutorial_camera_params.yml')
    assert (cam.width, cam.height) == (None, None)       # the file does not say
    np.testing.assert_allclose(cam.K[0], [628.158, 0, 324.099])
    np.testing.assert_allclose(cam.D, [0.0995485, -0.206384, 0.00754589, 0.00336531, 0])
    cam = load_camera_info_yaml(TUTORIAL / 'tutorial_camera_charuco.yml')
    assert (cam.width, cam.height) == (640, 480)
    assert cam.K[1, 1] == pytest.approx(456.76707935146891)


@pytest.mark.parametrize('text, words', [
    ('camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0]}\n',
     ['camera_matrix has 8 values', 'rows x cols = 3x3']),
    ('camera_matrix: {rows: 3, cols: 3}\n', ['camera_matrix lacks data']),
    ('image_width: 10\n', ['no camera_matrix key', 'image_width']),
    ('camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n'
     'distortion_model: kannala\n', ['kannala', 'not supported']),
    ('camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n'
     'distortion_coefficients: {rows: 1, cols: 3, data: [1, 2, 3]}\n',
     ['plumb_bob', 'got 3']),
    ('camera_matrix: [oops\n', ['not valid YAML']),
    ('%YAML:1.0\nsomething: 1\n', ['no camera_matrix']),
])
def test_errors_name_the_file_and_the_key(tmp_path, text, words):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CameraInfoError) as e:
        load_camera_info_yaml(path)
    assert str(e.value).startswith(str(path))
    for word in words:
        assert word in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(CameraInfoError, match='nope.yaml: cannot read'):
        load_camera_info_yaml(tmp_path / 'nope.yaml')


def test_model_validation():
    with pytest.raises(ValueError, match='3x3'):
        CameraModel(640, 480, np.eye(2))
    with pytest.raises(ValueError, match='fx, fy > 0'):
        CameraModel(640, 480, np.diag([-1.0, 1.0, 1.0]))
    cam = CameraModel(640, 480, np.eye(3), [])
    assert len(cam.D) == 5 and not cam.has_distortion
