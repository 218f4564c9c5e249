"""The TCP calibration's one api: :func:`calibrate_and_store` runs the core procedure
(core.tcp.procedure) over a RobotPort, gates the result, stores it with what it was measured
through and activates it (tcp_calibrator's goal handler calls it); :func:`calibrate_tcp` is the
client side of that node's ``calibrate_tcp`` (``cobot-calib tcp``)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math
import time

import numpy as np

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
from cobot_calib_ros.core.provenance import missing_prerequisites
from cobot_calib_ros.core.robot_port import Cancelled, never, RobotPort
from cobot_calib_ros.core.tcp import GateLimits, gate_problem
from cobot_calib_ros.core.tcp.procedure import calibrate_tcp as run_procedure
from cobot_calib_ros.core.tcp.procedure import Progress, TcpRequest, TcpRun
from cobot_calib_ros.store.records import TcpRecord

TCP_TIMEOUT = 1200.0   # [s] for the whole calibration (an operator confirms every touch)


@dataclass(frozen=True)
class TcpOutcome:
    """A TCP calibration stored: ``code`` SUCCESS (active) or IMPLAUSIBLE_FIT (stored as
    rejected, not active), ``message`` what to tell the user. Truthy (a Failure is not)."""

    record: TcpRecord
    run: TcpRun
    active: bool
    code: ErrorCode
    message: str


def _user_frame_or_none(rig) -> np.ndarray | None:
    try:
        return rig.T_base_user()
    except (KeyError, ValueError, Refusal):
        return None


def _point_problem(cell, point: str) -> Failure | None:
    if not point:
        try:
            cell.require('the TCP calibration (no point_name)', 'layouts')
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, str(e))
    if point not in cell.point_names:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'unknown point {point!r}; the cell has {cell.point_names}')
    return None


def calibrate_and_store(request: TcpRequest, robot: RobotPort, rig, repo, tool: str,
                        stamp_ns: int, *, cancelled: Cancelled = never,
                        progress: Progress | None = None,
                        warn: Callable[[str], None] | None = None) -> TcpOutcome | Failure:
    """Calibrate the TCP of ``tool`` over ``robot`` on ``rig`` (core.rig.Rig: the cell, the
    active kinematics the flange poses come from, the active TCP and user frame the reach is
    checked with) and store it in ``repo`` (a store.Repository): active when it passes
    core.tcp.gate_problem, else kept as rejected (IMPLAUSIBLE_FIT). A Failure stores
    nothing. ``warn`` is told the missing prerequisites before anything moves."""
    cell = rig.cell
    problem = _point_problem(cell, request.point)
    if problem is not None:
        return problem
    if not 0.0 < request.hold <= 10.0:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'hold {request.hold} s: give 0..10 s (0 = the parameter)')
    T_base_user = _user_frame_or_none(rig)
    point_base = None if T_base_user is None else frames.apply(
        T_base_user, cell.marker(request.point).nominal_top)
    through = {'kinematics': rig.active.kinematics_label}
    prerequisites = missing_prerequisites(f'the TCP of {tool} is', through)
    if prerequisites and warn is not None:
        warn(prerequisites)
    t_start = time.monotonic()
    run = run_procedure(
        request, robot, rig.chain('flange'), rig.chain('tcp'), np.asarray(cell.home, float),
        R_reference=tool_down_orientation(np.eye(4) if T_base_user is None else T_base_user,
                                          'z'),
        point_base=point_base, cancelled=cancelled, progress=progress)
    if not run:
        return run
    solution, plan, touches = run.solution, run.plan, run.touches
    nominal = cell.T_flange_tool if tool == cell.tool_frame else None
    gate = gate_problem(solution, GateLimits(touch_sigma=request.touch_sigma), nominal)
    record = TcpRecord.from_solution(
        solution, tool, request.point, touches.labels, touches.joints, touches.flange,
        stamp_ns, through['kinematics'], request.tilt,
        request.elongation if plan.elongators else 0.0, '' if gate is None else gate.message,
        measured_through=through)
    try:
        activation = repo.tcp.save_and_activate(record)
    except Refusal as e:                          # another cell's (store.cells)
        return e.failure
    except (OSError, ValueError) as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the TCP calibration: {e}')
    if gate is not None:
        return TcpOutcome(record, run, bool(activation), gate.code, (
            f'{record.id} rejected, stored as rejected and not made active (the active TCP '
            f'of {tool} is unchanged): {gate.message}'))
    position = solution.position
    x, y, z = position.t * 1e3
    angles = ', '.join(f'{math.degrees(a):.3f}' for a in rpy_from_matrix(solution.R_flange_tool))
    return TcpOutcome(record, run, bool(activation), ErrorCode.SUCCESS, (
        f'{record.id}: TCP of {tool} x {x:.3f} y {y:.3f} z {z:.3f} mm, rpy ({angles}) deg '
        f'({solution.method}); {len(position.residuals)} approaches, residual mean '
        f'{position.mean_residual_m * 1e3:.3f} mm, max {position.max_residual_m * 1e3:.3f} mm;'
        f' {time.monotonic() - t_start:.1f} s' + (f'; {prerequisites}' if prerequisites
                                                  else '')))


def calibrate_tcp(node, goal, timeout: float = TCP_TIMEOUT, feedback=None, executor=None):
    """Run calibrate_tcp with ``goal`` (CalibrateTcp.Goal) to its end; the result (CallError
    if the action is missing or does not finish in time; a failed calibration comes back with
    its error_code)."""
    from cobot_calib_msgs.action import CalibrateTcp
    from cobot_calib_ros.ros.calls import run_action_once
    return run_action_once(node, CalibrateTcp, 'calibrate_tcp', goal, timeout, feedback,
                           executor)
