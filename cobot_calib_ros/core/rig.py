"""The rig: which kinematic chain, ending at which tool, for a cell and its active results.

One place answers "which chain, with which tool" (issue 29): the arm's parameters are the
nominal model's, or a kinematic calibration record's (the dict the repository stores); the tool
is one of :data:`TOOLS`, each from the cell or from the result that identified it:
- ``tcp``: the tool centre point (the probe tip): the TCP record's if given (its position;
  its orientation when it measured one, else the cell's), else the cell's ``tool_offset``;
- ``flange``: no tool;
- ``camera``: the wrist camera's optical frame, the hand-eye record's if given, else the cell's
  nominal hand-eye;
- ``coupling``: the sphere coupling's centre, the kinematic record's identified tool position
  if given (the calibration measured it, with the arm), else the cell's nominal one; its
  orientation is the cell's (a sphere fit sees the centre only).

Records come in as the repository's dicts (core reads no storage); a new kind of result
(e.g. an identified TCP) is one more argument here and one more rule in :func:`tool_offset`.
A target pose given in a user frame is solved by :func:`solve_target`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.kinematics.ik import IkResult, solve_ik_with_restarts
from cobot_calib_ros.core.kinematics.model import Chain, KinematicModel
from cobot_calib_ros.core.kinematics.robots import model_for

Array = NDArray[np.float64]
Record = dict[str, Any]
TOOLS = ('tcp', 'flange', 'camera', 'coupling')
NOMINAL = 'nominal'     # the label of the cell's own value where no result is active


def model_chain(record: Record | None, model: KinematicModel, tool: ArrayLike) -> Chain:
    """The chain a kinematic calibration record describes (the nominal one for None) with
    T_flange_tool ``tool``. ValueError if the record is of another robot or its parameters do
    not fit the model."""
    if record is None:
        return model.chain(tool=tool)
    result = record['result']
    if record.get('robot') != model.name or result['parameter_names'] != list(
            model.parameter_names):
        raise ValueError(f'kinematic calibration {record["id"]} is for robot '
                         f'{record.get("robot")!r}, not {model.name!r}')
    return model.chain(np.array(result['params'], dtype=float), tool=tool)


def tool_offset(cell: Cell, tool: str, kinematics: Record | None = None,
                hand_eye: Record | None = None, tcp: Record | None = None) -> Array:
    """(4, 4) T_flange_tool of ``tool`` (one of :data:`TOOLS`); ``tcp``: the tool's active TCP
    calibration record (store.records.TcpRecord). ValueError naming what the cell lacks or the
    tools there are."""
    if tool == 'tcp':
        T = np.array(cell.tool_offset, dtype=float)
        if tcp is not None:
            measured = np.array(tcp['result']['T_flange_tcp'], dtype=float)
            T[:3, 3] = measured[:3, 3]
            if tcp['result'].get('orientation_method', 'none') != 'none':
                T[:3, :3] = measured[:3, :3]
        return T
    if tool == 'flange':
        return np.eye(4)
    if tool == 'camera':
        if hand_eye is not None:
            return np.array(hand_eye['result']['T_flange_optical'], dtype=float)
        if cell.camera is None:
            raise ValueError(f'cell {cell.name!r} has no camera: section; use another tool '
                             f'({", ".join(TOOLS)})')
        return np.asarray(cell.camera.T_flange_optical, dtype=float)
    if tool == 'coupling':
        if cell.spheres is None:
            raise ValueError(f'cell {cell.name!r} has no spheres: section (its coupling); use '
                             f'another tool ({", ".join(TOOLS)})')
        T = np.array(cell.spheres.coupling_offset, dtype=float)
        if kinematics is not None and kinematics['result'].get('tool_xyz') is not None:
            T[:3, 3] = kinematics['result']['tool_xyz']   # the centre only is identified
        return T
    raise ValueError(f'unknown tool {tool!r}; use one of {", ".join(TOOLS)}')


@dataclass(frozen=True)
class ActiveSet:
    """The results a rig is built from, as the repository's records (None: the cell's own
    nominal value): the kinematic calibration in use, the active hand-eye, TCP and user
    frame. A new kind of result is one more field here and one more rule in
    :func:`tool_offset`."""

    kinematics: Record | None = None
    hand_eye: Record | None = None
    tcp: Record | None = None       # the active TCP calibration of the cell's tool
    user_frame: Record | None = None    # the active user-frame calibration

    @property
    def kinematics_label(self) -> str:
        return NOMINAL if self.kinematics is None else self.kinematics['id']

    @property
    def hand_eye_label(self) -> str:
        return NOMINAL if self.hand_eye is None else self.hand_eye['id']

    @property
    def tcp_label(self) -> str:
        return NOMINAL if self.tcp is None else self.tcp['id']


class Rig:
    """A cell's robot with its active results: every "which chain, with which tool" of the
    suite is :meth:`chain` of a rig (nodes, checks, the verbs, robot_adapter)."""

    def __init__(self, cell: Cell, active: ActiveSet = ActiveSet(),
                 model: KinematicModel | None = None) -> None:
        self.cell, self.active = cell, active
        self.model = model_for(cell) if model is None else model
        # refused here, not at the first motion: a record of another robot
        model_chain(active.kinematics, self.model, np.eye(4))

    def tool(self, tool: str = 'tcp') -> Array:
        """(4, 4) T_flange_tool of ``tool`` (one of :data:`TOOLS`)."""
        return tool_offset(self.cell, tool, self.active.kinematics, self.active.hand_eye,
                           self.active.tcp)

    def chain(self, tool: str = 'tcp') -> Chain:
        """The arm with the kinematics in use, ending at ``tool``."""
        return model_chain(self.active.kinematics, self.model, self.tool(tool))

    def nominal_chain(self, tool: str = 'tcp') -> Chain:
        """The nominal arm ending at ``tool`` (the same tool as :meth:`chain`): what a
        controller with its nominal kinematics does, and what motions are planned on."""
        return self.model.chain(tool=self.tool(tool))

    def T_base_user(self) -> Array:
        """(4, 4) the active user frame in the base; ValueError when there is none."""
        frame = self.active.user_frame
        if frame is None or frame['result'].get('T_base_user') is None:
            raise ValueError(f'no active user frame in the results of cell {self.cell.name}; '
                             'calibrate one first (cobot-calib teach, calibrate_user_frame)')
        return np.array(frame['result']['T_base_user'], dtype=float)

    def with_kinematics(self, record: Record | None) -> Rig:
        return Rig(self.cell, replace(self.active, kinematics=record), self.model)


def solve_target(chain_: Chain, T_frame_tool: ArrayLike, seed: ArrayLike, home: ArrayLike,
                 T_base_frame: ArrayLike | None = None) -> IkResult:
    """Joints that put ``chain_``'s tool at ``T_frame_tool``, a pose in the frame
    ``T_base_frame`` (a user frame in the base; None: the base), from ``seed`` (then ``home``)."""
    T = np.asarray(T_frame_tool, dtype=float)
    if T_base_frame is not None:
        T = np.asarray(T_base_frame, dtype=float) @ T
    return solve_ik_with_restarts(chain_, T, seed, home)
