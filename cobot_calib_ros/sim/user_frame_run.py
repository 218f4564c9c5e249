"""A user-frame calibration on the simulated cell in-process (no ROS), as user_frame_solver
does it live: touch each marker, hold, average the joints, nominal forward kinematics, fit.
For tests and benchmarks that need many calibrations fast (drift: issue 19), and a table that
moves between them (:func:`moved_table`)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from cobot_calib_ros.core import user_frame
from cobot_calib_ros.core.user_frame import procedure
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import Simulation

HOLD_S = procedure.CAPTURE_DURATION


@dataclass(frozen=True)
class SimCalibration:
    fit: user_frame.FrameFit
    names: list[str]
    p_user: np.ndarray          # (N, 3) nominal marker tops, user frame [m]
    p_base: np.ndarray          # (N, 3) measured, base frame [m]
    robot_seconds: float        # moves and holds, as mock_robot reports them


def calibrate_user_frame(sim: Simulation, seed: int, names: Sequence[str] = (),
                         method: str = 'rigid') -> SimCalibration:
    """Touch ``names`` (default: every marker of the layout) with operator seed ``seed``."""
    cell = sim.cell
    names = list(names) or [m.name for m in cell.markers]
    arm = SimRobot(sim, seed_offset=seed)
    robot = DirectRobot(arm, sim.probe)
    chain = arm.model.chain(tool=cell.T_flange_tool)
    p_base = procedure.points_of_joints(chain, procedure.touch_joints(robot, names, HOLD_S))
    p_user = np.array([cell.marker(n).nominal_top for n in names])
    fit = user_frame.calibrate(method, p_user, p_base, names=names)
    return SimCalibration(fit, names, p_user, p_base, robot.robot_seconds)


def moved_table(sim: Simulation, offset_m: Sequence[float]) -> Simulation:
    """The same cell with its table (the true user frame and every marker on it) shifted by
    ``offset_m`` (3,) [m] in the base frame."""
    T = sim.world.T_base_user.copy()
    T[:3, 3] += np.asarray(offset_m, dtype=float)
    return replace(sim, world=replace(sim.world, T_base_user=T))
