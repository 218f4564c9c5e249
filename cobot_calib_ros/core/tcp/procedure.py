"""The TCP calibration as one procedure over a RobotPort (issue 39.2): plan the approaches,
check them for the arm's reach, touch, solve.

The same code runs over ROS (tcp_calibrator, through api.tcp.calibrate_and_store) and
in-process on the simulation (sim.tcp_run, the tests). It returns a :class:`TcpRun` or a
core.errors.Failure, never raises for a data, motion or capture problem; the gate, the record
and the activation are the api's (api/tcp.py). SI units: [m], [rad], [s].
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.robot_port import (Cancelled, never, port_failure, PortError,
                                             RobotPort, Stopped)
from cobot_calib_ros.core.tcp.solve import solve_position, TcpSolution
from cobot_calib_ros.core.tcp.touches import (checked_plan, DEFAULT_APPROACHES,
                                              DEFAULT_ELONGATION, DEFAULT_TILT, plan_touches,
                                              solve_touches, take_touches, TcpPlan, TcpTouches)

Array = NDArray[np.float64]
# touch index (from 0), touches planned, RMS tip distance of the approaches so far [m]
# (0 before the fourth, or while they are too alike)
Progress = Callable[[int, int, float], None]


@dataclass(frozen=True)
class TcpRequest:
    """What a TCP calibration is asked for (the action goal's, with the defaults filled)."""

    point: str
    count: int = DEFAULT_APPROACHES
    tilt: float = DEFAULT_TILT             # [rad] of the approaches from the first
    method: str = 'none'                   # orientation: 'none', 'z', 'zx'
    elongation: float = DEFAULT_ELONGATION  # [m] of the elongator points
    hold: float = 0.2                      # [s] joints averaged at every touch
    touch_sigma: float = 5e-5              # [m] the touch noise (the refinement's scale)


@dataclass(frozen=True)
class TcpRun:
    """What the procedure measured and solved."""

    plan: TcpPlan
    touches: TcpTouches
    solution: TcpSolution


def rms_so_far(touches: TcpTouches) -> float:
    """RMS tip distance of the approaches touched so far [m] (0 before four, or while they do
    not determine the tool)."""
    if touches.approaches < 4:
        return 0.0
    try:
        position = solve_position(np.array(touches.flange[:touches.approaches]))
    except (ValueError, Refusal):
        return 0.0
    return float(np.sqrt(np.mean(position.distances ** 2)))


def calibrate_tcp(request: TcpRequest, robot: RobotPort, flange_chain: kinematics.Chain,
                  tool_chain: kinematics.Chain, home: Array, *,
                  R_reference: Array | None = None, point_base: Array | None = None,
                  cancelled: Cancelled = never,
                  progress: Progress | None = None) -> TcpRun | Failure:
    """Touch ``request.point`` from the planned approaches and solve the TCP.

    ``flange_chain``: the kinematics in use ending at the flange (the flange poses);
    ``tool_chain``: the same arm through the tool as known (the reach checks); ``home`` [rad];
    ``R_reference``: the first approach's tool orientation in the base (default pointing down
    the base z); ``point_base`` (3,) [m]: where the point is when known (the active user
    frame's), checked for reach before anything moves, else from where the first touch found
    it. Failures: INVALID_INPUT (a goal that cannot work), DEGENERATE_POINTS (approaches too
    alike), MOTION_FAILED (unreachable or a move that failed), CAPTURE_FAILED, CANCELED
    (between touches), SOLVER_FAILED."""
    point = request.point
    try:
        plan = plan_touches(point, request.count, request.tilt, R_reference, request.method,
                            request.elongation)
        plan, locate = checked_plan(plan, tool_chain, home, request.tilt, point_base)
    except Refusal as e:
        where = 'planned ' if e.failure.code == ErrorCode.DEGENERATE_POINTS else \
            f'planned touches of {point}: '
        return Failure(e.failure.code, where + e.failure.message)
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    total = len(plan.steps())

    def on_touch(i: int, touches: TcpTouches) -> None:
        if progress is not None:
            progress(i, total, rms_so_far(touches))
    try:
        touches = take_touches(plan, robot, flange_chain, request.hold, cancelled=cancelled,
                               on_touch=on_touch, locate=locate)
    except Refusal as e:
        where = 'planned from the first touch: ' \
            if e.failure.code == ErrorCode.DEGENERATE_POINTS else \
            f'planned from where the first touch found {point}: '
        return Failure(e.failure.code, f'{where}{e.failure.message}; nothing stored')
    except Stopped as e:
        return port_failure(e, '; nothing stored')
    except PortError as e:
        return port_failure(e)
    try:
        solution = solve_touches(plan, touches, request.touch_sigma)
    except Refusal as e:
        return e.failure
    except (ValueError, np.linalg.LinAlgError) as e:
        return Failure(ErrorCode.SOLVER_FAILED, str(e))
    if not np.all(np.isfinite(solution.T_flange_tool)) or math.isnan(solution.turn_rad):
        return Failure(ErrorCode.SOLVER_FAILED, 'the TCP solve gave no finite result; touch '
                       'again')
    return TcpRun(plan, touches, solution)
