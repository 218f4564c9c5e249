"""Joint compliance: an elastic joint deflects in proportion to the gravity torque it carries.

The error model ``<model>+compliance`` (:class:`..measurement_fit.ErrorModel`) adds one
candidate per revolute joint, ``compliance_<joint>`` [rad]:

    q_model_j = q_j + offset_j + compliance_j * tau_j(q)

tau_j(q) is the gravity torque about joint j of the links beyond it, at the nominal geometry
and the measured joints, normalised to [-1, 1] (below). The links are lumped, no inertials
needed (MUKCa's iiwa 14 URDF has none): each link is a uniform rod from its joint's origin to
the next one's (the last to the flange), its mass proportional to its length and placed at its
middle. Joint j's torque is divided by the largest it can carry, the links beyond it stretched
out horizontally, so ``compliance_j`` is the deflection of joint j under its own largest
gravity torque [rad]: a real arm's are below a few mrad; bounded and reported as an angle.
Gravity is -z of the base frame (a floor-mounted arm).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.kinematics.model import _move_joint, _right_mul, KinematicModel

Array = NDArray[np.float64]
PREFIX = 'compliance_'
SUFFIX = '+compliance'
DOWN = (0.0, 0.0, -1.0)      # gravity in the base frame (direction; the scale is normalised)


def candidates(model: KinematicModel) -> tuple[str, ...]:
    """One compliance per revolute joint (a prismatic joint's is not modelled)."""
    slide = np.asarray(model.prismatic, dtype=bool) if len(model.prismatic) else \
        np.zeros(len(model.joint_names), bool)
    return tuple(f'{PREFIX}{j}' for j, s in zip(model.joint_names, slide) if not s)


def joint_index(model: KinematicModel, name: str) -> int:
    return model.joint_names.index(name[len(PREFIX):])


def gravity_torques(model: KinematicModel, q: ArrayLike, down: ArrayLike = DOWN) -> Array:
    """(m, n) normalised gravity torque about each joint (module docstring) at joints q (m, n)
    of the nominal ``model``; 0 for a prismatic joint."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    chain = model.chain()
    m, n = q.shape
    T = np.broadcast_to(np.eye(4), (m, 4, 4)).copy()
    origins, axes = [], []
    for i in range(n):
        T = _right_mul(T, chain.placements[i])
        _move_joint(T, q[:, i], bool(chain.prismatic[i]))
        origins.append(T[:, :3, 3].copy())
        axes.append(T[:, :3, 2].copy())
    origins.append(_right_mul(T, chain.flange)[:, :3, 3])
    ends = np.stack(origins, axis=1)                               # (m, n + 1, 3)
    lengths = np.linalg.norm(ends[:, 1:] - ends[:, :-1], axis=2)   # link k: joint k -> k + 1
    centres = 0.5 * (ends[:, 1:] + ends[:, :-1])
    weight = lengths[:, :, None] * np.asarray(down, dtype=float) / np.linalg.norm(down)
    reach = np.cumsum(lengths[0, ::-1])[::-1]                      # joint j -> flange
    tau = np.zeros((m, n))
    for j in range(n):
        if chain.prismatic[j]:
            continue
        arm = centres[:, j:] - ends[:, j:j + 1]
        moment = np.sum(np.cross(arm, weight[:, j:]), axis=1)
        # stretched out: link k's centre at (reach_j - reach_k) + l_k / 2 from joint j
        most = float(np.sum(lengths[0, j:] * (reach[j] - reach[j:] + 0.5 * lengths[0, j:])))
        tau[:, j] = np.einsum('mi,mi->m', moment, axes[j]) / max(most, 1e-12)
    return tau
