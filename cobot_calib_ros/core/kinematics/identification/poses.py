"""Pose grid around a sphere, the paper's Algorithm 2 / section 4.2, planned on a given chain.

Each pose keeps the tool centre on the sphere centre and turns the tool by Rx Ry Rz (each over
``angles_deg``) relative to an approach orientation; a 7-joint arm adds an arm angle, realised
here by locking one joint (index 2, the iiwa's a3) at its home value plus the arm angle and
solving 6-dof IK on the others. 5^3 x 5 = 625 poses per sphere with the paper's angles.
"""
from __future__ import annotations

from dataclasses import dataclass
import itertools
import math
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import make_transform, rot_x, rot_y, rot_z
from cobot_calib_ros.core.kinematics.ik import solve_ik_with_restarts
from cobot_calib_ros.core.kinematics.model import Chain

Array = NDArray[np.float64]

PAPER_ANGLES_DEG = (-20.0, -10.0, 0.0, 10.0, 20.0)


@dataclass(frozen=True)
class Pose:
    """A grid pose: joint angles q (n,) [rad] reaching T_base_tool (4, 4), and its angles."""

    q: Array
    T_base_tool: Array
    rx_deg: float
    ry_deg: float
    rz_deg: float
    arm_deg: float


@dataclass(frozen=True)
class Unreachable:
    """A grid pose the IK could not reach, and why."""

    rx_deg: float
    ry_deg: float
    rz_deg: float
    arm_deg: float
    message: str


class PoseGrid(list):
    """The reachable :class:`Pose` s in grid order; the skipped ones in ``unreachable``."""

    def __init__(self, poses: Iterable[Pose], unreachable: Iterable[Unreachable]) -> None:
        super().__init__(poses)
        self.unreachable: tuple[Unreachable, ...] = tuple(unreachable)


def lock_joint(chain: Chain, index: int, angle: float) -> Chain:
    """Chain without joint ``index``, held at ``angle`` [rad]: its turn is folded into the next
    joint's placement (or the flange for the last joint)."""
    keep = [i for i in range(chain.dof) if i != index]
    held = chain.placements[index] @ make_transform(rot_z(angle), np.zeros(3))
    placements = [chain.placements[i] for i in keep]
    flange = chain.flange
    if index + 1 < chain.dof:
        placements[index] = held @ chain.placements[index + 1]
    else:
        flange = held @ chain.flange
    return Chain(tuple(chain.joint_names[i] for i in keep), np.stack(placements), chain.tool,
                 chain.lower[keep], chain.upper[keep], flange, chain.prismatic[keep])


def sphere_pose_grid(chain: Chain, sphere_centre_base: ArrayLike,
                     R_base_tool_approach: ArrayLike, home: ArrayLike,
                     angles_deg: Sequence[float] = PAPER_ANGLES_DEG,
                     arm_angles_deg: Sequence[float] = PAPER_ANGLES_DEG,
                     redundant_joint: int = 2,
                     rz_angles_deg: Sequence[float] | None = None) -> PoseGrid:
    """Joint angles for every grid pose around one sphere, solved by IK on ``chain``.

    sphere_centre_base (3,) [m]; R_base_tool_approach (3, 3); home (n,) [rad], the IK seed and
    the locked joint's reference. Orientation R_approach @ Rx(rx) @ Ry(ry) @ Rz(rz), tool
    centre (``chain.tool``) at the sphere centre; rz over ``rz_angles_deg`` (default:
    ``angles_deg``). 6-joint chains use arm angle 0 only.
    Unreachable poses (IK failure, locked joint outside its limits) are skipped and listed in
    the result's ``unreachable``. Each pose is seeded with the previous solution (the grid
    order keeps neighbours close), then with home.
    """
    home = np.asarray(home, dtype=float)
    centre = np.asarray(sphere_centre_base, dtype=float)
    R_approach = np.asarray(R_base_tool_approach, dtype=float)
    if chain.dof not in (6, 7) or home.shape != (chain.dof,):
        raise ValueError(f'need a 6- or 7-joint chain and home of shape ({chain.dof},), got '
                         f'{chain.dof} joints and {home.shape}')
    arms = tuple(arm_angles_deg) if chain.dof == 7 else (0.0,)
    rzs = tuple(angles_deg if rz_angles_deg is None else rz_angles_deg)
    poses, unreachable = [], []
    for arm in arms:
        if chain.dof == 7:
            locked = home[redundant_joint] + math.radians(arm)
            if not chain.lower[redundant_joint] <= locked <= chain.upper[redundant_joint]:
                reason = f'{chain.joint_names[redundant_joint]} at {locked:.3f} rad beyond limits'
                unreachable += [Unreachable(*a, arm, reason) for a in
                                itertools.product(angles_deg, angles_deg, rzs)]
                continue
            sub = lock_joint(chain, redundant_joint, locked)
            keep = np.arange(chain.dof) != redundant_joint
        else:
            sub, keep, locked = chain, np.ones(chain.dof, dtype=bool), 0.0
        seed = home[keep]
        for rx, ry, rz in itertools.product(angles_deg, angles_deg, rzs):
            R = R_approach @ rot_x(math.radians(rx)) @ rot_y(math.radians(ry)) \
                @ rot_z(math.radians(rz))
            target = make_transform(R, centre)
            result = solve_ik_with_restarts(sub, target, seed, home[keep])
            if not result:
                unreachable.append(Unreachable(rx, ry, rz, arm, result.message))
                continue
            q = home.copy()
            q[keep] = result.q
            q[~keep] = locked
            poses.append(Pose(q, target, float(rx), float(ry), float(rz), float(arm)))
            seed = result.q
    return PoseGrid(poses, unreachable)
