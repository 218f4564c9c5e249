"""core.user_frame.landmarks: exact recovery of a synthetic user frame from marker poses."""
import numpy as np

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.user_frame.landmarks import (
    average_centre, frame_from_landmarks, frame_from_single, LANDMARK_MULTI, LANDMARK_SINGLE)

T_BASE_USER = frames.from_xyz_rpy([0.35, -0.05, 0.01], [0.002, -0.0015, 0.03])
PLACEMENTS = {0: (0.25, 0.08, 0.0), 1: (0.42, 0.175, 0.35), 2: (0.25, 0.27, -0.6),
              3: (0.08, 0.175, 1.2)}


def _T_user_marker(i):
    x, y, yaw = PLACEMENTS[i]
    return frames.make_transform(frames.rot_z(yaw), [x, y, 0.0])


def _err(T, T_true):
    pos, ang = frames.transform_error(T, T_true)
    return pos, ang


def test_single_exact():
    T_um = _T_user_marker(1)
    result = frame_from_single(T_BASE_USER @ T_um, T_um, marker_id=1,
                               covariance=np.diag([1e-8] * 3 + [1e-6] * 3))
    assert result and result.fit.method == LANDMARK_SINGLE
    np.testing.assert_allclose(result.fit.T_base_user, T_BASE_USER, atol=1e-12)
    assert result.names == ['L1', 'L1+x', 'L1+y'] and result.fit.rms < 1e-12
    # the covariance is carried to the user origin: larger in position than at the marker
    assert result.fit.covariance[0, 0] > 1e-8


def test_multi_exact_from_several_views():
    T_um = {i: _T_user_marker(i) for i in PLACEMENTS}
    obs = [(i, T_BASE_USER @ T_um[i], np.diag([1e-8] * 3 + [1e-6] * 3))
           for i in PLACEMENTS for _ in range(3)]
    result = frame_from_landmarks(obs, T_um)
    assert result, result.fit.message
    assert result.fit.method == LANDMARK_MULTI
    np.testing.assert_allclose(result.fit.T_base_user, T_BASE_USER, atol=1e-10)
    assert result.names == ['L0', 'L1', 'L2', 'L3'] and result.views == {i: 3 for i in PLACEMENTS}


def test_multi_two_markers_uses_orientations():
    T_um = {i: _T_user_marker(i) for i in (0, 2)}
    obs = [(i, T_BASE_USER @ T_um[i], np.eye(6) * 1e-8) for i in (0, 2)]
    result = frame_from_landmarks(obs, T_um)
    assert result, result.fit.message
    np.testing.assert_allclose(result.fit.T_base_user, T_BASE_USER, atol=1e-10)
    assert len(result.names) == 6 and 'orientations' in result.fit.message


def test_multi_noisy_averages_views_by_covariance():
    rng = np.random.default_rng(3)
    T_um = {i: _T_user_marker(i) for i in PLACEMENTS}
    obs = []
    for i in PLACEMENTS:
        for sigma in (1e-4, 1e-4, 1e-2):      # one bad view per marker, with its covariance
            T = T_BASE_USER @ T_um[i]
            T[:3, 3] += rng.normal(0.0, sigma, 3)
            obs.append((i, T, np.diag([sigma ** 2] * 3 + [1e-6] * 3)))
    result = frame_from_landmarks(obs, T_um, max_rms_error=None)
    assert result
    pos, ang = _err(result.fit.T_base_user, T_BASE_USER)
    assert pos < 5e-4 and ang < 3e-3


def test_average_centre_weights():
    mean, cov = average_centre([[0, 0, 0], [1, 1, 1]], [np.eye(3), np.eye(3) * 3])
    np.testing.assert_allclose(mean, [0.25] * 3)
    np.testing.assert_allclose(cov, np.eye(3) * 0.75)


def test_nothing_seen_and_unknown_ids():
    result = frame_from_landmarks([(9, np.eye(4), np.eye(6))], {0: np.eye(4)})
    assert not result and result.fit.code == ErrorCode.TOO_FEW_POINTS
