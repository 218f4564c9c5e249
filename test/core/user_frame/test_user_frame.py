"""core.user_frame: the paper's three- and N-point methods, rigid and robust fits, surface."""
from __future__ import annotations

import math

from hypothesis import assume, given, settings, strategies as st
from hypothesis.extra.numpy import arrays
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core import user_frame as uf
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import apply, from_vector, transform_error

# The paper's layout (ISO 9283): rectangle corners and centre on the table, user z = 0 [m].
RECT5 = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4, 0.3, 0.0], [0.0, 0.3, 0.0],
                  [0.2, 0.15, 0.0]])
# Six markers, no three on a line: a pentagon and its centre.
PENT6 = np.array([[0.2 + 0.2 * math.cos(a), 0.15 + 0.15 * math.sin(a), 0.0]
                  for a in np.arange(5) * 2 * math.pi / 5] + [[0.2, 0.15, 0.0]])
T_TRUE = from_vector([0.55, -0.12, 0.03, 0.1, -0.2, 0.7])
SIGMA = 3e-5  # [m] point noise of the Monte-Carlo tests


def noisy(T: np.ndarray, p_user: np.ndarray, sigma: float, rng: np.random.Generator
          ) -> np.ndarray:
    return apply(T, p_user) + rng.normal(0.0, sigma, p_user.shape)


def pose_error(T: np.ndarray, T_ref: np.ndarray) -> np.ndarray:
    """(rho, phi) with t = t_ref + rho, R = Exp(phi) R_ref, the module's convention [m, rad]."""
    phi = Rotation.from_matrix(T[:3, :3] @ T_ref[:3, :3].T).as_rotvec()
    return np.concatenate([T[:3, 3] - T_ref[:3, 3], phi])


# ----------------------------------------------------------------------------- 1. properties

poses = arrays(np.float64, 6, elements=st.floats(-3.0, 3.0)).map(from_vector)


@st.composite
def layouts(draw: st.DrawFn) -> np.ndarray:
    """Paper layout, flat random sets (z = 0) or 3-D random sets, well spread [m]."""
    kind = draw(st.sampled_from(['paper', 'flat', 'spatial']))
    if kind == 'paper':
        return RECT5
    n = draw(st.integers(3, 8))
    points = draw(arrays(np.float64, (n, 3), elements=st.floats(-0.5, 0.5)))
    if kind == 'flat':
        points[:, 2] = 0.0
    d = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(n)
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    assume(d.min() > 0.02 and min(uf.collinearity(points), uf.collinearity(points[:3])) > 0.05)
    assume(s[2] < 1e-12 * s[0] or s[2] > 0.05 * s[0])  # clearly flat or clearly 3-D
    return points


@pytest.mark.parametrize('method', uf.METHODS)
@settings(max_examples=60, deadline=None)
@given(T=poses, p_user=layouts())
def test_noise_free_points_recover_the_pose(method: str, T: np.ndarray, p_user: np.ndarray
                                            ) -> None:
    fit = uf.calibrate(method, p_user, apply(T, p_user))
    assert fit, fit.message
    dt, dr = transform_error(fit.T_base_user, T)
    assert dt < 1e-9 and dr < 1e-9
    np.testing.assert_allclose(fit.M, T, atol=1e-9)
    assert fit.max_residual < 1e-9
    np.testing.assert_allclose(fit.scale, 1.0, atol=1e-9)
    np.testing.assert_allclose(fit.shear, 0.0, atol=1e-9)
    assert fit.outliers == ()
    assert not np.isnan(fit.covariance).any()   # inf when there is no spare measurement


# ----------------------------------------------------------------------------- 2. three_point


def test_three_point_is_the_papers_m_on_hand_numbers() -> None:
    p_user = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.15, 0.0]]
    p_base = [[0.5, 0.1, 0.02], [0.7, 0.1, 0.02], [0.5, 0.22, 0.11]]
    # eq 3: v12 = (0.2, 0, 0), v13 = (0, 0.12, 0.09)
    # eq 4: k = v12 x v13 / |.| = (0, -0.018, 0.024) / 0.03 = (0, -0.6, 0.8); i = (1, 0, 0);
    #       j = k x i = (0, 0.8, 0.6)       eq 5: M = [i j k O], O = P1
    expected = np.array([[1.0, 0.0, 0.0, 0.5],
                         [0.0, 0.8, -0.6, 0.1],
                         [0.0, 0.6, 0.8, 0.02],
                         [0.0, 0.0, 0.0, 1.0]])
    fit = uf.fit_three_point(p_user, p_base)
    assert fit, fit.message
    np.testing.assert_allclose(fit.M, expected, atol=1e-12)
    np.testing.assert_allclose(fit.T_base_user, expected, atol=1e-12)
    assert fit.max_residual < 1e-12


def test_three_point_follows_the_papers_construction_on_an_inexact_triangle() -> None:
    """Measured triangle 1 mm long and not square: origin stays at P1, i along P1P2, k normal."""
    p_user = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.15, 0.0]]
    p1, p2, p3 = np.array([[0.5, 0.1, 0.02], [0.701, 0.1, 0.02], [0.5008, 0.2204, 0.1103]])
    v12, v13 = p2 - p1, p3 - p1                                         # eq 3
    k = np.cross(v12, v13) / np.linalg.norm(np.cross(v12, v13))         # eq 4
    i = v12 / np.linalg.norm(v12)
    expected = np.eye(4)
    expected[:3] = np.column_stack([i, np.cross(k, i), k, p1])           # eq 5, O = P1
    fit = uf.fit_three_point(p_user, [p1, p2, p3])
    np.testing.assert_allclose(fit.M, expected, atol=1e-12)
    np.testing.assert_allclose(fit.residuals[0], 0.0, atol=1e-15)
    assert np.linalg.norm(np.cross(fit.residuals[1], i)) < 1e-15        # P2 off along i only
    assert fit.max_residual == pytest.approx(1e-3, rel=1e-3)


def test_three_point_brief_numbers_give_a_pure_translation() -> None:
    fit = uf.fit_three_point([[0, 0, 0], [0.2, 0, 0], [0, 0.15, 0]],
                             [[0.5, 0.1, 0.02], [0.7, 0.1, 0.02], [0.5, 0.25, 0.02]])
    np.testing.assert_allclose(fit.M[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(fit.M[:3, 3], [0.5, 0.1, 0.02], atol=1e-12)


def test_three_point_uses_only_the_first_three_points() -> None:
    p_user = RECT5 + [0.05, 0.02, 0.0]           # P1 off the user origin
    p_base = apply(T_TRUE, p_user)
    p_base[3:] += [[1e-4, 0.0, -2e-4], [0.0, 3e-4, 0.0]]
    fit = uf.fit_three_point(p_user, p_base)
    np.testing.assert_allclose(fit.M, T_TRUE, atol=1e-12)
    np.testing.assert_allclose(fit.residuals[:3], 0.0, atol=1e-12)
    np.testing.assert_allclose(fit.residuals[3:], [[-1e-4, 0.0, 2e-4], [0.0, -3e-4, 0.0]],
                               atol=1e-12)
    assert fit.max_residual == pytest.approx(3e-4, rel=1e-9)
    assert fit.rms == pytest.approx(math.sqrt((5e-8 + 9e-8) / 5), rel=1e-9)


# ----------------------------------------------------------------------------- 3. five_point_lsq


def test_five_point_lsq_completes_the_z_column_of_a_flat_layout() -> None:
    p_base = apply(T_TRUE, RECT5)
    fit = uf.fit_five_point_lsq(RECT5, p_base)
    assert fit and 'coplanar' in fit.message
    above = np.array([[0.1, 0.2, 0.01], [0.3, 0.05, -0.02]])  # 10 mm over, 20 mm under
    np.testing.assert_allclose(apply(fit.M, above), apply(T_TRUE, above), atol=1e-12)
    # The paper's eqs 6-8 fed to numpy as they stand: rank-3 A, zero z column, heights lost.
    A = np.column_stack([RECT5, np.ones(len(RECT5))])
    naive = np.linalg.lstsq(A, p_base, rcond=None)[0].T
    np.testing.assert_allclose(naive[:, 2], 0.0, atol=1e-12)
    assert np.linalg.norm(naive @ [0.1, 0.2, 0.01, 1.0] - apply(T_TRUE, above[0])) > 9.9e-3


def test_five_point_lsq_reports_scale_and_shear_of_an_affine_map() -> None:
    distortion = np.array([[1.002, 0.001, 0.0], [0.0, 0.998, 0.0], [0.0, 0.0, 1.0]])
    M_true = T_TRUE.copy()
    M_true[:3, :3] = T_TRUE[:3, :3] @ distortion
    fit = uf.fit_five_point_lsq(RECT5, apply(M_true, RECT5))
    np.testing.assert_allclose(fit.M[:3, [0, 1, 3]], M_true[:3, [0, 1, 3]], atol=1e-12)
    norms = [1.002, math.hypot(0.001, 0.998)]
    normal = np.cross(fit.M[:3, 0], fit.M[:3, 1])
    np.testing.assert_allclose(fit.M[:3, 2], normal / np.linalg.norm(normal) * np.mean(norms),
                               atol=1e-12)
    np.testing.assert_allclose(fit.scale, [*norms, np.mean(norms)], atol=1e-12)
    np.testing.assert_allclose(fit.shear, [-math.atan2(0.001, 0.998), 0.0, 0.0], atol=1e-12)
    dt, dr = transform_error(fit.T_base_user, T_TRUE)
    assert dt < 1e-12 and 1e-4 < dr < 2e-3   # the nearest rotation absorbs half the shear
    assert fit.max_residual < 1e-12


def test_five_point_lsq_recovers_a_full_affine_map_from_3d_points() -> None:
    p_user = np.vstack([RECT5, [[0.1, 0.1, 0.05], [0.3, 0.2, 0.08]]])
    M_true = T_TRUE.copy()
    M_true[:3, :3] = T_TRUE[:3, :3] @ [[1.001, 0.002, -0.001], [0.0, 0.999, 0.003],
                                       [0.0, 0.0, 1.003]]
    fit = uf.fit_five_point_lsq(p_user, apply(M_true, p_user))
    assert fit and 'coplanar' not in fit.message
    np.testing.assert_allclose(fit.M, M_true, atol=1e-12)
    assert fit.condition_number == pytest.approx(
        np.divide(*np.linalg.svd(p_user - p_user.mean(0), compute_uv=False)[[0, 2]]))


# ----------------------------------------------------------------------------- 4. robust


def test_robust_names_a_2mm_outlier_among_six() -> None:
    """Each point in turn off by 2 mm (100 sigma); 4 trials each. A good point may also go at
    the test's design rate (0.5 % of calibrations, per round): at most 1 of these 24."""
    extra = 0
    for index in range(len(PENT6)):
        rng = np.random.default_rng(index)
        for trial in range(4):
            p_base = noisy(T_TRUE, PENT6, 2e-5, rng)
            offset = rng.normal(size=3) if trial else np.array([0.0, 0.0, 1.0])  # height error
            p_base[index] += T_TRUE[:3, :3] @ offset * 2e-3 / np.linalg.norm(offset)
            fit = uf.fit_robust(PENT6, p_base)
            assert fit, fit.message
            assert index in fit.outliers and f'rejected P{index + 1}:' in fit.message
            extra += len(fit.outliers) - 1
            assert np.linalg.norm(fit.residuals[index]) == pytest.approx(2e-3, rel=0.05)
            assert fit.max_residual < 1e-4
            limit = uf.estimation_limit(np.delete(PENT6, index, axis=0), 2e-5)
            dt, dr = transform_error(fit.T_base_user, T_TRUE)
            assert dt < uf.LIMIT_FACTOR * limit[0] and dr < uf.LIMIT_FACTOR * limit[1]
            plain_dt, _ = transform_error(uf.fit_rigid(PENT6, p_base).T_base_user, T_TRUE)
            assert plain_dt > 5 * dt
    assert extra <= 1


@pytest.mark.parametrize('index', range(len(RECT5)))
def test_robust_names_an_in_plane_outlier_on_the_paper_layout(index: int) -> None:
    p_base = noisy(T_TRUE, RECT5, 2e-5, np.random.default_rng(10 + index))
    p_base[index] += T_TRUE[:3, :3] @ [1.6e-3, -1.2e-3, 0.0]
    fit = uf.calibrate('robust', RECT5, p_base)
    assert fit.outliers == (index,) and f'rejected P{index + 1}:' in fit.message


@pytest.mark.parametrize('corner, opposite', [(0, 2), (1, 3), (2, 0), (3, 1)])
def test_robust_says_a_corner_height_error_cannot_be_located_on_five_points(
        corner: int, opposite: int) -> None:
    """Dropping the opposite corner leaves three points on a diagonal plus one: a plane."""
    p_base = noisy(T_TRUE, RECT5, 2e-5, np.random.default_rng(corner))
    p_base[corner] += T_TRUE[:3, 2] * 2e-3
    fit = uf.fit_robust(RECT5, p_base)
    assert fit.code == ErrorCode.DEGENERATE_POINTS and fit.T_base_user is None
    assert f'P{corner + 1}' in fit.message and f'P{opposite + 1}' in fit.message
    assert 'cannot tell' in fit.message


def test_robust_locates_a_height_error_when_no_three_points_are_on_a_line() -> None:
    pentagon = PENT6[:5]
    for index in range(5):
        p_base = noisy(T_TRUE, pentagon, 2e-5, np.random.default_rng(index))
        p_base[index] += T_TRUE[:3, 2] * 2e-3
        assert uf.fit_robust(pentagon, p_base).outliers == (index,)


def test_robust_names_two_outliers() -> None:
    grid = np.array([[x, y, 0.0] for x in (0.0, 0.2, 0.4) for y in (0.0, 0.15, 0.3)])
    rng = np.random.default_rng(7)
    for pair in [(0, 4), (2, 6), (1, 8), (3, 5)]:
        p_base = noisy(T_TRUE, grid, 2e-5, rng)
        p_base[list(pair)] += rng.normal(size=(2, 3)) * 1.2e-3
        fit = uf.fit_robust(grid, p_base)
        assert fit.outliers == pair, fit.message
        assert fit.max_residual < 1e-4


@pytest.mark.parametrize('layout', [RECT5, PENT6], ids=['rect5', 'pent6'])
def test_robust_keeps_the_points_of_clean_noisy_data(layout: np.ndarray) -> None:
    """Clean data: good points go at most at the design rate (0.5 %; here <= 1 % of 300), never
    with a floor of 10 sigma, and the fit never fails."""
    rng = np.random.default_rng(3)
    lost, floored = 0, 0
    for _ in range(300):
        p_base = noisy(T_TRUE, layout, 2e-5, rng)
        fit = uf.fit_robust(layout, p_base)
        assert fit, fit.message
        lost += len(fit.outliers)
        floored += len(uf.fit_robust(layout, p_base, threshold=2e-4).outliers)
    assert lost <= 3 and floored == 0


def test_robust_threshold_option_and_three_points() -> None:
    p_base = noisy(T_TRUE, PENT6, 2e-5, np.random.default_rng(1))
    p_base[2] += [0.0, 0.0, 2e-3]
    assert uf.calibrate('robust', PENT6, p_base, threshold=5e-3).outliers == ()
    assert uf.calibrate('robust', PENT6, p_base, threshold=1e-3).outliers == (2,)
    three = uf.fit_robust(RECT5[:3], apply(T_TRUE, RECT5[:3]))
    assert three and three.outliers == () and 'at least 4' in three.message


def test_robust_floor_never_rejects_a_sub_floor_deviation() -> None:
    """Near noise-free data (1 um): a 30 um deviation is 25 standard deviations off the fit of
    the others, but below the default floor (50 um) it stays; without a floor it goes."""
    p_base = noisy(T_TRUE, PENT6, 1e-6, np.random.default_rng(5))
    p_base[3] += [0.0, 3e-5, 0.0]
    assert uf.ROBUST_THRESHOLD > 3e-5 and uf.fit_robust(PENT6, p_base).outliers == ()
    fit = uf.fit_robust(PENT6, p_base, threshold=0.0)
    assert fit.outliers == (3,) and fit.message.startswith('rejected P4: 0.030 mm')


def test_robust_sigma_prior_and_false_rejection_set_the_test() -> None:
    """0.15 mm off with 0.02 mm noise: within what 5 estimated-noise points can tell, beyond a
    known 0.02 mm (chi-square test), within a known 0.1 mm or a 1e-9 false-rejection rate."""
    p_base = noisy(T_TRUE, PENT6, 2e-5, np.random.default_rng(6))
    p_base[3] += [0.0, 1.5e-4, 0.0]
    assert uf.fit_robust(PENT6, p_base).outliers == ()
    known = uf.fit_robust(PENT6, p_base, sigma_prior=2e-5)
    assert known.outliers == (3,) and known.sigma == 2e-5
    assert 'limit 4.1 for a 0.5% false-rejection rate' in known.message
    assert uf.fit_robust(PENT6, p_base, sigma_prior=1e-4).outliers == ()
    assert uf.fit_robust(PENT6, p_base, sigma_prior=2e-5, false_rejection=1e-9).outliers == ()


def test_robust_refuses_more_gross_errors_than_it_can_sort_out() -> None:
    pentagon = PENT6[:5]
    p_base = noisy(T_TRUE, pentagon, 1e-5, np.random.default_rng(0))
    p_base[0] += [5e-3, 0.0, 0.0]
    p_base[2] += [0.0, 0.0, 1e-3]
    fit = uf.fit_robust(pentagon, p_base)
    assert fit.code == ErrorCode.IMPLAUSIBLE_FIT and fit.T_base_user is None
    assert fit.message.startswith('too many gross errors: after rejecting P1, P3 is still')
    assert 'at least 4 points must remain' in fit.message


def test_robust_keeps_four_points_all() -> None:
    """At least MIN_INLIERS = 4 points remain: with 4, nothing can be rejected."""
    p_base = apply(T_TRUE, RECT5[:4])
    p_base[1] += [0.0, 0.0, 3e-3]
    fit = uf.fit_robust(RECT5[:4], p_base)
    assert fit and fit.outliers == () and 'only 4 points' in fit.message
    assert uf.MIN_INLIERS == 4 and '5 are needed' in fit.message


@pytest.mark.parametrize('opts', [{'false_rejection': 0.0}, {'false_rejection': 1.0},
                                  {'threshold': -1e-4}, {'sigma_prior': 0.0}])
def test_robust_bad_options_raise(opts: dict[str, float]) -> None:
    with pytest.raises(ValueError, match='false_rejection'):
        uf.fit_robust(PENT6, apply(T_TRUE, PENT6), **opts)


# ----------------------------------------------------------------------------- 5. covariance


def monte_carlo(method: str, n_trials: int) -> tuple[np.ndarray, np.ndarray]:
    """Pose errors (n, 6) and estimated sigma^2 (n,) of fits to noisy RECT5 [m, rad]."""
    rng = np.random.default_rng(2024)
    fits = [uf.calibrate(method, RECT5, noisy(T_TRUE, RECT5, SIGMA, rng))
            for _ in range(n_trials)]
    errors = np.array([pose_error(f.T_base_user, T_TRUE) for f in fits])
    return errors, np.array([f.sigma ** 2 for f in fits])


@pytest.mark.parametrize('method, n_trials', [
    ('rigid', 2000), ('three_point', 400), ('five_point_lsq', 400)])
def test_covariance_matches_monte_carlo(method: str, n_trials: int) -> None:
    errors, sigma2 = monte_carlo(method, n_trials)
    cov = uf.calibrate(method, RECT5, apply(T_TRUE, RECT5), sigma_prior=SIGMA).covariance
    np.testing.assert_allclose(cov, cov.T, atol=1e-20)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    np.testing.assert_allclose(errors.std(axis=0), np.sqrt(np.diag(cov)), rtol=0.15)
    assert sigma2.mean() == pytest.approx(SIGMA ** 2, rel=0.15)  # unbiased noise estimate
    limit = uf.estimation_limit(RECT5, SIGMA, method=method)
    achieved = [np.sqrt((e ** 2).sum(axis=1).mean()) for e in (errors[:, :3], errors[:, 3:])]
    np.testing.assert_allclose(achieved, limit, rtol=0.15)


def test_three_point_limit_is_worse_than_rigid_and_analytic_matches_sampling() -> None:
    limits = {m: uf.estimation_limit(RECT5, SIGMA, method=m) for m in uf.METHODS}
    assert limits['three_point'][1] > 1.3 * limits['rigid'][1]
    for method, limit in limits.items():
        sampled = uf.estimation_limit(RECT5, SIGMA, method=method, n_trials=2000)
        np.testing.assert_allclose(sampled, limit, rtol=0.15)
    # the limit does not depend on where the frame is, and scales with sigma
    assert uf.estimation_limit(RECT5, 2 * SIGMA) == pytest.approx(
        tuple(2 * v for v in limits['rigid']))
    rotated = uf.pose_covariance(RECT5, T_TRUE[:3, :3], SIGMA)
    assert np.trace(rotated[:3, :3]) == pytest.approx(limits['rigid'][0] ** 2)


def test_covariance_without_spare_measurements_is_inf_not_nan() -> None:
    fit = uf.fit_five_point_lsq(RECT5[:3], apply(T_TRUE, RECT5[:3]))
    assert fit and 'sigma_prior' in fit.message
    assert not np.isnan(fit.covariance).any()
    assert np.isinf(np.diag(fit.covariance)).all()
    prior = uf.fit_five_point_lsq(RECT5[:3], apply(T_TRUE, RECT5[:3]), sigma_prior=SIGMA)
    assert np.isfinite(prior.covariance).all() and prior.sigma == SIGMA


# ----------------------------------------------------------------------------- 6. surface


def height_field(p: np.ndarray) -> np.ndarray:
    """A bowed, tilted table [m]: 1 mm bow over 0.4 m, 0.5 mm/m tilt."""
    x, y = p[:, 0], p[:, 1]
    bow = 1e-3 * ((x - 0.2) / 0.2) ** 2 + 0.6e-3 * ((y - 0.15) / 0.15) ** 2
    return bow - 0.4e-3 * x * y / 0.06 + 5e-4 * x


def test_surface_fit_reduces_the_height_residual() -> None:
    grid = np.array([[x, y, 0.0] for x in (0.0, 0.2, 0.4) for y in (0.0, 0.15, 0.3)])
    p_base = apply(T_TRUE, grid + np.outer(height_field(grid), [0, 0, 1]))
    T = uf.fit_rigid(grid, p_base).T_base_user
    surface = uf.fit_surface(grid, p_base, T)
    assert surface and surface.powers_x == (0, 1, 0, 2, 1, 0)
    assert surface.rms_before > 2e-4 and surface.rms_after < 0.02 * surface.rms_before
    held_out = np.array([[0.1, 0.07, 0.0], [0.33, 0.22, 0.0]])
    truth = apply(T_TRUE, held_out + np.outer(height_field(held_out), [0, 0, 1]))
    corrected = np.linalg.norm(uf.user_to_base(T, held_out, surface) - truth, axis=1)
    plain = np.linalg.norm(uf.user_to_base(T, held_out) - truth, axis=1)
    assert corrected.max() < 2e-5 and plain.min() > 1e-4


def test_surface_order_follows_the_point_count() -> None:
    p_base = apply(T_TRUE, RECT5)
    assert uf.fit_surface(RECT5, p_base, T_TRUE).powers_x == (0, 1, 0)    # 5 -> plane
    assert uf.fit_surface(RECT5[:3], p_base[:3], T_TRUE).powers_x == (0,)  # 3 -> offset
    too_high = uf.fit_surface(RECT5, p_base, T_TRUE, order=2)
    assert not too_high and 'spare degree' in too_high.message
    tilted = apply(T_TRUE, RECT5 + np.outer(0.01 * RECT5[:, 0] + 1e-3, [0, 0, 1]))
    plane = uf.fit_surface(RECT5, tilted, T_TRUE, order=1)
    np.testing.assert_allclose(plane.coefficients, [1e-3, 0.01, 0.0], atol=1e-12)
    assert plane.rms_after < 1e-12


@settings(max_examples=50, deadline=None)
@given(T=poses, points=arrays(np.float64, (7, 3), elements=st.floats(-1.0, 1.0)),
       coefficients=arrays(np.float64, 6, elements=st.floats(-0.01, 0.01)))
def test_user_base_round_trip(T: np.ndarray, points: np.ndarray, coefficients: np.ndarray
                              ) -> None:
    surface = uf.SurfaceModel((0, 1, 0, 2, 1, 0), (0, 0, 1, 0, 1, 2), coefficients,
                              1e-3, 1e-4, ErrorCode.SUCCESS)
    np.testing.assert_allclose(uf.base_to_user(T, uf.user_to_base(T, points, surface), surface),
                               points, atol=1e-12)
    np.testing.assert_allclose(uf.user_to_base(T, uf.base_to_user(T, points, surface), surface),
                               points, atol=1e-12)
    np.testing.assert_allclose(uf.user_to_base(T, points, uf.SurfaceModel()), apply(T, points),
                               atol=1e-15)


# ----------------------------------------------------------------------------- 7. bad inputs


def with_nan(points: np.ndarray, index: int, value: float = math.nan) -> np.ndarray:
    out = points.copy()
    out[index, 1] = value
    return out


BASE = apply(T_TRUE, RECT5)
LINE = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 1e-6, 0.0], [0.3, 0.0, 0.0]])
BAD = {
    'too few': (RECT5[:2], BASE[:2], ErrorCode.TOO_FEW_POINTS, ['2 point', 'at least three']),
    'mismatch': (RECT5, BASE[:4], ErrorCode.INVALID_INPUT, ['5 user points', '4 base points']),
    'nan': (RECT5, with_nan(BASE, 3), ErrorCode.INVALID_INPUT, ['base point P4', 'not finite']),
    'inf': (with_nan(RECT5, 1, math.inf), BASE, ErrorCode.INVALID_INPUT, ['user point P2']),
    'huge': (RECT5, with_nan(BASE, 2, 1e200), ErrorCode.INVALID_INPUT,     # hung the SVD
             ['base point P3', 'metres']),
    'millimetres': (RECT5 * 1e3, BASE * 1e3 + 2e3, ErrorCode.INVALID_INPUT,
                    ['base point P1', 'not millimetres']),
    'same user': (RECT5[[0, 1, 2, 1]], BASE[:4], ErrorCode.DEGENERATE_POINTS,
                  ['user points P2 and P4', 'different marker']),
    'same base': (RECT5, BASE[[0, 1, 2, 3, 0]], ErrorCode.DEGENERATE_POINTS,
                  ['base points P1 and P5', 'robot move']),
    'collinear': (LINE, apply(T_TRUE, LINE), ErrorCode.DEGENERATE_POINTS,
                  ['collinear', 'not on one line']),
}


@pytest.mark.parametrize('method', uf.METHODS)
@pytest.mark.parametrize('case', BAD)
def test_bad_input_is_a_value_with_a_useful_message(method: str, case: str) -> None:
    p_user, p_base, code, words = BAD[case]
    fit = uf.calibrate(method, p_user, p_base)
    assert not fit and fit.code == code and fit.T_base_user is None and fit.M is None
    assert all(word in fit.message for word in words), fit.message
    numbers = [fit.rms, fit.max_residual, fit.condition_number, fit.collinearity, fit.sigma]
    assert not np.isnan(numbers).any() and not np.isnan(fit.covariance).any()


def test_three_point_needs_its_first_three_points_off_a_line() -> None:
    p_user = RECT5[[0, 4, 2, 1, 3]]    # corner, centre, opposite corner: a diagonal
    p_base = apply(T_TRUE, p_user)
    fit = uf.fit_three_point(p_user, p_base)
    assert fit.code == ErrorCode.DEGENERATE_POINTS and 'first 3 points' in fit.message
    assert uf.fit_rigid(p_user, p_base)


def test_unknown_method_and_default() -> None:
    fit = uf.calibrate('four_point', RECT5, BASE)
    assert fit.code == ErrorCode.UNKNOWN_METHOD and 'four_point' in fit.message
    assert all(name in fit.message for name in uf.METHODS)
    assert uf.calibrate('', RECT5, BASE).method == 'rigid'


def test_wrong_shapes_raise() -> None:
    with pytest.raises(ValueError, match='N, 3'):
        uf.fit_rigid(RECT5[:, :2], BASE[:, :2])
    with pytest.raises(ValueError):
        uf.calibrate('rigid', RECT5, 'five points')
    with pytest.raises(ValueError, match='unknown method'):
        uf.estimation_limit(RECT5, SIGMA, method='nope')


def test_diagnostics_of_a_good_fit() -> None:
    fit = uf.fit_rigid(RECT5, BASE)
    assert fit.condition_number == pytest.approx(4 / 3)   # 0.4 x 0.3 m rectangle
    assert fit.collinearity == pytest.approx(3 / 4)
    assert uf.estimation_limit(LINE, SIGMA) == (math.inf, math.inf)


# ----------------------------------------------------------------------------- 8. names

HOUSE = ['home', 'x_axis', 'corner', 'y_axis', 'centre']   # names for RECT5


def test_names_default_to_p1_to_pn_and_must_match_the_points() -> None:
    assert uf.point_names(3) == ('P1', 'P2', 'P3') == uf.point_names(3, [])
    assert uf.point_names(2, ('a', 'b')) == ('a', 'b')
    with pytest.raises(ValueError, match='one per point'):
        uf.calibrate('rigid', RECT5, BASE, names=HOUSE[:4])
    with pytest.raises(ValueError, match='one per point'):
        uf.point_names(2, 'ab')


@pytest.mark.parametrize('method', uf.METHODS)
def test_input_failures_name_the_points(method: str) -> None:
    nan = uf.calibrate(method, RECT5, with_nan(BASE, 2), names=HOUSE)
    assert 'base point corner is not finite' in nan.message
    same = uf.calibrate(method, RECT5[[0, 1, 2, 1, 4]], BASE, names=HOUSE)
    assert 'user points x_axis and y_axis coincide' in same.message
    assert 'base point corner' in uf.fit_surface(RECT5, with_nan(BASE, 2), T_TRUE,
                                                 names=HOUSE).message


def test_three_point_names_its_first_three_points() -> None:
    p_user = RECT5[[0, 4, 2, 1, 3]]
    fit = uf.calibrate('three_point', p_user, apply(T_TRUE, p_user), names=list('ABCDE'))
    assert 'the first 3 points (A, B, C) are (nearly) collinear' in fit.message


def test_robust_messages_name_the_points() -> None:
    p_base = noisy(T_TRUE, RECT5, 2e-5, np.random.default_rng(12))
    p_base[2] += T_TRUE[:3, :3] @ [1.6e-3, -1.2e-3, 0.0]
    fit = uf.calibrate('robust', RECT5, p_base, names=HOUSE)
    assert fit.outliers == (2,) and fit.message.startswith('rejected corner: 2.0')
    p_base = noisy(T_TRUE, RECT5, 2e-5, np.random.default_rng(0))
    p_base[0] += T_TRUE[:3, 2] * 2e-3
    fit = uf.calibrate('robust', RECT5, p_base, names=HOUSE)
    assert 'cannot tell which of points home or corner is wrong' in fit.message
