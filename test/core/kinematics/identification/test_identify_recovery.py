"""Noise-free recovery: the identified robot reproduces the true one to 1e-6 mm everywhere.

True robot = nominal iiwa7 + Table-6-sized errors on the parameters Algorithm 1 keeps (with the
eccentric coupling and tool_x/y/z as candidates); data = the Algorithm 2 grid (a subset:
rx, ry, rz, arm in {-20, 0, 20} deg, 81 poses per sphere) solved on the true chain; start =
nominal. Held out: 200 uniform configurations over the whole joint space, far outside the
three spheres' neighbourhood.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification import (
    absolute_errors, all_pairs, default_candidates, find_redundant, identify, ParameterSet,
    PositionObservations, SphereObservations, tool_frames, uniform_configurations)
from sphere_scene import (CENTRES_BASE, KNOWN_DISTANCES, MODEL, sphere_data, TOOL,
                          true_robot)

ANGLES = (-20.0, 0.0, 20.0)
HELD_OUT = uniform_configurations(MODEL, 200, 99)
TOLERANCE_M = 1e-9  # 1e-6 mm


@pytest.fixture(scope='module')
def free() -> tuple[str, ...]:
    q = uniform_configurations(MODEL, 29, 0)
    return find_redundant(MODEL, q, TOOL, default_candidates(MODEL)).kept


@pytest.fixture(scope='module')
def truth(free):
    return true_robot(free, seed=7)


@pytest.fixture(scope='module')
def data(truth):
    return sphere_data(*truth, ANGLES, ANGLES)


def held_out_errors(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """(identified, nominal) position errors [m] on HELD_OUT after rigid registration."""
    p_true = tool_frames(MODEL, *truth, HELD_OUT)[:, :3, 3]
    return (absolute_errors(MODEL, result.params, result.tool_xyz, HELD_OUT, p_true),
            absolute_errors(MODEL, MODEL.nominal, TOOL, HELD_OUT, p_true))


def check_recovery(result, truth, free) -> None:
    errors, nominal = held_out_errors(result, truth)
    print(f'{result.message}: {result.iterations} iterations, {result.solve_seconds:.3f} s, '
          f'rms {result.rms_m:.3g} m; held-out max {errors.max() * 1e3:.3g} mm '
          f'(nominal {nominal.max() * 1e3:.3f} mm)')
    assert result.code == ErrorCode.SUCCESS
    assert nominal.max() > 1e-3  # the errors matter: over 1 mm with the nominal model
    assert errors.max() < TOLERANCE_M
    ps = ParameterSet(MODEL, free)
    assert ps.values(result.params, result.tool_xyz) == pytest.approx(
        ps.values(*truth), abs=1e-9)
    assert np.all(np.isfinite(result.std)) and result.std.max() < 1e-8
    assert 'unidentifiable' not in result.extra


def test_grid_data_sit_on_the_spheres(data, truth):
    p = tool_frames(MODEL, *truth, data.q)[:, :3, 3]
    assert len(data.q) == 3 * 81
    assert np.abs(p - CENTRES_BASE[data.sphere]).max() < 2e-10


def test_centres_form_recovers_the_true_robot(free, truth, data):
    result = identify(ParameterSet(MODEL, free), data, tool_xyz0=TOOL, loss='linear')
    check_recovery(result, truth, free)
    assert result.extra['form'] == 'centres' and result.extra['objective'] == 'relative'
    centres = result.extra['sphere_centres_base']
    assert np.array([centres[s] for s in (0, 1, 2)]) == pytest.approx(CENTRES_BASE, abs=1e-9)


def test_pairs_form_recovers_the_true_robot(free, truth, data):
    """The paper's eq 11 on all pairs of every third row (81 rows, 3240 pairs)."""
    pairs = all_pairs(np.arange(0, len(data.q), 3))
    result = identify(ParameterSet(MODEL, free), data, tool_xyz0=TOOL, loss='linear',
                      pairs=pairs)
    check_recovery(result, truth, free)
    assert result.extra['pairs_same_sphere'] + result.extra['pairs_known_distance'] == len(pairs)
    assert result.extra['pairs_skipped'] == 0


def test_pairs_without_known_distances_are_skipped(free, data):
    """A pair between spheres whose distance is unknown says nothing frame-free: skipped."""
    q, sphere = data.q, data.sphere
    only_01 = SphereObservations(q, sphere, KNOWN_DISTANCES[:1])
    pairs = all_pairs(np.arange(0, len(q), 9))
    result = identify(ParameterSet(MODEL, free), only_01, tool_xyz0=TOOL, loss='linear',
                      pairs=pairs, max_iterations=2)
    s = sphere[pairs]
    unknown = (s[:, 0] != s[:, 1]) & ~np.isin(s, [0, 1]).all(axis=1)
    assert result.extra['pairs_skipped'] == unknown.sum() > 0


def test_absolute_objective_recovers_robot_and_world_frame(free, truth):
    """Laser-tracker data: positions in a world frame 1 m away, rotated; base frame identified."""
    T_world_base = frames.from_xyz_rpy([1.2, -0.4, 0.3], [0.05, -0.1, 2.0])
    q = uniform_configurations(MODEL, 60, 5)
    p = frames.apply(T_world_base, tool_frames(MODEL, *truth, q)[:, :3, 3])
    result = identify(ParameterSet(MODEL, free), PositionObservations(q, p), tool_xyz0=TOOL,
                      loss='linear')
    assert result.extra['form'] == 'absolute'
    assert result.extra['T_world_base'] == pytest.approx(T_world_base, abs=1e-10)
    p_held = frames.apply(T_world_base, tool_frames(MODEL, *truth, HELD_OUT)[:, :3, 3])
    errors = absolute_errors(MODEL, result.params, result.tool_xyz, HELD_OUT, p_held,
                             result.extra['T_world_base'])
    assert errors.max() < TOLERANCE_M
