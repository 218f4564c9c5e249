"""A TCP calibration on the simulated cell in-process (no ROS), as tcp_calibrator does it live:
the same procedure (core.tcp.procedure.calibrate_tcp) over the sim's robot port. For
tests and bench/bench_tcp.py; :func:`moved_tool` gives the same cell with its real tool bent."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from cobot_calib_ros.core.tcp import TcpSolution
from cobot_calib_ros.core.tcp.procedure import calibrate_tcp as run_procedure, TcpRequest
from cobot_calib_ros.core.tcp.touches import (DEFAULT_ELONGATION, DEFAULT_TILT, TcpPlan,
                                              TcpTouches)
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import Simulation

HOLD_S = 0.2        # [s] tcp_calibrator's default hold


@dataclass(frozen=True)
class SimTcp:
    plan: TcpPlan
    touches: TcpTouches
    solution: TcpSolution
    robot_seconds: float


def calibrate_tcp(sim: Simulation, seed: int, count: int = 6, tilt: float = DEFAULT_TILT,
                  method: str = 'none', elongation: float = DEFAULT_ELONGATION,
                  exact_kinematics: bool = False, point: str = '') -> SimTcp:
    """One TCP calibration with operator seed ``seed``; the flange poses through the nominal
    kinematics, or the mock's true arm (``exact_kinematics``: as with an exact kinematic
    calibration active). RuntimeError with the Failure's message when it fails."""
    arm = SimRobot(sim, seed_offset=seed)
    robot = DirectRobot(arm, sim.probe)
    chain = arm.model.chain(arm.true_parameters if exact_kinematics else None)
    # as tcp_calibrator without a user frame: the touches checked from where the first found
    # the point, through the arm and the cell's nominal tool
    tool_chain = arm.model.chain(arm.true_parameters if exact_kinematics else None,
                                 tool=sim.cell.T_flange_tool)
    request = TcpRequest(point or sim.cell.point_names[0], count, tilt, method, elongation,
                         HOLD_S)
    run = run_procedure(request, robot, chain, tool_chain, sim.cell.home)
    if not run:
        raise RuntimeError(f'{run.code.name}: {run.message}')
    return SimTcp(run.plan, run.touches, run.solution, robot.robot_seconds)


def moved_tool(sim: Simulation, offset_m: Sequence[float]) -> Simulation:
    """The same cell with its real tool tip moved by ``offset_m`` (3,) in the flange frame."""
    T = sim.T_flange_tool_true.copy()
    T[:3, 3] += np.asarray(offset_m, dtype=float)
    return replace(sim, T_flange_tool_true=T)
