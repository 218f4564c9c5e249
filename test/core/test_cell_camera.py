"""The cell file's wrist camera and landmarks (issue 11): optional, validated with file:line."""
import shutil

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import CellFileError
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.paths import cell_file

SAWYER = cell_file('sawyer_close')


def test_the_sawyer_cell_has_a_camera_and_landmarks():
    cell = load_cell(SAWYER)
    camera = cell.camera.camera_model()
    assert (camera.width, camera.height, camera.name) == (752, 480, 'wrist_camera_optical')
    assert camera.distortion_model == 'plumb_bob' and len(camera.D) == 5
    marks = cell.landmarks
    assert marks.dictionary == 'DICT_5X5_100' and marks.marker_length == 0.05
    assert sorted(marks.markers) == [0, 1, 2, 3, 4, 5]
    assert BoardSpec.parse(marks.board).n_corners == 24


def test_a_cell_without_them_still_loads():
    cell = load_cell(cell_file('iiwa7_close'))
    assert cell.camera is None and cell.landmarks is None


def test_nominal_target_poses_lie_on_the_flat_table():
    marks = load_cell(SAWYER).landmarks
    x, y, yaw = marks.markers[1]
    T = marks.T_user_marker(1)
    np.testing.assert_allclose(T[:3, 3], [x, y, 0.0])
    np.testing.assert_allclose(T[:3, :3], frames.rot_z(yaw))      # z up, out of the face
    T_board = marks.T_user_board()
    spec = BoardSpec.parse(marks.board)
    centre = frames.apply(T_board, [*np.array(spec.size) / 2, 0.0])
    np.testing.assert_allclose(centre, [*marks.board_pose[:2], 0.0], atol=1e-12)
    np.testing.assert_allclose(T_board[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)  # z into it


def _broken(tmp_path, old: str, new: str):
    text = SAWYER.read_text()
    assert old in text
    path = tmp_path / 'broken.yaml'
    path.write_text(text.replace(old, new, 1))
    shutil.copy(SAWYER.parent / 'sawyer.urdf', tmp_path)     # the robot's URDF, beside it
    return path


@pytest.mark.parametrize('old, new, words', [
    ('    dictionary: DICT_5X5_100', '    dictionary: DICT_5X5_99',
     ['cell.landmarks.dictionary', 'unknown marker dictionary', 'DICT_5X5_100']),
    ('      0: [0.25, 0.08, 0.0]', '      0: [0.25, 0.08]',
     ['cell.landmarks.markers.0', '3 finite']),
    ('    marker_length: 0.050', '    marker_length: 50',
     ['cell.landmarks.marker_length', 'metres']),
    ('square=0.03,', 'square=0.01,', ['cell.landmarks.board.spec', 'marker']),
    ('    resolution: [752, 480]', '    resolution: [752.5, 480]', ['cell.camera.resolution']),
    ('    distortion: [-0.11, 0.09, 0.0004, -0.0006, -0.03]', '    distortion: [-0.11, 0.09]',
     ['cell.camera', 'coefficients']),
])
def test_a_broken_camera_or_landmark_names_file_line_and_key(tmp_path, old, new, words):
    path = _broken(tmp_path, old, new)
    with pytest.raises(CellFileError) as error:
        load_cell(path)
    assert str(error.value).startswith(f'{path}:')
    for word in words:
        assert word in str(error.value)
