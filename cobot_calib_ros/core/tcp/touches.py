"""The TCP calibration's touches: which orientations, and the procedure over a RobotPort.

The plan: the first approach has the tool pointing down (the cell's touch orientation); the
others are tilted by ``tilt`` from it about horizontal axes spread evenly round the point, so
their rotations differ about different axes (the rank the position solve needs). With an
orientation method, elongator touches follow from the first approach's orientation: along the
tool's z the tip backs off up its own axis (distance -elongation: the point above the fixed one,
clear of the table), along x it moves sideways by +elongation.

The procedure (:func:`take_touches`) touches, holds, captures the joints and takes the flange
pose through the chain it is given (the active kinematics, ending at the flange): the same code
over ROS (tcp_calibrator, ros.robot_calls.RobotCalls) and in-process on the simulation
(bench/bench_tcp.py, sim.robot.DirectRobot).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.frames import Rotation
from cobot_calib_ros.core.robot_port import Approach, Cancelled, check_cancel, never, RobotPort
from cobot_calib_ros.core.tcp.solve import check_determined, solve_tcp, TcpSolution

Array = NDArray[np.float64]
DEFAULT_APPROACHES = 6
DEFAULT_TILT = 0.52           # [rad] (30 deg)
DEFAULT_ELONGATION = 0.05     # [m]
MAX_TILT = math.radians(60.0)
ELONGATOR_AXES = {'none': (), 'z': ('z',), 'zx': ('z', 'x')}
SIGNS = {'z': -1.0, 'x': 1.0}     # z: back up the tool's axis, clear of the table


@dataclass(frozen=True)
class TcpPlan:
    """The touches of one TCP calibration of ``point``."""

    point: str
    orientations: tuple[Array, ...]          # (3, 3) tool orientations in the base frame
    elongators: tuple[tuple[str, float], ...] = ()   # (axis, signed distance [m])

    def steps(self) -> list[tuple[str, Approach]]:
        """(label, approach) of every touch, approaches first."""
        steps = [(f'approach {i + 1}', Approach(R)) for i, R in enumerate(self.orientations)]
        steps += [(f'{axis} elongator', Approach(self.orientations[0], axis, d))
                  for axis, d in self.elongators]
        return steps


def plan_touches(point: str, count: int = DEFAULT_APPROACHES, tilt: float = DEFAULT_TILT,
                 R_reference: ArrayLike | None = None, method: str = 'none',
                 elongation: float = DEFAULT_ELONGATION) -> TcpPlan:
    """``count`` approaches of ``point`` (the first in ``R_reference``, default the tool
    pointing down the base z) and the elongator touches of ``method`` ('none', 'z', 'zx').
    ValueError naming a goal that cannot work; TooAlike (a ValueError) for approaches that
    would not determine the tool (a small tilt), before anything moves."""
    if not 4 <= count <= 32:
        raise ValueError(f'{count} approaches: give 4..32 (KUKA and ABB use 4, more average '
                         'the touch noise)')
    if not math.radians(5.0) <= tilt <= MAX_TILT:
        raise ValueError(f'tilt {math.degrees(tilt):.1f} deg: give 5..60 deg (>= 20 deg '
                         'determines the tool well)')
    if method not in ELONGATOR_AXES:
        raise ValueError(f'orientation method {method!r}: use one of {list(ELONGATOR_AXES)}')
    if method != 'none' and not 0.005 <= elongation <= 0.3:
        raise ValueError(f'elongation {elongation * 1e3:.1f} mm: give 5..300 mm')
    R0 = np.diag([1.0, -1.0, -1.0]) if R_reference is None else np.asarray(R_reference, float)
    orientations = [R0]
    for k in range(count - 1):
        azimuth = 2.0 * math.pi * k / (count - 1)
        axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
        orientations.append(Rotation.from_rotvec(tilt * axis).as_matrix() @ R0)
    check_determined(orientations)
    return TcpPlan(point, tuple(orientations),
                   tuple((axis, SIGNS[axis] * elongation) for axis in ELONGATOR_AXES[method]))


@dataclass
class TcpTouches:
    """What the touches measured so far: joints and flange poses, in plan order."""

    labels: list[str] = field(default_factory=list)
    joints: list[Array] = field(default_factory=list)           # (n,) [rad]
    flange: list[Array] = field(default_factory=list)           # (4, 4) T_base_flange [m]
    approaches: int = 0


def take_touches(plan: TcpPlan, robot: RobotPort, chain: kinematics.Chain, hold: float,
                 cancelled: Cancelled = never,
                 on_touch: Callable[[int, TcpTouches], None] | None = None) -> TcpTouches:
    """Touch every step of ``plan``, hold ``hold`` [s], capture the joints and take the flange
    pose by ``chain`` (a chain ending at the flange). Stopped on a cancel between touches;
    MoveFailed / CaptureFailed from the robot as they come."""
    touches = TcpTouches()
    steps = plan.steps()
    for i, (label, approach) in enumerate(steps):
        check_cancel(cancelled, f'touch {i + 1} of {len(steps)} ({label})')
        robot.touch(plan.point, approach)
        q = robot.capture(hold).q
        touches.labels.append(label)
        touches.joints.append(np.asarray(q, dtype=float))
        touches.flange.append(kinematics.fk(chain, q))
        touches.approaches += not approach.axis
        if on_touch is not None:
            on_touch(i, touches)
    return touches


def solve_touches(plan: TcpPlan, touches: TcpTouches,
                  robust_scale: float = 5e-5) -> TcpSolution:
    """The TCP of a completed plan's touches (core.tcp.solve.solve_tcp)."""
    n = touches.approaches
    elongators = {axis: (touches.flange[n + k], d)
                  for k, (axis, d) in enumerate(plan.elongators)}
    return solve_tcp(np.array(touches.flange[:n]), elongators, robust_scale)
