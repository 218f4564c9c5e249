"""The rig: which kinematic chain, ending at which tool, for a cell and its active results.

One place answers "which chain, with which tool" (issue 29): the arm's parameters are the
nominal model's, or a kinematic calibration's (:class:`Kinematics`); the tool is one of
:data:`TOOLS`, each from the cell or from the result that identified it:
- ``tcp``: the tool centre point (the probe tip): the active :class:`Tcp`'s (its position;
  its orientation when it measured one, else the cell's), else the cell's ``T_flange_tool``;
- ``flange``: no tool;
- ``camera``: the wrist camera's optical frame, the :class:`HandEye`'s if given, else the
  cell's nominal hand-eye;
- ``coupling``: the sphere coupling's centre, the kinematic calibration's identified tool
  position if given (the calibration measured it, with the arm), else the cell's nominal one;
  its orientation is the cell's (a sphere fit sees the centre only).

Results come in as small typed records (one per kind, below: what core needs, in SI, with the
result's id and ``measured_through``: kind -> the id of the result it was measured through,
'nominal' for the cell's own value); store.rigs builds them from the stored records and
:func:`store.rigs.active_set` gathers a cell's :class:`ActiveSet`. A new kind of result is one
more record type here, one more :class:`ActiveSet` field and, if it is a tool, one more rule
in :func:`T_flange_tool`. A target pose given in a user frame is solved by :func:`solve_target`.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.kinematics.ik import IkResult, solve_ik_with_restarts
from cobot_calib_ros.core.kinematics.model import Chain, KinematicModel
from cobot_calib_ros.core.kinematics.robots import model_for

Array = NDArray[np.float64]
TOOLS = ('tcp', 'flange', 'camera', 'coupling')
NOMINAL = 'nominal'     # the label of the cell's own value where no result is active
KINDS = ('kinematics', 'tcp', 'hand_eye', 'intrinsics', 'user_frame')   # the result kinds


@dataclass(frozen=True, eq=False)
class Kinematics:
    """A kinematic calibration of ``robot`` (a model name): the model's full parameter vector
    and, when it identified one, the tool position (the sphere coupling's centre) [m]."""

    id: str
    robot: str
    parameter_names: tuple[str, ...]
    params: Array                          # (P,) [m, rad]
    p_flange_tool: Array | None = None     # (3,) [m] on the flange
    measured_through: Mapping[str, str] = field(default_factory=dict)
    unseen_tool_note: str = ''   # what the measurement could not see that every tool carries


@dataclass(frozen=True, eq=False)
class Tcp:
    """A TCP calibration of ``tool``: T_flange_tool [m], its rotation a measured one only when
    ``orientation_measured``."""

    id: str
    tool: str
    T_flange_tool: Array                   # (4, 4)
    orientation_measured: bool = False
    measured_through: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class HandEye:
    """A hand-eye calibration: T_flange_optical [m] of the wrist camera."""

    id: str
    T_flange_optical: Array                # (4, 4)
    measured_through: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """An intrinsics calibration of ``camera`` (its optical frame): the lens as a
    core.landmarks.camera.CameraModel."""

    id: str
    camera: str
    model: Any                             # core.landmarks.camera.CameraModel
    measured_through: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class UserFrame:
    """A user-frame calibration: T_base_user [m]."""

    id: str
    T_base_user: Array                     # (4, 4)
    measured_through: Mapping[str, str] = field(default_factory=dict)


def model_chain(kinematics: Kinematics | None, model: KinematicModel,
                tool: ArrayLike) -> Chain:
    """The chain a kinematic calibration describes (the nominal one for None) with
    T_flange_tool ``tool``. ValueError if it is of another robot or its parameters do not fit
    the model."""
    if kinematics is None:
        return model.chain(tool=tool)
    if kinematics.robot != model.name or tuple(kinematics.parameter_names) != tuple(
            model.parameter_names):
        raise ValueError(f'kinematic calibration {kinematics.id} is for robot '
                         f'{kinematics.robot!r}, not {model.name!r}')
    return model.chain(np.array(kinematics.params, dtype=float), tool=tool)


def T_flange_tool(cell: Cell, tool: str, kinematics: Kinematics | None = None,
                hand_eye: HandEye | None = None, tcp: Tcp | None = None) -> Array:
    """(4, 4) T_flange_tool of ``tool`` (one of :data:`TOOLS`); ``tcp``: the tool's active TCP
    calibration. ValueError naming what the cell lacks or the tools there are."""
    if tool == 'tcp':
        T = np.array(cell.T_flange_tool, dtype=float)
        if tcp is not None:
            measured = np.asarray(tcp.T_flange_tool, dtype=float)
            T[:3, 3] = measured[:3, 3]
            if tcp.orientation_measured:
                T[:3, :3] = measured[:3, :3]
        return T
    if tool == 'flange':
        return np.eye(4)
    if tool == 'camera':
        if hand_eye is not None:
            return np.array(hand_eye.T_flange_optical, dtype=float)
        if cell.camera is None:
            raise ValueError(f'cell {cell.name!r} has no camera: section; use another tool '
                             f'({", ".join(TOOLS)})')
        return np.asarray(cell.camera.T_flange_optical, dtype=float)
    if tool == 'coupling':
        if cell.spheres is None:
            raise ValueError(f'cell {cell.name!r} has no spheres: section (its coupling); use '
                             f'another tool ({", ".join(TOOLS)})')
        T = np.array(cell.spheres.T_flange_coupling, dtype=float)
        if kinematics is not None and kinematics.p_flange_tool is not None:
            T[:3, 3] = kinematics.p_flange_tool # the centre only is identified
        return T
    raise ValueError(f'unknown tool {tool!r}; use one of {", ".join(TOOLS)}')


@dataclass(frozen=True)
class ActiveSet:
    """The results a rig is built from (None: the cell's own nominal value): the kinematic
    calibration in use, the active TCP of the cell's tool, hand-eye, intrinsics of the wrist
    camera and user frame; ``stale``: the results among them measured through a result that is
    no longer the one in use (core.provenance.Stale, one line each). store.rigs.active_set
    gathers it; a new kind of result is one more field here."""

    kinematics: Kinematics | None = None
    hand_eye: HandEye | None = None
    tcp: Tcp | None = None
    user_frame: UserFrame | None = None
    intrinsics: Intrinsics | None = None
    stale: tuple = ()

    def label(self, kind: str) -> str:
        """The id of the ``kind`` (one of :data:`KINDS`) in use, 'nominal' for none."""
        result = getattr(self, kind)
        return NOMINAL if result is None else result.id

    @property
    def kinematics_label(self) -> str:
        return self.label('kinematics')

    @property
    def hand_eye_label(self) -> str:
        return self.label('hand_eye')

    @property
    def tcp_label(self) -> str:
        return self.label('tcp')

    def stale_of(self, kinds) -> tuple:
        """The staleness of the results of ``kinds`` (those a consumer uses)."""
        return tuple(s for s in self.stale if s.kind in kinds)

    def tool_label(self, tool: str) -> str:
        """The id of the result ``tool``'s offset comes from ('nominal': the cell's; '' for
        the flange)."""
        kind = TOOL_RESULTS.get(tool, '')
        return self.label(kind) if kind else ''

    def stale_used(self, tool: str, in_user_frame: bool) -> tuple:
        """The staleness of the results a pose of ``tool`` (in the active user frame when
        ``in_user_frame``) is solved with."""
        kinds = {'kinematics', TOOL_RESULTS.get(tool, '')} | (
            {'user_frame'} if in_user_frame else set())
        return self.stale_of(kinds)


TOOL_RESULTS = {'tcp': 'tcp', 'camera': 'hand_eye', 'coupling': 'kinematics', 'flange': ''}


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
        return T_flange_tool(self.cell, tool, self.active.kinematics, self.active.hand_eye,
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
        if frame is None:
            raise ValueError(f'no active user frame in the results of cell {self.cell.name}; '
                             'calibrate one first (cobot-calib teach, calibrate_user_frame)')
        return np.array(frame.T_base_user, dtype=float)

    def with_kinematics(self, kinematics: Kinematics | None) -> Rig:
        return Rig(self.cell, replace(self.active, kinematics=kinematics), self.model)


def solve_target(chain_: Chain, T_frame_tool: ArrayLike, seed: ArrayLike, home: ArrayLike,
                 T_base_frame: ArrayLike | None = None) -> IkResult:
    """Joints that put ``chain_``'s tool at ``T_frame_tool``, a pose in the frame
    ``T_base_frame`` (a user frame in the base; None: the base), from ``seed`` (then ``home``)."""
    T = np.asarray(T_frame_tool, dtype=float)
    if T_base_frame is not None:
        T = np.asarray(T_base_frame, dtype=float) @ T
    return solve_ik_with_restarts(chain_, T, seed, home)
