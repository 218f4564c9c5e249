"""api.intrinsics in-process over the simulation (sim DirectRobot and DirectImages: images
rendered by the mock's TRUE lens, 1.3 % longer than the nominal one the cell gives; a folder
repository): calibrate_on_cell as camera_calibrator runs it, planned views recovering the true
lens, the camera_info YAML written by its one writer and the record active; live views of an
arm at rest refused as too few; a bag source, a cancel, and store_run without a repository."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.api.intrinsics import calibrate_on_cell, IntrinsicsRequest, store_run
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics import model_for
from cobot_calib_ros.core.landmarks.intrinsics_capture import IntrinsicsRun
from cobot_calib_ros.loaders import load_camera_info_yaml
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.camera import DirectImages, SimCamera
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation, with_true_lens
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import active_intrinsics

K_TRUE = np.array([[628.0, 0.0, 380.1], [0.0, 627.2, 236.9], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.15, 0.12, 0.0003, -0.0004, -0.05])
SIM = with_true_lens(load_simulation(cell_file('ur10e_close')), K_TRUE, D_TRUE)
CAMERA = SIM.cell.camera.frame_id


def _calibrate(tmp_path, request, deadline=lambda: False, at=None, **kwargs):
    arm = SimRobot(SIM)
    if at is not None:
        arm.set_joints(at)
    robot = DirectRobot(arm, SIM.probe)
    repo = store.open(tmp_path, cell=ResultsCell.of(SIM.cell))
    outcome = calibrate_on_cell(
        request, SIM.cell, model_for(SIM.cell), robot, DirectImages(SimCamera(SIM, arm), arm),
        T_base_user=lambda: SIM.world.T_base_user, repo=repo, data_dir=tmp_path, wall_ns=1,
        live_deadline=deadline, **kwargs)
    return outcome, repo, robot


def test_planned_views_find_the_true_lens_write_its_yaml_and_activate_it(tmp_path):
    seen = []
    outcome, repo, robot = _calibrate(tmp_path, IntrinsicsRequest(count=12, planned=True),
                                      progress=lambda *a: seen.append(a))
    assert outcome and outcome.code == ErrorCode.SUCCESS, outcome.message
    K = outcome.run.fit.camera.K
    # 12 views (test/sim/test_intrinsics_mock.py): 0.05-0.08 % and up to 1 px; the nominal
    # lens is 1.3 % off, so these bounds tell the truth from it
    assert K[0, 0] == pytest.approx(628.0, rel=2e-3) and K[1, 1] == pytest.approx(627.2, rel=2e-3)
    assert abs(K[0, 2] - 380.1) < 1.5 and abs(K[1, 2] - 236.9) < 1.5
    assert abs(K[0, 0] - SIM.cell.camera.K[0, 0]) > 5.0
    assert [(views, total) for views, total, _ in seen] == [(i, 12) for i in range(1, 13)]
    assert seen[0][2].fraction < seen[-1][2].fraction and robot.moves == 12
    path = outcome.record.result.yaml_path
    assert path == str((tmp_path / 'intrinsics' / f'{outcome.record.id}.yaml').resolve())
    np.testing.assert_array_equal(load_camera_info_yaml(path).K, K)
    assert outcome.active and np.array_equal(active_intrinsics(repo, CAMERA).K, K)
    assert outcome.message.endswith('; active')


def test_live_views_of_an_arm_at_rest_are_too_few_and_nothing_is_stored(tmp_path):
    """Nobody moves the board: every image is the same view, kept once."""
    from cobot_calib_ros.core.landmarks.intrinsics_views import intrinsics_views
    view = intrinsics_views(SIM.cell, model_for(SIM.cell), 1,
                            T_base_user=SIM.world.T_base_user)[0]
    images = []
    outcome, repo, _ = _calibrate(tmp_path, IntrinsicsRequest(count=6), at=view,
                                  deadline=lambda: images.append(1) or len(images) > 5)
    assert outcome.code == ErrorCode.TOO_FEW_POINTS
    assert outcome.message.startswith('1 views of the board'), outcome.message
    assert active_intrinsics(repo, CAMERA) is None and not (tmp_path / 'intrinsics').exists()


def test_a_bag_source_and_a_bad_goal_are_refused_saying_what_to_do(tmp_path):
    bag, _, robot = _calibrate(tmp_path, IntrinsicsRequest(source='/no/such/run.mcap'))
    assert bag.code == ErrorCode.INVALID_INPUT and 'cobot-calib intrinsics BAG' in bag.message
    bad, _, _ = _calibrate(tmp_path, IntrinsicsRequest(model='kannala', count=3))
    assert bad.code == ErrorCode.INVALID_INPUT and 'model must be one of' in bad.message
    assert robot.moves == 0


def test_a_cancel_before_a_view_stores_nothing(tmp_path):
    seen = []
    outcome, repo, robot = _calibrate(tmp_path, IntrinsicsRequest(count=8, planned=True),
                                      cancelled=lambda: len(seen) >= 2,
                                      progress=lambda *a: seen.append(a))
    assert outcome.code == ErrorCode.CANCELED
    assert outcome.message == 'cancelled at view 3 of 8; nothing stored'
    assert robot.moves == 2 and active_intrinsics(repo, CAMERA) is None


def test_without_a_repository_the_yaml_is_written_and_nothing_stored(tmp_path):
    from cobot_calib_ros.core.landmarks.camera import CameraModel
    from cobot_calib_ros.core.landmarks.intrinsics import Coverage, IntrinsicsFit
    lens = CameraModel(752, 480, K_TRUE, D_TRUE, 'plumb_bob', 'cam')
    fit = IntrinsicsFit(lens, 0.03, {}, (), 0.031,
                        Coverage(np.ones((4, 4), bool), 1.0, (), (), 40.0), 20, {})
    outcome = store_run(IntrinsicsRun(fit, [], []), source='test', board='',
                        yaml_path=tmp_path / 'sub' / 'cam.yaml')
    assert outcome and outcome.code == ErrorCode.SUCCESS and not outcome.active
    np.testing.assert_array_equal(load_camera_info_yaml(tmp_path / 'sub' / 'cam.yaml').K,
                                  K_TRUE)
    blocked = tmp_path / 'file'
    blocked.write_text('')
    failed = store_run(IntrinsicsRun(fit, [], []), source='test', board='',
                       yaml_path=blocked / 'cam.yaml')
    assert failed.code == ErrorCode.STORAGE_FAILED
    assert failed.message.startswith('could not store the intrinsics')
