"""What the robot visits to collect kinematic calibration data, planned on the nominal model.

- :func:`sphere_plan`: the second paper's Algorithm 2 grid on every sphere of the cell's plate.
- :func:`tracker_plan`: configurations measured by a laser tracker, either in the calibrated
  volume (around the spheres, where the calibration is meant to hold) or spread over the
  workspace (like the paper's Tables 3-4).

A plan is a list of steps ``{'q': [rad], 'target': sphere index or -1, 'label': str}``.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.kinematics.identification.poses import lock_joint, sphere_pose_grid
from cobot_calib_ros.core.kinematics.ik import solve_ik, solve_ik_with_restarts
from cobot_calib_ros.core.kinematics.model import fk, KinematicModel

Array = NDArray[np.float64]
REGIONS = ('volume', 'workspace')
TRACKER_CONFIGS = 125          # the paper's validation set
VOLUME_MARGIN = 0.05           # the volume reaches this far beyond the sphere centres [m]
VOLUME_TILT = math.radians(20.0)   # largest tilt from the approach orientation in the volume
WORKSPACE_MIN_Z = 0.05         # workspace configurations keep the coupling this high [m]
REDUNDANT_JOINT = 2            # locked to realise the arm angle on 7-joint arms (poses.py)
LEAN_DEG = (0.0, 10.0, -10.0, 20.0, -20.0)   # approach leans tried per sphere [deg]


def even_subset(count: int, limit: int) -> NDArray[np.int64]:
    """Indices of ``limit`` steps spread evenly over ``count`` (all when limit is 0)."""
    if limit <= 0 or limit >= count:
        return np.arange(count)
    return np.unique(np.round(np.linspace(0, count - 1, limit)).astype(np.int64))


def sphere_plan(cell: Cell, model: KinematicModel, max_configs: int = 0,
                angles_deg=(-20.0, -10.0, 0.0, 10.0, 20.0),
                arm_angles_deg=None, rz_angles_deg=None) -> tuple[list[dict], list[str]]:
    """Steps that bring the coupling onto every sphere in the pose grid, and why poses were
    left out (unreachable on the nominal model). ``max_configs`` > 0 keeps an even subset.
    ``arm_angles_deg``: the arm angles of a 7-joint arm, ``rz_angles_deg`` the turns about
    the approach axis (both default: ``angles_deg``)."""
    plate = cell.spheres
    if plate is None:
        raise ValueError(f'cell {cell.name!r} has no spheres: section; see '
                         'config/cells/iiwa7_close.yaml')
    chain = model.chain(tool=plate.T_flange_coupling)
    R0 = frames.rpy_to_matrix(*plate.approach_rpy)
    arm = (angles_deg if arm_angles_deg is None else arm_angles_deg) \
        if model.chain().dof == 7 else (0.0,)
    steps, skipped = [], []
    for k, (name, centre) in enumerate(zip(plate.names, plate.centres_base())):
        R, home = _approach(chain, centre, R0, cell.home, angles_deg, arm)
        if home is None:
            skipped.append(f'{name}: the approach pose itself is unreachable')
            continue
        grid = sphere_pose_grid(chain, centre, R, home, angles_deg=angles_deg,
                                arm_angles_deg=arm, rz_angles_deg=rz_angles_deg)
        for pose in grid:
            steps.append({'q': pose.q.tolist(), 'target': k,
                          'label': f'{name} rx{pose.rx_deg:+.0f} ry{pose.ry_deg:+.0f} '
                                   f'rz{pose.rz_deg:+.0f} arm{pose.arm_deg:+.0f}'})
        skipped += [f'{name} rx{u.rx_deg:+.0f} ry{u.ry_deg:+.0f} rz{u.rz_deg:+.0f} '
                    f'arm{u.arm_deg:+.0f}: {u.message}' for u in grid.unreachable]
    return [steps[i] for i in even_subset(len(steps), max_configs)], skipped


def _approach(chain, centre: Array, R0: Array, home: Array, angles_deg,
              arm_deg) -> tuple[Array, Array | None]:
    """The approach orientation for one sphere, and the grid's home pose on it.

    ``R0`` leaned towards or away from the base by one of LEAN_DEG, whichever reaches the
    most corners of the grid (every angle at its extremes); near spheres need the wrist to
    lean out, far ones in (a quarter of the iiwa's grid is out of reach without it).
    """
    radial = np.array([centre[0], centre[1], 0.0])
    axis = np.cross([0.0, 0.0, 1.0], radial / max(np.linalg.norm(radial), 1e-9))
    extremes = (min(angles_deg), max(angles_deg))
    corners = [(rx, ry, rz, a) for rx in extremes for ry in extremes for rz in extremes
               for a in {min(arm_deg), max(arm_deg)}]
    best = (-1, None, None)
    for lean in LEAN_DEG:
        R = frames.from_vector(np.r_[0.0, 0.0, 0.0, axis * math.radians(lean)])[:3, :3] @ R0
        start = _home_on_sphere(chain, centre, R, home)
        if start is None:
            continue
        grid = sphere_pose_grid(chain, centre, R, start, angles_deg=extremes, arm_angles_deg=
                                tuple(sorted({min(arm_deg), max(arm_deg)})))
        if len(grid) > best[0]:
            best = (len(grid), R, start)
        if len(grid) == len(corners):
            break
    return best[1] if best[1] is not None else R0, best[2]


def _home_on_sphere(chain, centre: Array, R: Array, home: Array) -> Array | None:
    """The approach pose on a sphere with the redundant joint at its home value: the grid's
    reference and first seed (seeding every pose from the cell's home leaves a quarter of the
    iiwa's grid unsolved)."""
    T = frames.make_transform(R, centre)
    if chain.dof == 7:
        result = solve_ik(lock_joint(chain, REDUNDANT_JOINT, home[REDUNDANT_JOINT]), T,
                          np.delete(home, REDUNDANT_JOINT))
        return np.insert(result.q, REDUNDANT_JOINT, home[REDUNDANT_JOINT]) if result else None
    result = solve_ik_with_restarts(chain, T, home, home)
    return result.q if result else None


def tracker_plan(cell: Cell, model: KinematicModel, region: str, count: int = TRACKER_CONFIGS,
                 seed: int = 0) -> list[dict]:
    """``count`` configurations for laser-tracker measurements in ``region``."""
    if region not in REGIONS:
        raise ValueError(f'unknown region {region!r}; use one of {", ".join(REGIONS)}')
    if cell.spheres is None:
        raise ValueError(f'cell {cell.name!r} has no spheres: section (it places the coupling '
                         'that carries the retro-reflector)')
    rng = np.random.default_rng(seed)
    chain = model.chain(tool=cell.spheres.T_flange_coupling)
    draw = _volume_draw(cell, chain) if region == 'volume' else _workspace_draw(chain)
    steps, attempts = [], 0
    while len(steps) < count:
        attempts += 1
        if attempts > 50 * count:
            raise ValueError(f'only {len(steps)} of {count} {region} configurations found')
        q = draw(rng)
        if q is not None:
            steps.append({'q': q.tolist(), 'target': -1, 'label': f'{region} {len(steps)}'})
    return steps


def _volume_draw(cell: Cell, chain):
    """Random poses in the box around the spheres, tilted up to 20 deg from the approach."""
    centres = cell.spheres.centres_base()
    lo, hi = centres.min(axis=0) - VOLUME_MARGIN, centres.max(axis=0) + VOLUME_MARGIN
    hi[2] = lo[2] + 2 * VOLUME_MARGIN + 0.1
    R0 = frames.rpy_to_matrix(*cell.spheres.approach_rpy)

    def draw(rng: np.random.Generator) -> Array | None:
        axis = rng.normal(size=3)
        tilt = frames.from_vector(np.r_[0.0, 0.0, 0.0, axis / np.linalg.norm(axis)
                                        * rng.uniform(0.0, VOLUME_TILT)])[:3, :3]
        T = frames.make_transform(R0 @ tilt, rng.uniform(lo, hi))
        result = solve_ik_with_restarts(chain, T, cell.home, cell.home)
        return result.q if result else None
    return draw


def _workspace_draw(chain):
    """Uniform joint configurations (80 % of each range) with the coupling above the table and
    in front of the robot: a spread like the paper's Tables 3-4."""
    lower, upper = chain.lower * 0.8, chain.upper * 0.8

    def draw(rng: np.random.Generator) -> Array | None:
        q = rng.uniform(lower, upper)
        p = fk(chain, q)[:3, 3]
        return q if p[2] > WORKSPACE_MIN_Z and p[0] > 0.1 else None
    return draw


def uniform_configurations(model: KinematicModel, count: int, seed: int) -> Array:
    """(count, n) joint angles [rad] drawn uniformly within the joint limits (paper: 29)."""
    if not (np.all(np.isfinite(model.lower)) and np.all(np.isfinite(model.upper))):
        raise ValueError(f'model {model.name!r} has unbounded joints: give configurations')
    rng = np.random.default_rng(seed)
    return rng.uniform(model.lower, model.upper, (count, len(model.lower)))
