"""Hand-eye calibration (core.landmarks.hand_eye) on synthetic poses whose truth is exact, and the
view plan on the sawyer_close cell."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.landmarks.hand_eye import (board_in_image, check_noise,
                                                     DISTANCE_RANGE, hand_eye_views,
                                                     MAX_NOISE_RATIO, park_martin,
                                                     solve_hand_eye, TILT_RANGE_DEG)
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.loaders import load_cell
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
    assert result.residual_m < 1e-12 and result.residual_rad < 1e-12
    assert result.n_views == n and result.residuals_m.shape == (n,)
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
    assert 0.02e-3 < result.residual_m < 1e-3 and 0.2e-3 < result.residual_rad < 5e-3


# A board pose's noise as PnP has it: depth (optical z) worse than across, rotation about z
# better than about x and y [m, rad]. 1-sigma.
BOARD_SIGMA = np.array([2e-5, 2e-5, 8e-5, 4e-4, 4e-4, 1e-4])


def _noisy_boards(F: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """Board poses with noise drawn from BOARD_SIGMA (position added in the optical frame,
    rotation on the left: the covariances' convention), and those covariances."""
    M = []
    for m in _boards(F):
        d = rng.normal(0.0, BOARD_SIGMA)
        M.append(frames.make_transform(frames.from_vector(np.r_[0, 0, 0, d[3:]])[:3, :3]
                                       @ m[:3, :3], m[:3, 3] + d[:3]))
    return np.array(M), np.repeat(np.diag(BOARD_SIGMA ** 2)[None], len(F), axis=0)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_noise_gate_passes_views_that_fit_within_their_noise(seed):
    rng = np.random.default_rng(seed)
    F = _flange_poses(12, seed=seed)
    M, cov = _noisy_boards(F, rng)
    result = solve_hand_eye(F, M, covariances=cov)
    check = check_noise(result, cov)
    # E|dp|^2 = trace * (1 - 12/72): sqrt((2e-5^2 * 2 + 8e-5^2) * 5/6) = 0.0775 mm, and
    # sqrt((4e-4^2 * 2 + 1e-4^2) * 5/6) = 0.5244 mrad
    assert check.expected_m == pytest.approx(0.07746e-3, abs=1e-8)
    assert check.expected_rad == pytest.approx(0.52440e-3, abs=1e-8)
    assert check and check.problem == ''
    assert 0.6 < check.ratio < 1.6, check.ratio


def test_the_noise_gate_refuses_a_view_whose_image_shows_another_pose():
    """Issue 22.9: one image of the arm 2.6 mm / 10.8 mrad before it came to rest, paired
    with the joints at rest: the fit absorbs some of it, the residual gives it away."""
    rng = np.random.default_rng(0)
    F = _flange_poses(12, seed=0)
    M, cov = _noisy_boards(F, rng)
    early = F[5] @ frames.from_vector([0.002, -0.001, 0.0014, 0.006, 0.004, -0.008])
    M[5] = _boards(early[None])[0]
    result = solve_hand_eye(F, M, covariances=cov)
    check = check_noise(result, cov)
    assert not check and check.ratio > MAX_NOISE_RATIO
    assert check.problem.startswith(f'residual RMS {result.residual_m * 1e3:.3f} mm / ')
    assert 'some views do not fit the others' in check.problem
    # the same views without the early image pass
    keep = [i for i in range(12) if i != 5]
    assert check_noise(solve_hand_eye(F[keep], M[keep], covariances=cov[keep]), cov[keep])


def test_the_noise_gate_needs_one_finite_covariance_per_view():
    F = _flange_poses(5)
    result = solve_hand_eye(F, _boards(F))
    with pytest.raises(ValueError, match='5 finite 6x6'):
        check_noise(result, np.zeros((4, 6, 6)))
    with pytest.raises(ValueError, match='positive definite'):
        check_noise(result, np.zeros((5, 6, 6)))


def test_fewer_than_three_views_are_refused():
    F = _flange_poses(2)
    result = solve_hand_eye(F, _boards(F))       # a data problem: a Failure, not raised
    assert result == Failure(ErrorCode.TOO_FEW_POINTS, result.message)
    assert 'at least 3 views, got 2' in result.message


def test_mismatched_and_malformed_inputs_are_refused():
    """One shape for every problem (issue 39 item 1): a Failure with its cause, never a
    raise beside it."""
    F = _flange_poses(4)
    for result, says in ((solve_hand_eye(F, _boards(F)[:3]), '4 flange poses but 3 board poses'),
                         (solve_hand_eye(F[:, :3], _boards(F)), '4x4'),
                         (solve_hand_eye(F, _boards(F), method='daniilidis'), 'unknown method'),
                         (solve_hand_eye(F, _boards(F), covariances=np.zeros((3, 6, 6))),
                          '4 finite 6x6')):
        assert isinstance(result, Failure) and result.code == ErrorCode.INVALID_INPUT
        assert says in result.message


def test_rotations_about_one_axis_are_degenerate():
    base = _flange_poses(1)[0]
    F = np.array([base @ frames.make_transform(frames.rot_z(a), [0.01 * a, 0.02 * a, 0.0])
                  for a in np.linspace(-0.6, 0.6, 8)])
    result = solve_hand_eye(F, _boards(F))     # a data problem: a Failure, not raised
    assert not result and result.code == ErrorCode.DEGENERATE_POINTS
    assert 'every rotation between them is about one axis' in result.message


def test_pure_translations_are_degenerate():
    base = _flange_poses(1)[0]
    F = np.array([base @ frames.make_transform(np.eye(3), [0.02 * i, -0.01 * i, 0.0])
                  for i in range(6)])
    result = solve_hand_eye(F, _boards(F))
    assert not result and result.code == ErrorCode.DEGENERATE_POINTS
    assert 'hardly rotates' in result.message


def test_views_look_at_the_board_from_different_angles():
    cell = load_cell(cell_file('sawyer_close'))
    model = kinematics.model_for(cell)
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
    model = kinematics.model_for(cell)
    with pytest.raises(ValueError, match='T_base_user'):
        hand_eye_views(cell, model)
    with pytest.raises(ValueError, match='at least 3'):
        hand_eye_views(cell, model, 2, T_base_user=T_BASE_USER)

