"""Kinematics core: reference FK values, pinocchio agreement, parameters, IK round trips."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.testing import assert_allclose
import pinocchio as pin
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics import (
    Chain, fk, KinematicModel, model_by_name, position_jacobian_wrt_params, solve_ik,
    to_pinocchio)
from cobot_calib_ros.core.kinematics.model import iiwa14, iiwa7, sawyer, ur10_pybotics

DATA = Path(__file__).resolve().parents[2] / 'data' / 'pybotics'
SAWYER_NEUTRAL = [0.0, -1.18, 0.0, 2.18, 0.0, 0.57, 3.3161]  # named_poses.yaml [rad]


def random_q(chain: Chain, rng: np.random.Generator, m: int, margin: float = 0.9) -> np.ndarray:
    """(m, n) configurations [rad] inside margin * the joint limits."""
    return rng.uniform(margin * chain.lower, margin * chain.upper, (m, chain.dof))


def some_tool() -> np.ndarray:
    """A non-trivial T_flange_tool [m, rad]."""
    return frames.from_xyz_rpy([0.01, -0.02, 0.15], [0.1, -0.2, 0.3])


# --- reference values -----------------------------------------------------------------------

def test_ur10_matches_pybotics_reference():
    table = np.loadtxt(DATA / 'ur10-joints-poses.csv', delimiter=',', comments='#')
    assert table.shape == (20, 22)
    q = np.radians(table[:, :6])
    T = fk(ur10_pybotics().chain(), q)
    T[:, :3, 3] *= 1000.0  # m -> mm, as in the reference
    assert_allclose(T, table[:, 6:].reshape(-1, 4, 4), rtol=0.0, atol=1e-3)


@pytest.mark.parametrize(('q_deg', 'p_expected'), [
    ([0, 0, 0, 0, 0, 0, 0], [0.0, 0.0, 1.266]),
    ([10, 20, 30, -40, 50, -60, 70], [0.494907331, 0.137578658, 1.005000788]),
    ([-45, 60, -30, -90, 20, 45, 0], [0.194559951, -0.503081699, 0.118122285]),
])
def test_iiwa7_flange_position(q_deg, p_expected):
    T = fk(iiwa7().chain(), np.radians(q_deg))
    assert_allclose(T[:3, 3], p_expected, rtol=0.0, atol=1e-9)


@pytest.mark.parametrize(('q', 'p_expected'), [
    ([0.0] * 7, [1.0155, 0.1603, 0.3170]),
    (SAWYER_NEUTRAL, [0.4496, 0.1603, 0.21575]),
    ([0.3, -0.5, 0.2, 1.0, -0.4, 0.6, 1.0], [0.72185, 0.45363, 0.15185]),
])
def test_sawyer_right_hand_position(q, p_expected):
    T = fk(sawyer().chain(), q)
    assert_allclose(T[:3, 3], p_expected, rtol=0.0, atol=6e-5)


def test_sawyer_neutral_hand_points_down_within_limits():
    model = sawyer()
    T = fk(model.chain(), SAWYER_NEUTRAL)
    assert_allclose(T[:3, 2], [0.0008, 0.0, -1.0], rtol=0.0, atol=5e-5)
    assert np.all((model.lower <= SAWYER_NEUTRAL) & (np.array(SAWYER_NEUTRAL) <= model.upper))


def test_iiwa14_differs_from_iiwa7_by_link_lengths_only():
    assert_allclose(fk(iiwa14().chain(), np.zeros(7))[:3, 3], [0.0, 0.0, 1.306], atol=1e-12)
    assert_allclose(iiwa14().lower, iiwa7().lower)
    assert_allclose(iiwa7().upper[[0, 1, 6]], np.radians([170, 120, 175]))


# --- fk structure ---------------------------------------------------------------------------

@pytest.mark.parametrize('name', ['iiwa7', 'iiwa14', 'sawyer', 'ur10'])
def test_vectorised_fk_equals_loop(name):
    chain = model_by_name(name).chain(tool=some_tool())
    q = random_q(chain, np.random.default_rng(1), 50)
    assert_allclose(fk(chain, q), np.stack([fk(chain, qi) for qi in q]), rtol=0, atol=1e-15)
    assert fk(chain, q[0]).shape == (4, 4)
    assert fk(chain, q[:1]).shape == (1, 4, 4)


def test_fk_equals_explicit_mdh_product():
    model, q = iiwa7(), np.radians([10, 20, 30, -40, 50, -60, 70])
    T = np.eye(4)
    for (alpha, a, theta, d), qi in zip(model.rows(), q):
        T = (T @ frames.make_transform(frames.rot_x(alpha), [0, 0, 0])
             @ frames.make_transform(np.eye(3), [a, 0, 0])
             @ frames.make_transform(frames.rot_z(theta + qi), [0, 0, d]))
    assert_allclose(fk(model.chain(), q), T, rtol=0, atol=1e-15)


def test_tool_is_applied_after_flange():
    model, q, tool = sawyer(), np.array(SAWYER_NEUTRAL), some_tool()
    assert_allclose(fk(model.chain(tool=tool), q), fk(model.chain(), q) @ tool, atol=1e-15)


def test_fk_rejects_wrong_shape():
    with pytest.raises(ValueError, match='expected q of shape'):
        fk(iiwa7().chain(), np.zeros(6))
    with pytest.raises(ValueError, match='parameters'):
        iiwa7().chain(np.zeros(27))
    with pytest.raises(ValueError, match='unknown robot model'):
        model_by_name('puma560')


def test_chain_is_read_only():
    chain = iiwa7().chain()
    with pytest.raises(ValueError):
        chain.placements[0, 0, 3] = 1.0


@pytest.mark.parametrize('name', ['iiwa7', 'sawyer', 'ur10'])
def test_pinocchio_fk_equals_numpy_fk(name):
    chain = model_by_name(name).chain(tool=some_tool())
    pmodel = to_pinocchio(chain)
    data = pmodel.createData()
    tool_id = pmodel.getFrameId('tool')
    for q in random_q(chain, np.random.default_rng(2), 100):
        pin.framesForwardKinematics(pmodel, data, q)
        assert_allclose(data.oMf[tool_id].homogeneous, fk(chain, q), rtol=0, atol=1e-12)
    assert_allclose(pmodel.upperPositionLimit, chain.upper)


# --- parameters -----------------------------------------------------------------------------

def test_parameter_names_and_sizes():
    assert iiwa7().parameter_names[:5] == ('alpha_1', 'a_1', 'theta_1', 'd_1', 'alpha_2')
    assert len(iiwa7().nominal) == 28
    assert sawyer().parameter_names[:7] == (
        'x_right_j0', 'y_right_j0', 'z_right_j0', 'roll_right_j0', 'pitch_right_j0',
        'yaw_right_j0', 'x_right_j1')
    assert len(sawyer().nominal) == 42
    assert isinstance(model_by_name('ur10'), KinematicModel)


def test_iiwa7_d3_plus_1mm_raises_flange_by_1mm():
    model = iiwa7()
    params = model.nominal.copy()
    params[model.parameter_names.index('d_3')] += 1e-3
    delta = fk(model.chain(params), np.zeros(7))[:3, 3] - fk(model.chain(), np.zeros(7))[:3, 3]
    assert_allclose(delta, [0.0, 0.0, 1e-3], rtol=0, atol=1e-15)


def test_theta_offset_equals_joint_offset():
    model, q = iiwa7(), np.radians([10, 20, 30, -40, 50, -60, 70])
    params = model.nominal.copy()
    params[model.parameter_names.index('theta_4')] += 0.01
    q_shifted = q.copy()
    q_shifted[3] += 0.01
    assert_allclose(fk(model.chain(params), q), fk(model.chain(), q_shifted), atol=1e-15)


@pytest.mark.parametrize('name', ['iiwa7', 'sawyer'])
def test_position_jacobian_matches_finite_differences(name):
    model, tool = model_by_name(name), some_tool()
    rng = np.random.default_rng(3)
    params = model.nominal + rng.normal(0.0, 1e-3, model.nominal.shape)
    q = random_q(model.chain(), rng, 5)
    J = position_jacobian_wrt_params(model, params, q, tool)
    h = 1e-6
    for j in range(len(params)):
        step = np.zeros_like(params)
        step[j] = h
        plus = fk(model.chain(params + step, tool), q)[:, :3, 3]
        minus = fk(model.chain(params - step, tool), q)[:, :3, 3]
        assert_allclose(J[:, :, j], (plus - minus) / (2 * h), rtol=0, atol=1e-8)


# --- inverse kinematics ---------------------------------------------------------------------

@pytest.mark.parametrize('name', ['iiwa7', 'sawyer'])
def test_ik_round_trip(name):
    chain = model_by_name(name).chain(tool=some_tool())
    rng = np.random.default_rng(4)
    for q_true in random_q(chain, rng, 30):
        T_target = fk(chain, q_true)
        result = solve_ik(chain, T_target, q_true + rng.normal(0.0, 0.1, chain.dof))
        assert result, result.message
        position_error, angle_error = frames.transform_error(fk(chain, result.q), T_target)
        assert position_error < 1e-9 and angle_error < 1e-9
        assert result.position_error < 1e-10 and result.orientation_error < 1e-10
        assert np.all((chain.lower <= result.q) & (result.q <= chain.upper))


def test_ik_position_only():
    chain = iiwa7().chain()
    rng = np.random.default_rng(5)
    q_true = random_q(chain, rng, 1)[0]
    target = fk(chain, q_true)
    target[:3, :3] = np.eye(3)  # orientation to be ignored
    result = solve_ik(chain, target, q_true + 0.1, position_only=True)
    assert result, result.message
    assert_allclose(fk(chain, result.q)[:3, 3], target[:3, 3], rtol=0, atol=1e-9)
    assert np.isnan(result.orientation_error)


@pytest.mark.parametrize('name', ['iiwa7', 'sawyer'])
def test_ik_unreachable_target_fails_as_value(name):
    chain = model_by_name(name).chain()
    target = fk(chain, np.zeros(chain.dof))
    target[:3, 3] += [3.0, 0.0, 0.0]
    result = solve_ik(chain, target, np.zeros(chain.dof))
    assert not result and result.code == ErrorCode.MOTION_FAILED
    assert result.position_error > 1.0
    assert 'no convergence' in result.message
    assert np.all((chain.lower <= result.q) & (result.q <= chain.upper))


def test_ik_reports_joint_limit_blocking():
    chain = iiwa7().chain()
    q_out = np.radians([0, 0, 0, 150, 0, 0, 0])  # A4 beyond its 120 deg limit
    result = solve_ik(chain, fk(chain, q_out), np.radians([0, 0, 0, 100, 0, 0, 0]))
    assert not result
    assert 'joint_a4' in result.message
    assert result.q[3] <= chain.upper[3]
