"""`cobot-calib detect` on real photos, in-process (no ROS graph needed)."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cobot_calib_ros.cli.main import main

DATA = Path(__file__).resolve().parents[1] / 'data' / 'opencv-aruco-tutorial'
SINGLE = DATA / 'singlemarkersoriginal.jpg'
BOARD_PHOTO = DATA / 'choriginal.jpg'
BOARD = 'charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250'
GRID_PHOTO = DATA.parent / 'industrial-calibration' / 'aruco.jpg'
GOLD = {t['image']: t for t in
        json.loads((DATA / 'expected_detections.json').read_text())['tests']}


def _run(capsys, *argv):
    code = main(['detect', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def _json_lines(out: str) -> list[dict]:
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_json_ids_corners_and_poses_of_the_single_markers_photo(capsys):
    code, out, err = _run(capsys, SINGLE, '--json', '--refine', 'subpix', '--camera-info',
                          DATA / 'tutorial_camera_params.yml', '--marker-length', '0.05')
    assert code == 0, err
    [result] = _json_lines(out)
    gold = GOLD[SINGLE.name]
    markers = {m['id']: m for m in result['markers']}
    assert sorted(markers) == sorted(gold['ids'])
    for marker_id, corners in zip(gold['ids'], gold['corners_px']):
        np.testing.assert_allclose(markers[marker_id]['corners'], np.reshape(corners, (4, 2)),
                                   atol=gold['tolerance_px'])
    pose = markers[40]['pose']
    assert pose['frame'] == 'T_optical_marker'
    np.testing.assert_allclose(pose['translation'], [0.0638, 0.0734, 0.6759], atol=0.005)
    assert np.array(pose['covariance']).shape == (6, 6) and pose['mirror_ratio'] > 2
    assert (result['width'], result['height'], result['dictionary']) == (640, 480,
                                                                          'DICT_6X6_250')


def test_text_output_states_the_conventions_and_board_pose(capsys, tmp_path):
    code, out, err = _run(capsys, BOARD_PHOTO, '--board', BOARD, '--camera-info',
                          DATA / 'tutorial_camera_charuco.yml', '--annotate', tmp_path / 'a.png')
    assert code == 0, err
    assert 'origin at the centre of the top-left pixel' in ' '.join(out.split())
    assert 'T_optical_board: xyz (-0.0912, -0.1890, 0.3987) m' in out
    assert '24 corner(s) from 17 marker(s)' in out
    assert (tmp_path / 'a.png').exists()          # one image: the name as given


def test_board_json_and_one_annotation_per_image(capsys, tmp_path):
    code, out, err = _run(capsys, BOARD_PHOTO, DATA / 'chocclusion_original.jpg', '--json',
                          '--board', BOARD, '--camera-info', DATA / 'tutorial_camera_charuco.yml',
                          '--annotate', tmp_path / 'out.png')
    assert code == 0, err
    first, second = _json_lines(out)
    assert len(first['board']['charuco_ids']) == 24 and len(second['board']['charuco_ids']) == 16
    np.testing.assert_allclose(first['board']['pose']['translation'],
                               [-0.0912, -0.1891, 0.3987], atol=1e-3)
    assert all(m.get('board') for m in first['markers'])
    assert [p.name for p in sorted(tmp_path.iterdir())] == ['out-0.png', 'out-1.png']


def test_a_corrupt_image_is_reported_and_the_others_processed(capsys, tmp_path):
    corrupt = tmp_path / 'corrupt.png'
    corrupt.write_bytes(b'\x89PNG\r\n\x1a\n' + b'not really a png' * 10)
    code, out, err = _run(capsys, corrupt, SINGLE, tmp_path / 'missing.jpg', '--json')
    assert code == 1
    assert f'{corrupt}: not an image OpenCV can decode' in err
    assert 'missing.jpg: cannot read' in err
    results = _json_lines(out)
    assert [r['image'] for r in results] == [str(corrupt), str(SINGLE),
                                             str(tmp_path / 'missing.jpg')]
    assert 'error' in results[0] and len(results[1]['markers']) == 6


@pytest.mark.parametrize('argv, words', [
    (['--dictionary', 'DICT_6X6_25'], ['bad --dictionary', 'did you mean DICT_6X6_250']),
    (['--board', 'charuco:squares=5x7,square=40,marker=20,dict=DICT_6X6_250'],
     ['bad --board', 'metres']),
    (['--marker-length', '0.05'], ['need --camera-info']),
    (['--marker-length', '50', '--camera-info', str(DATA / 'tutorial_camera_params.yml')],
     ['bad --marker-length 50', 'metres']),
    (['--camera-info', str(DATA / 'expected_detections.json')],
     ['bad --camera-info', 'expected_detections.json']),
    (['--annotate', '/nonexistent-dir/out.png'], ['bad --annotate', 'no folder']),
])
def test_bad_arguments_exit_2_with_one_line(capsys, argv, words):
    code, out, err = _run(capsys, SINGLE, *argv)
    assert code == 2 and out == ''
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err
    for word in words:
        assert word in err


def test_help_shows_a_board_example(capsys):
    with pytest.raises(SystemExit) as e:
        main(['detect', '--help'])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert '--board charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250' in out
    text = ' '.join(out.split())
    assert 'z into the board' in text and 'y up, z out of the face' in text


def test_camera_info_for_another_resolution_fails_that_image(capsys, tmp_path):
    info = tmp_path / 'cam.yaml'
    info.write_text('image_width: 1280\nimage_height: 960\ncamera_matrix: {rows: 3, cols: 3, '
                    'data: [900, 0, 640, 0, 900, 480, 0, 0, 1]}\n')
    code, out, err = _run(capsys, SINGLE, '--camera-info', info, '--marker-length', '0.05')
    assert code == 1
    assert 'the image is 640x480 px but the camera info is for 1280x960 px' in err


def test_the_400_marker_grid_photo_all_found_and_fitted(capsys):
    """industrial_calibration's aruco.jpg (4032x3024, a 20x20 GridBoard of DICT_6X6_1000, 35 mm
    markers 10 mm apart) crashed in cv2.remap on e6ccb73. Upstream's test: all 400 markers,
    homography error < 3 px."""
    code, out, err = _run(capsys, GRID_PHOTO, '--dictionary', 'DICT_6X6_1000', '--json')
    assert code == 0, err
    [result] = _json_lines(out)
    assert (result['width'], result['height']) == (4032, 3024)
    assert [m['id'] for m in result['markers']] == list(range(400))
    assert {m['refinement'] for m in result['markers']} == {'edges'}
    grid, image = [], []
    for m in result['markers']:
        row, col = divmod(m['id'], 20)
        x, y = 0.045 * col, 0.045 * row
        grid += [[x, y], [x + 0.035, y], [x + 0.035, y + 0.035], [x, y + 0.035]]
        image += m['corners']
    grid, image = np.array(grid), np.array(image)
    H, _ = cv2.findHomography(grid, image, 0)
    error = np.linalg.norm(cv2.perspectiveTransform(grid[None], H)[0] - image, axis=1)
    print(f'homography error mean {error.mean():.2f} px, max {error.max():.2f} px')
    assert error.mean() < 3.0


def test_text_counts_the_markers_that_kept_subpix_corners(capsys, tmp_path):
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    image = np.full((240, 400), 255, np.uint8)
    image[60:180, 60:180] = cv2.aruco.generateImageMarker(d, 3, 120)
    image[100:109, 300:309] = cv2.resize(cv2.aruco.generateImageMarker(d, 7, 600), (9, 9),
                                         interpolation=cv2.INTER_AREA)
    path = tmp_path / 'two.png'
    cv2.imwrite(str(path), image)
    code, out, err = _run(capsys, path, '--dictionary', 'DICT_4X4_50')
    assert code == 0, err
    assert '2 marker(s) of DICT_4X4_50 (refine edges)' in out
    assert '1 of 2 marker(s) kept sub-pixel corners' in out
    [line7] = [line for line in out.splitlines() if line.startswith('  id    7:')]
    [line3] = [line for line in out.splitlines() if line.startswith('  id    3:')]
    assert line7.endswith('[subpix]') and not line3.endswith(']')
