"""Noise-free recovery through the one engine (CalibrationJob, the node's core call): the
identified robot reproduces the true one to 1e-6 mm everywhere.

True robot = nominal iiwa7 + Table-6-sized errors on the parameters the identification keeps
on these data (with the eccentric coupling: tool_x/y/z, the ball); data = the Algorithm 2 grid
(a subset: rx, ry, rz, arm in {-20, 0, 20} deg, 81 poses per sphere) solved on the true chain;
start = nominal. Held out: 200 uniform configurations over the whole joint space, far outside
the three spheres' neighbourhood.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics.identification import (
    absolute_errors, ParameterSet, PositionObservations, tool_frames)
from cobot_calib_ros.core.kinematics.kinematic_calibration import (CalibrationJob,
                                                                   free_parameters)
from cobot_calib_ros.core.kinematics.plans import uniform_configurations
from sphere_scene import CENTRES_BASE, MODEL, sphere_data, TOOL, true_robot

ANGLES = (-20.0, 0.0, 20.0)
HELD_OUT = uniform_configurations(MODEL, 200, 99)
TOLERANCE_M = 1e-9  # 1e-6 mm


@pytest.fixture(scope='module')
def free() -> tuple[str, ...]:
    """What the identification keeps on the grid (the nominal robot's grid: the same poses
    within the IK's reach of a true robot's)."""
    return free_parameters(MODEL, sphere_data(MODEL.nominal, TOOL, ANGLES, ANGLES), TOOL)


@pytest.fixture(scope='module')
def truth(free):
    return true_robot(free, seed=7)


@pytest.fixture(scope='module')
def data(truth):
    return sphere_data(*truth, ANGLES, ANGLES)


def held_out_errors(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """(identified, nominal) position errors [m] on HELD_OUT after rigid registration."""
    p_true = tool_frames(MODEL, *truth, HELD_OUT)[:, :3, 3]
    return (absolute_errors(MODEL, result.params, result.p_flange_tool, HELD_OUT, p_true),
            absolute_errors(MODEL, MODEL.nominal, TOOL, HELD_OUT, p_true))


def check_recovery(outcome, truth, free) -> None:
    result = outcome.result
    errors, nominal = held_out_errors(result, truth)
    print(f'{result.message}: {result.iterations} iterations, {result.solve_seconds:.3f} s, '
          f'rms {result.rms_m:.3g} m; held-out max {errors.max() * 1e3:.3g} mm '
          f'(nominal {nominal.max() * 1e3:.3f} mm)')
    assert result.converged and outcome.verdict.passed
    assert result.free == free
    assert nominal.max() > 1e-3  # the errors matter: over 1 mm with the nominal model
    assert errors.max() < TOLERANCE_M
    ps = ParameterSet(MODEL, free)
    assert ps.values(result.params, result.p_flange_tool) == pytest.approx(
        ps.values(*truth), abs=1e-9)
    assert np.all(np.isfinite(result.std)) and result.std.max() < 1e-8


def test_grid_data_sit_on_the_spheres(data, truth):
    p = tool_frames(MODEL, *truth, data.q)[:, :3, 3]
    assert len(data.q) == 3 * 81
    assert np.abs(p - CENTRES_BASE[data.sphere]).max() < 2e-10


def test_sphere_data_recover_the_true_robot(free, truth, data):
    outcome = CalibrationJob(None, MODEL, data, p_flange_tool0=TOOL, loss='linear').run()
    check_recovery(outcome, truth, free)
    assert outcome.result.extra['objective'] == 'relative'
    centres = outcome.result.extra['nuisance']
    assert np.array([[centres[f'centre_{s}_{c}'] for c in 'xyz'] for s in (0, 1, 2)]) == \
        pytest.approx(CENTRES_BASE, abs=1e-9)


def test_tracker_data_recover_the_robot_in_a_world_frame(free, truth):
    """Laser-tracker data: positions in a world frame 1 m away, rotated (the points kind: the
    base frame is fitted with the arm)."""
    T_world_base = frames.from_xyz_rpy([1.2, -0.4, 0.3], [0.05, -0.1, 2.0])
    q = uniform_configurations(MODEL, 60, 5)
    p = frames.apply(T_world_base, tool_frames(MODEL, *truth, q)[:, :3, 3])
    outcome = CalibrationJob(None, MODEL, PositionObservations(q, p), p_flange_tool0=TOOL,
                             loss='linear').run()
    assert outcome.result.extra['objective'] == 'absolute' and outcome.verdict.passed
    p_held = frames.apply(T_world_base, tool_frames(MODEL, *truth, HELD_OUT)[:, :3, 3])
    errors = absolute_errors(MODEL, outcome.result.params, outcome.result.p_flange_tool, HELD_OUT,
                             p_held)
    assert errors.max() < TOLERANCE_M
