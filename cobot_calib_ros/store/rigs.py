"""The rig of a cell with a repository's active results (core.rig.Rig): what every node, check
and verb asks for "which chain, with which tool"."""
from __future__ import annotations

from typing import Any

import numpy as np

from cobot_calib_ros.core.rig import ActiveSet, Rig
from cobot_calib_ros.core.kinematics.robots import model_for

ACTIVE = ('active', 'latest')


def rig_of(repository, cell, kinematics: str = 'latest', model=None) -> Rig:
    """``cell``'s rig with the kinematic calibration ``kinematics`` names ('latest' or
    'active': the robot's active one, nominal when it has none; 'nominal'; an id), the
    active hand-eye, TCP of the cell's tool and user frame. KeyError: no such calibration
    stored; ValueError: it is of another robot (both name it)."""
    model = model_for(cell) if model is None else model
    choice = 'latest' if kinematics in ACTIVE else kinematics
    record = repository.kinematics.resolve(choice, model.name)
    return Rig(cell, ActiveSet(record, active_hand_eye(repository), active_tcp(repository, cell),
                               repository.user_frames.active()), model)


def active_tcp(repository, cell) -> dict[str, Any] | None:
    """The active TCP calibration of the cell's tool (named by its tool_frame), None if there
    is none or it does not read as a transform (the cell's tool_offset is used then)."""
    try:
        record = repository.tcp.active(cell.tool_frame)
    except (OSError, ValueError):
        return None
    if record is None:
        return None
    T = np.array(record['result'].get('T_flange_tcp', ()), dtype=float)
    return record if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


def active_hand_eye(repository) -> dict[str, Any] | None:
    """The active hand-eye record, None if there is none or it does not read as a transform
    (the cell's nominal hand-eye is used then)."""
    try:
        record = repository.hand_eye.active()
    except (OSError, ValueError):
        return None
    if record is None:
        return None
    X = np.array(record['result'].get('T_flange_optical', ()), dtype=float)
    return record if X.shape == (4, 4) and np.all(np.isfinite(X)) else None
