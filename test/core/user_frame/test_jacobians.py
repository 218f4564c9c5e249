"""The analytic derivatives of the estimators (jacobians.py) equal central differences.

They replaced refitting per coordinate in the covariance of five_point_lsq and three_point and
in the scale standard errors (issue 31 item 8); these cases are the proof that the figures did
not change: a non-coplanar box, a thin slab, a coplanar layout (the affine normal column
completed), and a fit with a 3 % wrong drawing (M far from a rotation).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core.frames import apply, make_transform
from cobot_calib_ros.core.user_frame.covariance import _pose_delta
from cobot_calib_ros.core.user_frame.estimators import (
    _affine_fit, _affine_pose, _three_point_pose)
from cobot_calib_ros.core.user_frame.jacobians import (
    affine_jacobian, affine_pose_jacobian, nearest_rigid_jacobian, scale_jacobian,
    three_point_jacobian)

STEP = 1e-6               # [m]


def case(name: str) -> tuple[np.ndarray, np.ndarray]:
    """(p_user, p_base) [m]: 6 points, a random pose, 0.1 mm noise (seeded)."""
    rng = np.random.default_rng(31)
    p_user = {'box': rng.uniform(0.0, 0.08, (6, 3)),
              'slab': rng.uniform(0.0, 1.0, (6, 3)) * [0.08, 0.08, 0.02],
              'plane': np.column_stack([rng.uniform(0.0, 0.1, (6, 2)), np.zeros(6)]),
              'stretched': rng.uniform(0.0, 0.08, (6, 3))}[name]
    T = make_transform(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.5, 0.5, 3))
    p_base = apply(T, p_user) + rng.normal(0.0, 1e-4, p_user.shape)
    return (p_user * [1.03, 1.0, 1.0] if name == 'stretched' else p_user), p_base


def central_differences(f, pb: np.ndarray) -> np.ndarray:
    """(..., 3N) derivative of f(p_base) by central differences."""
    flat = pb.ravel()
    columns = []
    for k in range(flat.size):
        step = np.zeros_like(flat)
        step[k] = STEP
        columns.append((f((flat + step).reshape(-1, 3)) - f((flat - step).reshape(-1, 3)))
                       / (2.0 * STEP))
    return np.stack(columns, axis=-1)


def pose_differences(estimate, pu: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """(6, 3N) d(rho, phi) / d p_base of ``estimate`` by central differences."""
    T0 = estimate(pu, pb)
    return central_differences(lambda p: _pose_delta(estimate(pu, p), T0), pb)


@pytest.mark.parametrize('name', ['box', 'slab', 'plane', 'stretched'])
def test_analytic_derivatives_equal_central_differences(name: str) -> None:
    pu, pb = case(name)
    M, completed = _affine_fit(pu, pb)
    assert completed == (name == 'plane')
    dM = affine_jacobian(pu, pb)
    expected = central_differences(lambda p: _affine_fit(pu, p)[0][:3], pb)
    np.testing.assert_allclose(dM, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())
    scales = central_differences(lambda p: np.linalg.norm(_affine_fit(pu, p)[0][:3, :3], axis=0),
                                 pb)
    np.testing.assert_allclose(scale_jacobian(M, dM), scales, rtol=1e-6,
                               atol=1e-6 * np.abs(scales).max())
    pose = pose_differences(_affine_pose, pu, pb)
    np.testing.assert_allclose(nearest_rigid_jacobian(M, dM), pose, rtol=1e-6,
                               atol=1e-6 * np.abs(pose).max())
    np.testing.assert_array_equal(affine_pose_jacobian(pu, pb), nearest_rigid_jacobian(M, dM))


@pytest.mark.parametrize('name', ['box', 'slab', 'plane'])
def test_the_three_point_jacobian_equals_central_differences(name: str) -> None:
    pu, pb = case(name)
    pose = pose_differences(_three_point_pose, pu, pb)
    assert not pose[:, 9:].any()                     # only the first three points count
    np.testing.assert_allclose(three_point_jacobian(pu, pb), pose, rtol=1e-6,
                               atol=1e-6 * np.abs(pose).max())


def test_the_scale_jacobian_of_a_non_coplanar_fit_is_the_closed_form() -> None:
    """sum_x (d scale_j / d x)^2 = [(A^T A)^-1]_jj: the module doc of covariance.py."""
    pu, pb = case('box')
    M, _ = _affine_fit(pu, pb)
    J = scale_jacobian(M, affine_jacobian(pu, pb))
    A = np.column_stack([pu, np.ones(len(pu))])
    np.testing.assert_allclose((J ** 2).sum(axis=1), np.diag(np.linalg.inv(A.T @ A))[:3],
                               rtol=1e-12)


def test_an_exact_mirror_gives_a_finite_jacobian_not_an_error() -> None:
    """M = diag(-1, 1, 1): its nearest rotation is not unique (tr S I - S is singular); the fit
    is refused by check_plausible, but computing its covariance must not raise."""
    M = np.diag([-1.0, 1.0, 1.0, 1.0])
    dM = np.random.default_rng(4).normal(size=(3, 4, 15))
    J = nearest_rigid_jacobian(M, dM)
    assert J.shape == (6, 15) and np.isfinite(J).all()
    np.testing.assert_array_equal(J[:3], dM[:, 3])
