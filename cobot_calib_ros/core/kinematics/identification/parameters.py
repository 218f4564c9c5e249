"""Which parameters are free, and the tool position with its Jacobian over them.

The tool centre point is a pure translation ``p_flange_tool`` (3,) [m] in the flange frame (the
sphere-coupling paper identifies only the tool's translation); its free names are 'tool_x',
'tool_y', 'tool_z'. Model parameters are named as in :class:`KinematicModel`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import make_transform
from cobot_calib_ros.core.kinematics.model import (
    fk, KinematicModel, position_jacobian_wrt_params)

Array = NDArray[np.float64]

TOOL_NAMES = ('tool_x', 'tool_y', 'tool_z')


def tool_transform(p_flange_tool: ArrayLike) -> Array:
    """(4, 4) T_flange_tool of a tool centre at ``p_flange_tool`` (3,) [m], no rotation."""
    return make_transform(np.eye(3), np.asarray(p_flange_tool, dtype=float))


@dataclass(frozen=True)
class ParameterSet:
    """Free parameters: names of ``model.parameter_names`` and/or :data:`TOOL_NAMES`.

    ValueError on an unknown or repeated name, or an empty set.
    """

    model: KinematicModel
    free: tuple[str, ...]

    def __post_init__(self) -> None:
        free = tuple(self.free)
        object.__setattr__(self, 'free', free)
        known = set(self.model.parameter_names) | set(TOOL_NAMES)
        unknown = [n for n in free if n not in known]
        if unknown:
            raise ValueError(f'unknown parameter names {unknown} for model {self.model.name!r}; '
                             f'use names of model.parameter_names or {TOOL_NAMES}')
        if len(set(free)) != len(free):
            raise ValueError(f'repeated parameter names in {free}')
        if not free:
            raise ValueError('no free parameters: name at least one')

    @property
    def index(self) -> NDArray[np.intp]:
        """Positions of the free names in [model parameters..., tool_x, tool_y, tool_z]."""
        names = self.model.parameter_names + TOOL_NAMES
        return np.array([names.index(n) for n in self.free], dtype=np.intp)

    def values(self, params: ArrayLike, p_flange_tool: ArrayLike) -> Array:
        """(len(free),) current values [m or rad] of the free parameters."""
        return np.concatenate([np.asarray(params, dtype=float),
                               np.asarray(p_flange_tool, dtype=float)])[self.index]

    def assign(self, x: ArrayLike, params: ArrayLike,
               p_flange_tool: ArrayLike) -> tuple[Array, Array]:
        """Copies of (params, p_flange_tool) with the free ones set to ``x`` (len(free),)."""
        full = np.concatenate([np.asarray(params, dtype=float),
                               np.asarray(p_flange_tool, dtype=float)])
        full[self.index] = x
        return full[:-3], full[-3:]

    def positions(self, params: ArrayLike, p_flange_tool: ArrayLike, q: ArrayLike) -> Array:
        """Tool positions (m, 3) [m] in base for q (m, n) [rad]."""
        return tool_frames(self.model, params, p_flange_tool, q)[:, :3, 3]

    def positions_and_jacobian(self, params: ArrayLike, p_flange_tool: ArrayLike,
                               q: ArrayLike) -> tuple[Array, Array]:
        """Tool positions p (m, 3) [m] in base and d p / d free (m, 3, len(free)).

        q (m, n) [rad]. d p / d p_flange_tool is R_base_flange (the tool does not rotate).
        """
        p, J_model, R = tool_kinematics(self.model, params, p_flange_tool, q)
        return p, np.concatenate([J_model, R], axis=2)[:, :, self.index]


def tool_frames(model: KinematicModel, params: ArrayLike | None, p_flange_tool: ArrayLike,
                q: ArrayLike) -> Array:
    """(m, 4, 4) T_base_tool for q (m, n) [rad]; params default nominal, p_flange_tool (3,) [m]."""
    return fk(model.chain(params, tool_transform(p_flange_tool)), np.atleast_2d(q))


def tool_kinematics(model: KinematicModel, params: ArrayLike | None, p_flange_tool: ArrayLike,
                    q: ArrayLike) -> tuple[Array, Array, Array]:
    """Tool positions (m, 3) [m], d p / d model params (m, 3, P), R_base_flange (m, 3, 3).

    q (m, n) [rad]; params default nominal; tool centre ``p_flange_tool`` (3,) [m] in the flange.
    """
    T = tool_frames(model, params, p_flange_tool, q)
    J = position_jacobian_wrt_params(model, params, q, tool_transform(p_flange_tool))
    return T[:, :3, 3], J, T[:, :3, :3]
