"""A simulated sphere-coupling cell for the identification tests: the paper's setup on iiwa7.

Three spheres at the paper's Table 1 positions (world frame, mm) on a plate placed in the
iiwa7 workspace, an eccentric coupling (the tool centre off the flange axis, as the paper's
trihedral coupling), and a "true" robot: nominal + errors of the size of the paper's Table 6
on chosen parameters. Data come from the Algorithm 2 grid solved by IK on the TRUE chain, so
the true tool centre sits on the sphere centre to the IK tolerance (1e-10 m).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics import fk, solve_ik
from cobot_calib_ros.core.kinematics.identification import (
    lock_joint, ParameterSet, sphere_pose_grid, SphereObservations, tool_transform)
from cobot_calib_ros.core.kinematics.model import iiwa7

MODEL = iiwa7()
TOOL = np.array([0.030, -0.010, 0.060])  # nominal coupling centre in the flange [m]
SPHERES_WORLD = np.array([[0.0, 0.0, 0.0], [300.009, 0.0, 0.0],
                          [150.049, 260.051, 0.0]]) * 1e-3  # paper Table 1 [m]
KNOWN_DISTANCES = tuple((i, j, float(np.linalg.norm(SPHERES_WORLD[i] - SPHERES_WORLD[j])))
                        for i, j in ((0, 1), (0, 2), (1, 2)))
T_BASE_WORLD = frames.make_transform(frames.rot_z(math.pi / 2), [0.65, -0.15, 0.20])
CENTRES_BASE = frames.apply(T_BASE_WORLD, SPHERES_WORLD)
ELBOW_UP = np.radians([0.0, 40.0, 0.0, -80.0, 0.0, 60.0, 0.0])
# error scale per parameter kind [m or rad], the size of the paper's Table 6 deviations
ERROR_SCALE = {'alpha': 1e-3, 'a': 2e-4, 'theta': 5e-4, 'd': 5e-4, 'tool': 3e-4}


def true_robot(free: tuple[str, ...], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(params, p_flange_tool) of a robot differing from nominal on ``free`` (uniform errors)."""
    ps = ParameterSet(MODEL, free)
    rng = np.random.default_rng(seed)
    errors = [ERROR_SCALE[n.split('_')[0]] * rng.uniform(-1.0, 1.0) for n in free]
    return ps.assign(ps.values(MODEL.nominal, TOOL) + errors, MODEL.nominal, TOOL)


def approach(chain, centre: np.ndarray) -> np.ndarray:
    """Tool pointing down (as at ELBOW_UP), tilted about the horizontal so the wrist leans
    away from the base for near spheres and towards it for far ones (keeps all 625 poses of
    each sphere reachable)."""
    radial = np.array([centre[0], centre[1], 0.0]) / math.hypot(centre[0], centre[1])
    tilt = math.radians(15.0) * (0.55 - math.hypot(centre[0], centre[1])) / 0.15
    return (Rotation.from_rotvec(tilt * np.cross([0.0, 0.0, 1.0], radial)).as_matrix()
            @ fk(chain, ELBOW_UP)[:3, :3])


def home_for(chain, centre: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Configuration on the sphere in orientation R with joint a3 at 0 (the arm-angle origin)."""
    result = solve_ik(lock_joint(chain, 2, 0.0), frames.make_transform(R, centre),
                      np.delete(ELBOW_UP, 2))
    assert result, result.message
    return np.insert(result.q, 2, 0.0)


def sphere_data(params: np.ndarray, p_flange_tool: np.ndarray, angles_deg, arm_angles_deg,
                known_distances=KNOWN_DISTANCES) -> SphereObservations:
    """Grid poses on the three spheres, solved on the chain of (params, p_flange_tool)."""
    chain = MODEL.chain(params, tool_transform(p_flange_tool))
    q, sphere = [], []
    for s, centre in enumerate(CENTRES_BASE):
        R = approach(chain, centre)
        grid = sphere_pose_grid(chain, centre, R, home_for(chain, centre, R), angles_deg,
                                arm_angles_deg)
        assert not grid.unreachable, grid.unreachable[:3]
        q += [pose.q for pose in grid]
        sphere += [s] * len(grid)
    return SphereObservations(np.array(q), np.array(sphere), known_distances)
