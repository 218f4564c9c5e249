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


def chain(cell: Cell, kinematics: Record | None = None, tool: str = 'tcp', *,
          hand_eye: Record | None = None, model: KinematicModel | None = None) -> Chain:
    """The chain of the cell's robot with ``kinematics`` (a kinematic calibration record, None
    for the nominal model) ending at ``tool``. ``model``: the cell's model if already built."""
    model = model_for(cell) if model is None else model
    return model_chain(kinematics, model, tool_offset(cell, tool, kinematics, hand_eye))


def solve_target(chain_: Chain, T_frame_tool: ArrayLike, seed: ArrayLike, home: ArrayLike,
                 T_base_frame: ArrayLike | None = None) -> IkResult:
    """Joints that put ``chain_``'s tool at ``T_frame_tool``, a pose in the frame
    ``T_base_frame`` (a user frame in the base; None: the base), from ``seed`` (then ``home``)."""
    T = np.asarray(T_frame_tool, dtype=float)
    if T_base_frame is not None:
        T = np.asarray(T_base_frame, dtype=float) @ T
    return solve_ik_with_restarts(chain_, T, seed, home)
