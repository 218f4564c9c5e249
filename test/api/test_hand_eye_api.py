"""api.hand_eye.calibrate_and_store in-process over the simulation (sim DirectRobot and
DirectCamera: images rendered at the arm's joints, the board detected and posed; a folder
repository): the procedure hand_eye_calibrator runs, scored against the simulation's TRUE
hand-eye, stored with what it was measured through and made active; a cancel stores nothing;
views that do not fit their noise are stored as rejected, not active."""
from __future__ import annotations

import numpy as np

from cobot_calib_ros import store
from cobot_calib_ros.api.hand_eye import calibrate_and_store, HandEyeViewsRequest
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics import model_for
from cobot_calib_ros.core.robot_port import LandmarkImage, Sighting
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import rig_of

SIM = load_simulation(cell_file('sawyer_close'))
MODEL = model_for(SIM.cell)
# the user frame as a user-frame calibration knows it: a few mm and mrad off the truth
T_BASE_USER = frames.from_xyz_rpy([0.352, -0.048, 0.0], [0.0, 0.0, 0.03])
# Through an exact kinematic calibration: in-process 0.009-0.010 mm / 0.08-0.10 mrad from the
# truth (bench/bench_hand_eye.py); the nominal hand-eye is 1.64 mm / 8.13 mrad off.
MAX_ERROR_M = 0.05e-3
MAX_ERROR_RAD = 0.3e-3
BOARD_SIGMA = np.array([2e-5, 2e-5, 8e-5, 4e-4, 4e-4, 1e-4])   # [m, rad] a PnP board pose


def _repo(tmp_path):
    repo = store.open(tmp_path, cell=ResultsCell.of(SIM.cell))
    assert repo.kinematics.save_and_activate({
        'id': 'k-true', 'robot': MODEL.name, 'stamp_ns': 1, 'method': 'test', 'inputs': {},
        'result': {'parameter_names': list(MODEL.parameter_names),
                   'params': SIM.true_parameters(MODEL).tolist()}})
    return repo


class PosedBoard:
    """A CameraPort that sees the board where it truly is from the arm's true camera, with
    BOARD_SIGMA noise and that covariance (no rendering); at the views in ``stale`` the image
    shows the arm where it was at the view before (issue 22.9)."""

    def __init__(self, arm: SimRobot, stale=()) -> None:
        self.scene, self.arm, self.stale = SimCamera(SIM, arm), arm, set(stale)
        self.rng, self.clock, self.views, self.last_q = np.random.default_rng(2), 0, 0, arm.q

    def now_ns(self) -> int:
        self.clock += 1
        return self.clock

    def landmarks_after(self, t_ns, wanted, max_images, timeout) -> LandmarkImage:
        q = self.last_q if self.views in self.stale else self.arm.q
        self.views, self.last_q = self.views + 1, self.arm.q
        key = next(k for k in self.scene.targets if k[0] == 'board')
        d = self.rng.normal(0.0, BOARD_SIGMA)
        T = frames.from_vector(np.r_[0, 0, 0, d[3:]]) @ self.scene.T_optical_targets(q)[key]
        T[:3, 3] += d[:3]
        return LandmarkImage(self.now_ns() + t_ns, (Sighting(
            'board', key[1], T, np.diag(BOARD_SIGMA ** 2)),))


def _calibrate(repo, camera_of, request, **kwargs):
    arm = SimRobot(SIM, seed_offset=4)
    robot = DirectRobot(arm, SIM.probe)
    return calibrate_and_store(request, robot, camera_of(arm), rig_of(repo, SIM.cell, 'active',
                                                                      MODEL),
                               repo, T_BASE_USER, 1, flange_frame='flange', **kwargs), robot


def test_the_hand_eye_found_is_the_true_one_stored_with_its_provenance_and_active(tmp_path):
    repo = _repo(tmp_path)
    seen, warned = [], []
    outcome, _ = _calibrate(
        repo, lambda arm: DirectCamera(SimCamera(SIM, arm), arm, boards=True),
        HandEyeViewsRequest(12, hold=0.1), warn=warned.append,
        progress=lambda i, used, views: seen.append((i, used)))
    assert outcome and outcome.code == ErrorCode.SUCCESS, outcome.message
    X = outcome.run.result.T_flange_optical
    err_m, err_rad = frames.transform_error(X, SIM.camera.T_flange_optical)
    print(f'\nhand-eye {err_m * 1e3:.4f} mm / {err_rad * 1e3:.4f} mrad from the truth; '
          f'{outcome.message}')
    assert err_m < MAX_ERROR_M and err_rad < MAX_ERROR_RAD
    assert seen == [(i, True) for i in range(12)]
    record = repo.hand_eye.active()
    assert record['id'] == outcome.record.id and not record.get('gate_problem')
    assert record['measured_through'] == {'kinematics': 'k-true', 'intrinsics': 'nominal'}
    np.testing.assert_allclose(record['result']['T_flange_optical'], X, atol=1e-12)
    assert record['result']['residual_mm'] == outcome.run.result.residual_m * 1e3
    assert 0.0 < outcome.run.result.residual_m < 1e-3
    assert warned and 'measured through the nominal intrinsics' in warned[0]
    assert outcome.message.endswith(warned[0])


def test_a_cancel_before_a_view_stores_nothing(tmp_path):
    repo = _repo(tmp_path)
    seen = []
    outcome, robot = _calibrate(repo, PosedBoard, HandEyeViewsRequest(12, hold=0.05),
                                cancelled=lambda: len(seen) >= 2,
                                progress=lambda *a: seen.append(a))
    assert outcome.code == ErrorCode.CANCELED
    assert outcome.message == 'cancelled at view 3 of 12; nothing stored or published'
    assert robot.moves == 2 and repo.hand_eye.active() is None and not repo.hand_eye.ids()


def test_images_of_another_pose_are_stored_as_rejected_and_not_made_active(tmp_path):
    repo = _repo(tmp_path)
    good, _ = _calibrate(repo, PosedBoard, HandEyeViewsRequest(12, hold=0.05))
    assert good and good.code == ErrorCode.SUCCESS, good.message
    bad, _ = _calibrate(repo, lambda arm: PosedBoard(arm, stale={3, 7, 10}),
                        HandEyeViewsRequest(12, hold=0.05))
    assert bad and bad.code == ErrorCode.SOLVER_FAILED
    assert 'rejected, stored as rejected and not made active' in bad.message
    assert 'some views do not fit the others' in bad.message
    assert repo.hand_eye.active()['id'] == good.record.id
    assert repo.hand_eye.rejected()[bad.record.id] == bad.run.gate_problem


def test_too_few_views_are_refused_before_anything_moves(tmp_path):
    repo = _repo(tmp_path)
    few, robot = _calibrate(repo, PosedBoard, HandEyeViewsRequest(2))
    assert few.code == ErrorCode.INVALID_INPUT and few.message.startswith('views must be 3..200')
    assert robot.moves == 0 and not repo.hand_eye.ids()
