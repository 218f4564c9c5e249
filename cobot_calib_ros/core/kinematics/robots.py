"""The robots the project knows, and the one resolver from a cell's robot to its model.

A cell names its robot either by a built-in model (ROBOTS: the URDF-origin Sawyer, the iiwa
modified-DH tables, pybotics' UR10) or by a URDF and the two links of the chain
(``robot: {urdf: FILE, base_link: ..., tip_link: ...}``: a UrdfRobot, whose text the cell
loader read; with ``model: NAME`` a built-in model is its kinematics and the URDF its
description, where the calibration is written back). ``model_for`` turns either into the
KinematicModel every node, the simulation and the CLI use.
"""
from __future__ import annotations

from dataclasses import dataclass

from cobot_calib_ros.core.kinematics.model import (iiwa14, iiwa7, KinematicModel, sawyer,
                                                   ur10_pybotics)

BUILT_IN = {'iiwa7': iiwa7, 'iiwa14': iiwa14, 'sawyer': sawyer, 'ur10': ur10_pybotics}
ROBOTS = tuple(BUILT_IN)


@dataclass(frozen=True)
class UrdfRobot:
    """A robot given by its URDF: the chain from ``base_link`` to ``tip_link``."""

    name: str               # the model's name (records are tied to it)
    urdf_file: str          # as the cell file gives it, for messages
    base_link: str
    tip_link: str
    urdf: str = ''          # the URDF text (read by the loader)
    model: str = ''         # a built-in model of this chain (its kinematics), else the URDF's


def model_by_name(name: str) -> KinematicModel:
    """One of ROBOTS; ValueError otherwise."""
    try:
        return BUILT_IN[name]()
    except KeyError:
        raise ValueError(f'unknown robot model {name!r}; known: {sorted(BUILT_IN)}') from None


def model_for(robot) -> KinematicModel:
    """The kinematic model of a cell (core.cell.Cell: its ``urdf_robot``, else its ``robot``
    name), a built-in name, or a UrdfRobot (its chain from base_link to tip_link). ValueError
    when unknown or when the URDF has no such chain."""
    if hasattr(robot, 'urdf_robot'):                # a Cell
        robot = robot.urdf_robot or robot.robot
    if isinstance(robot, UrdfRobot) and robot.model:
        return model_by_name(robot.model)
    if isinstance(robot, UrdfRobot):
        from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
        if not robot.urdf:
            raise ValueError(f'robot {robot.name!r}: the URDF {robot.urdf_file} was not read')
        return model_from_urdf(robot.urdf, robot.base_link, robot.tip_link, robot.name)
    return model_by_name(robot)
