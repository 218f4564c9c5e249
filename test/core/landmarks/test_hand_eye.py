"""Hand-eye calibration (core.landmarks.hand_eye) on synthetic poses whose truth is exact, and the
view plan on the sawyer_close cell."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.cell import load_cell
from cobot_calib_ros.core.landmarks.hand_eye import (board_in_image, DISTANCE_RANGE,
                                                     hand_eye_views, park_martin,
                                                     solve_hand_eye, TILT_RANGE_DEG)
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.paths import cell_file

X_TRUE = frames.from_xyz_rpy([0.0758, -0.0006, 0.0213], [0.004, -0.003, 1.5772])
B_TRUE = frames.from_xyz_rpy([0.48, 0.36, 0.002], [math.pi, 0.001, 0.03])
T_BASE_USER = frames.from_xyz_rpy([0.35, -0.05, 0.0], [0.0, 0.0, 0.03])


def _flange_poses(n: int, seed: int = 0) -> np.ndarray:
    """Flange poses above the board, rotated about varied axes (up to ~0.5 rad)."""
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(n):
        R = frames.rot_x(math.pi)
        d = frames.from_vector(np.r_[rng.uniform(-0.1, 0.1, 3), rng.uniform(-0.5, 0.5, 3)])
        poses.append(frames.make_transform(d[:3, :3] @ R, B_TRUE[:3, 3] + [0.0, 0.0, 0.35]
                                           + d[:3, 3]))
    return np.array(poses)


def _boards(F: np.ndarray, X: np.ndarray = X_TRUE, B: np.ndarray = B_TRUE) -> np.ndarray:
    return np.array([np.linalg.inv(X) @ np.linalg.inv(f) @ B for f in F])


@pytest.mark.parametrize('n', [3, 5, 12])
def test_noise_free_poses_are_recovered_exactly(n):
    F = _flange_poses(n, seed=n)
    result = solve_hand_eye(F, _boards(F))
    dx = frames.transform_error(result.T_flange_optical, X_TRUE)
    db = frames.transform_error(result.T_base_board, B_TRUE)
    assert max(dx) < 1e-9 and max(db) < 1e-9, (dx, db)
    assert result.residual_mm < 1e-9 and result.residual_mrad < 1e-9
    assert result.n_views == n and result.residuals_mm.shape == (n,)
    assert max(frames.transform_error(park_martin(F, _boards(F)), X_TRUE)) < 1e-9


def test_noise_is_refined_below_the_closed_form_and_the_covariance_fits():
    rng = np.random.default_rng(3)
    F = _flange_poses(15, seed=1)
    sigma_m, sigma_rad = 1e-4, 1e-3
    M = np.array([m @ frames.from_vector(np.r_[rng.normal(0, sigma_m, 3),
                                               rng.normal(0, sigma_rad, 3)])
                  for m in _boards(F)])
    cov = np.repeat(np.diag([sigma_m ** 2] * 3 + [sigma_rad ** 2] * 3)[None], len(F), axis=0)
    result = solve_hand_eye(F, M, covariances=cov)
    err_m, err_rad = frames.transform_error(result.T_flange_optical, X_TRUE)
    init_m, init_rad = frames.transform_error(result.initial, X_TRUE)
    assert err_m < 3e-4 and err_rad < 2e-3
    assert err_m <= init_m * 1.5
    sigma = np.sqrt(np.diag(result.covariance))
    assert result.covariance.shape == (6, 6) and np.all(np.isfinite(sigma))
    assert np.all(sigma[:3] < 5e-4) and np.all(sigma[3:] < 5e-3)
    assert 0.02 < result.residual_mm < 1.0 and 0.2 < result.residual_mrad < 5.0


def test_fewer_than_three_views_are_refused():
    F = _flange_poses(2)
    with pytest.raises(ValueError, match='at least 3 views'):
        solve_hand_eye(F, _boards(F))


def test_mismatched_and_malformed_inputs_are_refused():
    F = _flange_poses(4)
    with pytest.raises(ValueError, match='4 flange poses but 3 board poses'):
        solve_hand_eye(F, _boards(F)[:3])
    with pytest.raises(ValueError, match='4x4'):
        solve_hand_eye(F[:, :3], _boards(F))
    with pytest.raises(ValueError, match='unknown method'):
        solve_hand_eye(F, _boards(F), method='daniilidis')


def test_rotations_about_one_axis_are_degenerate():
    base = _flange_poses(1)[0]
    F = np.array([base @ frames.make_transform(frames.rot_z(a), [0.01 * a, 0.02 * a, 0.0])
                  for a in np.linspace(-0.6, 0.6, 8)])
    with pytest.raises(ValueError, match='one axis'):
        solve_hand_eye(F, _boards(F))


def test_pure_translations_are_degenerate():
    base = _flange_poses(1)[0]
    F = np.array([base @ frames.make_transform(np.eye(3), [0.02 * i, -0.01 * i, 0.0])
                  for i in range(6)])
    with pytest.raises(ValueError, match='hardly rotates'):
        solve_hand_eye(F, _boards(F))


def test_views_look_at_the_board_from_different_angles():
    cell = load_cell(cell_file('sawyer_close'))
    model = kinematics.model_by_name(cell.robot)
    views = hand_eye_views(cell, model, 12, seed=0, T_base_user=T_BASE_USER)
    assert len(views) == 12
    chain = model.chain(tool=cell.camera.T_flange_optical)
    B = T_BASE_USER @ cell.landmarks.T_user_board()
    size = BoardSpec.parse(cell.landmarks.board).size
    centre = frames.apply(B, [size[0] / 2, size[1] / 2, 0.0])
    normal = -B[:3, 2]                       # board z points into the table
    for q in views:
        assert np.all(q >= chain.lower) and np.all(q <= chain.upper)
        T = kinematics.fk(chain, q)
        d = np.linalg.norm(T[:3, 3] - centre)
        assert DISTANCE_RANGE[0] - 1e-6 <= d <= DISTANCE_RANGE[1] + 1e-6
        view = T[:3, 2]
        np.testing.assert_allclose(view, (centre - T[:3, 3]) / d, atol=1e-6)
        tilt = math.degrees(math.acos(np.clip(-view @ normal, -1, 1)))
        assert TILT_RANGE_DEG[0] - 1e-4 <= tilt <= TILT_RANGE_DEG[1] + 1e-4
        assert board_in_image(frames.invert(T) @ B, size, cell.camera.camera_model())
    # the views' rotations span more than one axis: the solver's degeneracy check passes
    F = np.array([kinematics.fk(model.chain(), q) for q in views])
    solve_hand_eye(F, _boards(F, cell.camera.T_flange_optical, B))
    again = hand_eye_views(cell, model, 12, seed=0, T_base_user=T_BASE_USER)
    assert all(np.array_equal(a, b) for a, b in zip(views, again))    # seeded: repeatable


def test_views_need_a_user_frame_and_a_board():
    cell = load_cell(cell_file('sawyer_close'))
    model = kinematics.model_by_name(cell.robot)
    with pytest.raises(ValueError, match='T_base_user'):
        hand_eye_views(cell, model)
    with pytest.raises(ValueError, match='at least 3'):
        hand_eye_views(cell, model, 2, T_base_user=T_BASE_USER)
