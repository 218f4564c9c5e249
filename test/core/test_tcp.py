"""core.tcp: the TCP solve on fixed synthetic data with known answers, its refusals and gate."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode, Refusal
from cobot_calib_ros.core.tcp import GateLimits, gate_problem, solve_position, solve_tcp
from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
from cobot_calib_ros.core.tcp.touches import plan_touches

T_FLANGE_TOOL = frames.from_xyz_rpy([0.0123, -0.0041, 0.1532], [0.012, -0.021, 0.3])
FIXED_POINT = np.array([0.52, 0.11, 0.08])


def _flange(R_tool: np.ndarray, tip: np.ndarray = FIXED_POINT) -> np.ndarray:
    """The flange pose that puts the tool (T_FLANGE_TOOL) at ``tip`` in orientation R_tool."""
    return frames.make_transform(R_tool, tip) @ frames.invert(T_FLANGE_TOOL)


def _approaches(count: int, tilt: float = 0.52, noise: float = 0.0, seed: int = 3):
    rng = np.random.default_rng(seed)
    plan = plan_touches('P1', count, tilt)
    return np.array([_flange(R, FIXED_POINT + rng.normal(0.0, noise, 3))
                     for R in plan.orientations])


def test_noise_free_approaches_give_the_tool_and_the_point_exactly():
    position = solve_position(_approaches(4))
    assert np.allclose(position.t, T_FLANGE_TOOL[:3, 3], atol=1e-12)
    assert np.allclose(position.c, FIXED_POINT, atol=1e-12)
    assert np.allclose(position.linear, [*T_FLANGE_TOOL[:3, 3], *FIXED_POINT], atol=1e-12)
    assert position.max_residual_m < 1e-12
    assert 2.0 < position.condition < 20.0


def test_noisy_touches_give_the_tool_within_their_noise_and_pass_the_gate():
    sigma = 2e-5
    position = solve_position(_approaches(8, noise=sigma))
    error = np.linalg.norm(position.t - T_FLANGE_TOOL[:3, 3])
    std = np.sqrt(np.trace(position.covariance[:3, :3]))
    assert error < 4 * std and std < 5 * sigma
    assert 0.0 < position.mean_residual_m <= position.max_residual_m < 5 * sigma
    assert position.rms_per_axis == pytest.approx(sigma, rel=0.5)
    solution = solve_tcp(_approaches(8, noise=sigma))
    assert gate_problem(solution, GateLimits(touch_sigma=sigma), nominal=T_FLANGE_TOOL) is None


def test_three_nearly_parallel_orientations_are_refused_naming_them():
    """Must-show 1: orientations 0.3 and 0.4 deg apart do not determine the tool."""
    R0 = np.diag([1.0, -1.0, -1.0])
    Rs = [R0, frames.rot_x(math.radians(0.3)) @ R0, frames.rot_y(math.radians(0.4)) @ R0]
    with pytest.raises(Refusal) as refusal:
        solve_position([_flange(R) for R in Rs])
    assert refusal.value.failure.code == ErrorCode.DEGENERATE_POINTS
    message = str(refusal.value)
    assert 'approaches 1 and 2 differ by 0.3 deg' in message
    assert 'approaches 1 and 3 differ by 0.4 deg' in message
    assert 'approaches 2 and 3 differ by 0.5 deg' in message
    assert 'tilt them >= 20 deg apart about different axes' in message


def test_a_fourth_distinct_approach_does_not_rescue_three_alike_ones():
    """Three alike and one tilted: all rotation differences are about one axis."""
    R0 = np.diag([1.0, -1.0, -1.0])
    Rs = [R0, frames.rot_x(0.004) @ R0, frames.rot_x(-0.003) @ R0, frames.rot_x(0.6) @ R0]
    with pytest.raises(Refusal, match=r'approaches 1 and 2 differ by 0\.2 deg') as refusal:
        solve_position([_flange(R) for R in Rs])
    assert 'approaches 1 and 4' not in str(refusal.value)


def test_approaches_far_apart_about_one_axis_are_refused_naming_the_axis():
    R0 = np.diag([1.0, -1.0, -1.0])
    Rs = [frames.rot_y(a) @ R0 for a in (-0.6, -0.2, 0.2, 0.6)]
    with pytest.raises(Refusal, match=r'turn about one axis \(base direction \[-?0\.0, '
                                       r'-?1\.0, -?0\.0\]\)'):
        solve_position([_flange(R) for R in Rs])


def test_too_few_or_malformed_poses_are_refused():
    with pytest.raises(ValueError, match='2 approaches: at least 3'):
        solve_position(_approaches(4)[:2])
    bad = _approaches(4)
    bad[1, 0, 3] = math.nan
    with pytest.raises(ValueError, match='finite flange poses'):
        solve_position(bad)


def test_the_refinement_keeps_one_slipped_touch_from_pulling_the_tool():
    flange = _approaches(8, noise=1e-5)
    flange[5, :3, 3] += [3e-4, -2e-4, 0.0]          # one touch slipped by 0.36 mm
    position = solve_position(flange, robust_scale=2e-5)
    linear_error = np.linalg.norm(position.linear[:3] - T_FLANGE_TOOL[:3, 3])
    refined_error = np.linalg.norm(position.t - T_FLANGE_TOOL[:3, 3])
    assert refined_error < 0.5 * linear_error
    assert position.distances.argmax() == 5


def _elongators(method: str, noise: float = 0.0):
    plan = plan_touches('P1', 6, 0.52, method=method, elongation=0.05)
    R_ref = plan.orientations[0]
    rng = np.random.default_rng(11)
    out = {}
    for axis, distance in plan.elongators:
        tip = FIXED_POINT + distance * R_ref[:, 'xyz'.index(axis)] + rng.normal(0, noise, 3)
        out[axis] = (_flange(R_ref, tip), distance)
    return np.array([_flange(R) for R in plan.orientations]), out


def test_z_and_x_elongator_points_give_the_tool_orientation():
    approaches, elongators = _elongators('zx')
    solution = solve_tcp(approaches, elongators)
    assert solution.method == 'zx' and solution.turn_rad < 1e-9
    assert np.allclose(solution.T_flange_tool, T_FLANGE_TOOL, atol=1e-9)
    assert rpy_from_matrix(solution.R_flange_tool) == pytest.approx((0.012, -0.021, 0.3),
                                                                   abs=1e-9)


def test_a_z_elongator_alone_gives_z_and_the_flange_x_made_orthogonal():
    approaches, elongators = _elongators('z')
    solution = solve_tcp(approaches, elongators)
    z_true = T_FLANGE_TOOL[:3, 2]
    assert np.allclose(solution.R_flange_tool[:, 2], z_true, atol=1e-9)
    x_expected = np.array([1.0, 0.0, 0.0]) - z_true[0] * z_true
    assert np.allclose(solution.R_flange_tool[:, 0], x_expected / np.linalg.norm(x_expected),
                       atol=1e-9)


def test_elongator_noise_turns_z_by_about_noise_over_elongation():
    approaches, elongators = _elongators('z', noise=2e-5)
    solution = solve_tcp(approaches, elongators)
    angle = math.acos(min(1.0, solution.R_flange_tool[:, 2] @ T_FLANGE_TOOL[:3, 2]))
    assert 0.0 < angle < 5 * math.sqrt(2) * 2e-5 / 0.05


def test_the_gate_names_a_slipped_touch_a_far_tool_and_a_turned_elongator():
    flange = _approaches(6, noise=2e-5)
    flange[2, :3, 3] += [0.0, 0.0, 2e-3]            # a touch 2 mm off
    problem = gate_problem(solve_tcp(flange, robust_scale=1.0), GateLimits(touch_sigma=2e-5))
    assert problem.code == ErrorCode.IMPLAUSIBLE_FIT
    problem = problem.message
    assert 'more than the touch noise (0.020 mm) explains' in problem
    assert 'touch again' in problem
    solution = solve_tcp(_approaches(6))
    nominal = T_FLANGE_TOOL.copy()
    nominal[:3, 3] += [0.0, 0.0, 0.03]
    assert "30.0 mm from the cell's T_flange_tool" in gate_problem(solution, nominal=nominal).message
    assert 'beyond 100 mm' in gate_problem(solution, GateLimits(max_tool_length=0.1)).message
    approaches, elongators = _elongators('z')
    T, d = elongators['z']
    elongators['z'] = (T @ frames.make_transform(frames.rot_x(0.05), [0, 0, 0]), d)
    assert 'turned 2.86 deg' in gate_problem(solve_tcp(approaches, elongators)).message


def test_plans_refuse_goals_that_cannot_work():
    with pytest.raises(ValueError, match='3 approaches: give 4..32'):
        plan_touches('P1', 3)
    with pytest.raises(ValueError, match='tilt 2.9 deg: give 5..60'):
        plan_touches('P1', 4, 0.05)
    with pytest.raises(ValueError, match="orientation method 'y'"):
        plan_touches('P1', 4, method='y')
    plan = plan_touches('P1', 5, method='zx')
    labels = [label for label, _ in plan.steps()]
    assert labels == ['approach 1', 'approach 2', 'approach 3', 'approach 4', 'approach 5',
                      'z elongator', 'x elongator']
    angles = [math.degrees(frames.rotation_angle(R @ plan.orientations[0].T))
              for R in plan.orientations[1:]]
    assert angles == pytest.approx([math.degrees(0.52)] * 4)


def test_a_plan_too_alike_is_refused_before_anything_moves():
    with pytest.raises(Refusal, match=r'approaches 1 and 2 differ by 6\.0 deg.*tilt them'):
        plan_touches('P1', 4, math.radians(6.0))
    assert len(plan_touches('P1', 4, math.radians(12.0)).orientations) == 4
