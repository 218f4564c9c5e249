"""`cobot-calib intrinsics` on images of the mock camera's true lens, from a folder and from a
bag, in-process: the printed figures, the camera_info YAML and the cell's record."""
import json

import cv2
import numpy as np
import pytest
from rclpy.serialization import serialize_message

from cobot_calib_ros.bags.writer import BagWriter
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.landmarks.intrinsics_views import intrinsics_views
from cobot_calib_ros.loaders import load_camera_info_yaml
from cobot_calib_ros.ros.images import gray_to_image
from cobot_calib_ros.sim.camera import SimCamera
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros import store
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import active_intrinsics
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation, with_true_lens

T0 = 1_795_000_000_000_000_000


@pytest.fixture(scope='module')
def shots(tmp_path_factory):
    """12 planned views of the board through the true lens: a folder of PNGs and a bag."""
    sim = with_true_lens(load_simulation(cell_file('ur10e_close')),
                         [[628.0, 0.0, 380.1], [0.0, 627.2, 236.9], [0.0, 0.0, 1.0]],
                         [-0.15, 0.12, 0.0003, -0.0004, -0.05])
    arm = SimRobot(sim)
    scene = SimCamera(sim, arm)
    root = tmp_path_factory.mktemp('shots')
    folder = root / 'images'
    folder.mkdir()
    plan = intrinsics_views(sim.cell, arm.model, 12, 0, T_base_user=sim.world.T_base_user)
    with BagWriter(root / 'bag') as bag:
        bag.add_topic('/wrist_camera/image_raw', 'sensor_msgs/msg/Image')
        for i, q in enumerate(plan):
            arm.set_joints(q)
            image = scene.render(arm.q)
            cv2.imwrite(str(folder / f'view{i:02d}.png'), image)
            stamp = T0 + i * 100_000_000
            msg = gray_to_image(image, 'wrist_camera_optical', _stamp(stamp))
            bag.write('/wrist_camera/image_raw', serialize_message(msg), stamp)
        (folder / 'notes.txt').write_text('not an image')
        (folder / 'broken.png').write_bytes(b'not a png')
    return folder, root / 'bag'


def _stamp(ns: int):
    from builtin_interfaces.msg import Time
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _run(capsys, *argv):
    code = main(['intrinsics', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_folder_calibrates_writes_the_yaml_and_stores_the_active_record(shots, tmp_path,
                                                                       capsys):
    folder, _ = shots
    code, out, err = _run(capsys, folder, '--cell', 'ur10e_close', '--data-dir', tmp_path,
                          '--json')
    assert code == 0, err
    result = json.loads(out)
    assert result['fx'] == pytest.approx(628.0, rel=2e-3)       # 12 views: see
    assert result['fy'] == pytest.approx(627.2, rel=2e-3)       # test_intrinsics_mock
    assert abs(result['cx'] - 380.1) < 1.5 and abs(result['cy'] - 236.9) < 1.5
    assert result['views'] == 12 and result['skipped'] == {'broken.png': 'not a readable image'}
    assert result['camera'] == 'wrist_camera_optical' and result['active'] is True
    assert result['rms_px'] < 0.06 and result['heldout_rms_px'] < 1.5 * result['rms_px']
    written = load_camera_info_yaml(result['yaml_path'])
    assert written.K[0, 0] == result['fx'] and written.name == 'wrist_camera_optical'
    repo = store.open(tmp_path, None, ResultsCell('ur10e_close'))
    assert active_intrinsics(repo, 'wrist_camera_optical').K[0, 0] == result['fx']
    # `cobot-calib detect --cell` poses with the active intrinsics, as with their YAML
    image = folder / 'view03.png'
    board = 'charuco:squares=7x5,square=0.03,marker=0.022,dict=DICT_4X4_50'
    poses = []
    for source in (['--cell', 'ur10e_close', '--data-dir', tmp_path],
                   ['--camera-info', result['yaml_path']]):
        code = main(['detect', str(image), '--board', board, '--json', *map(str, source)])
        out, err = capsys.readouterr()
        assert code == 0, err
        poses.append(json.loads(out)['board'])
    assert poses[0] == poses[1] and 'T_optical_board' in json.dumps(poses[0])


def test_bag_gives_the_same_calibration_as_the_folder(shots, tmp_path, capsys):
    folder, bag = shots
    board = 'charuco:squares=7x5,square=0.03,marker=0.022,dict=DICT_4X4_50'
    code, out, err = _run(capsys, bag, '--board', board, '--output', tmp_path / 'cam.yaml')
    assert code == 0, err
    assert '  fx 62' in out and 'wrote ' + str(tmp_path / 'cam.yaml') in out
    code, _, err = _run(capsys, folder, '--board', board, '--output', tmp_path / 'cam2.yaml')
    assert code == 0, err
    # the same pixels; OpenCV's threads leave ~1e-12 (seen once ~1e-9) between two runs
    np.testing.assert_allclose(load_camera_info_yaml(tmp_path / 'cam.yaml').K,
                               load_camera_info_yaml(tmp_path / 'cam2.yaml').K, rtol=1e-6)


def test_too_few_views_are_refused_with_the_reason(shots, tmp_path, capsys):
    folder, _ = shots
    few = tmp_path / 'few'
    few.mkdir()
    for name in ('view00.png', 'view01.png', 'view02.png'):
        (few / name).write_bytes((folder / name).read_bytes())
    code, out, err = _run(capsys, few, '--cell', 'ur10e_close', '--data-dir', tmp_path)
    assert code == 1 and 'TOO_FEW_POINTS' in err and '3 views' in err


def test_no_board_is_a_usage_error(shots, capsys):
    folder, _ = shots
    code, _, err = _run(capsys, folder)
    assert code == 2 and '--board' in err


def test_a_missing_folder_is_named_as_such(tmp_path, capsys):
    code, _, err = _run(capsys, tmp_path / 'nowhere', '--cell', 'ur10e_close')
    assert code == 2 and 'nowhere: no such folder or bag' in err, err


def test_images_of_another_board_say_what_was_read_and_found(shots, tmp_path, capsys):
    folder, _ = shots       # 12 views of a DICT_4X4_50 board, a text file, a broken PNG
    code, _, err = _run(capsys, folder, '--board',
                        'charuco:squares=7x5,square=0.03,marker=0.022,dict=DICT_5X5_50')
    assert code == 1 and '0 views of the board' in err, err
    assert '13 images read, 0 with the board' in err, err      # broken.png is read, unreadable
    assert 'view00.png: 0 board corners found, 6 needed (0 of its markers)' in err, err
    assert 'check --board' in err, err
