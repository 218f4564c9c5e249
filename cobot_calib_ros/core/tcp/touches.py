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

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
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
# The robot (or the operator) solves each touch through the real arm and tool, which differ
# from the planning chain by millimetres: a planned touch keeps its joints this far inside
# their limits, so the real one is inside them too.
JOINT_MARGIN = math.radians(1.0)
# Alternatives for an approach that cannot be reached, in order of preference: the azimuth of
# its tilt moved by these fractions of the spacing between approaches, and the tool turned
# about its own axis (which moves the wrist, not the flange) by these angles [rad].
AZIMUTH_SHIFTS = (0.0, 0.25, -0.25, 0.5, -0.5, 0.75, -0.75, 1.0, -1.0, 1.5, -1.5)
ROLLS = (0.0, math.pi / 2, -math.pi / 2, math.pi)


def unreachable(message: str) -> Refusal:
    """The refusal (MOTION_FAILED) of a planned pose the arm cannot take (inverse kinematics,
    joint limits), found before anything moves; the message names the pose and the limit."""
    return Refusal(Failure(ErrorCode.MOTION_FAILED, message))


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
    ValueError naming a goal that cannot work; a Refusal (DEGENERATE_POINTS, core.tcp.solve.
    too_alike) for approaches that would not determine the tool (a small tilt), before
    anything moves."""
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
    orientations = [R0] + [_tilted(R0, tilt, 2.0 * math.pi * k / (count - 1))
                           for k in range(count - 1)]
    check_determined(orientations)
    return TcpPlan(point, tuple(orientations),
                   tuple((axis, SIGNS[axis] * elongation) for axis in ELONGATOR_AXES[method]))


def _tilted(R0: Array, tilt: float, azimuth: float, roll: float = 0.0) -> Array:
    """``R0`` tilted by ``tilt`` [rad] about the horizontal axis at ``azimuth`` [rad], the tool
    turned by ``roll`` [rad] about its own z first."""
    axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    return Rotation.from_rotvec(tilt * axis).as_matrix() @ R0 @ frames.rot_z(roll)


def reachable_plan(plan: TcpPlan, chain: kinematics.Chain, point_base: ArrayLike,
                   q_start: ArrayLike, home: ArrayLike, tilt: float = DEFAULT_TILT,
                   margin: float = JOINT_MARGIN, taken: int = 0) -> TcpPlan:
    """``plan`` with every touch checked, in order, for an inverse kinematics solution of
    ``chain`` (the arm through the tool, as planned: nominal or calibrated) with the tip at
    ``point_base`` (3,) [m, base] (or the elongator point) and the joints ``margin`` [rad]
    inside their limits, each solved from the last (from ``q_start`` [rad], the arm's joints
    now), as the robot goes from touch to touch. A tilted approach that cannot be reached is
    replaced by the first of its alternatives that can (AZIMUTH_SHIFTS of its tilt's azimuth,
    ROLLS of the tool about its axis); the first approach and the elongator touches may only
    turn about the tool axis. A Refusal: MOTION_FAILED (:func:`unreachable`) naming the touch
    and the joint limit when one has no reachable alternative, DEGENERATE_POINTS when the
    alternatives left the plan undetermined: before anything moves. ``taken``: the first
    approaches already touched, kept as they are (``q_start``: the joints at the last of them)."""
    p = np.asarray(point_base, dtype=float)
    home = np.asarray(home, dtype=float)
    R0 = plan.orientations[0]
    count = len(plan.orientations)
    spacing = 2.0 * math.pi / max(count - 1, 1)
    q = np.asarray(q_start, dtype=float)
    chosen: list[Array] = list(plan.orientations[:taken])
    for i in range(taken, count):
        if i == 0:
            options = [R0 @ frames.rot_z(roll) for roll in ROLLS]
        else:
            azimuth = spacing * (i - 1)
            options = [_tilted(R0, tilt, azimuth + shift * spacing, roll)
                       for shift in AZIMUTH_SHIFTS for roll in ROLLS]
        R, q = _first_reachable(options, chain, p, q, home, margin, f'approach {i + 1}')
        chosen.append(R)
    for axis, d in plan.elongators:
        R, q = _first_reachable([chosen[0]], chain, p + d * chosen[0][:, 'xyz'.index(axis)], q,
                                home, margin, f'{axis} elongator')
    check_determined(chosen)
    return TcpPlan(plan.point, tuple(chosen), plan.elongators)


def checked_plan(plan: TcpPlan, chain: kinematics.Chain, home: ArrayLike,
                 tilt: float = DEFAULT_TILT, point_base: ArrayLike | None = None
                 ) -> tuple[TcpPlan, Callable[[TcpPlan, Array], TcpPlan] | None]:
    """How a TCP calibration checks its touches for the arm's reach (``chain``: the arm
    through the tool as known: the active kinematics and TCP, else nominal): with the point's
    position known (``point_base`` (3,) [m]: the active user frame's), (the plan checked by
    :func:`reachable_plan` before anything moves, None); else (``plan``, the ``locate`` of
    :func:`take_touches` that checks the rest from where the first touch, the operator's own
    straight-down approach, found the point). Refusals as reachable_plan."""
    home = np.asarray(home, dtype=float)
    if point_base is not None:
        return reachable_plan(plan, chain, point_base, home, home, tilt), None

    def locate(plan_: TcpPlan, q: Array) -> TcpPlan:
        tip = kinematics.fk(chain, q)[:3, 3]
        return reachable_plan(plan_, chain, tip, q, home, tilt, taken=1)
    return plan, locate


def _first_reachable(options: list[Array], chain: kinematics.Chain, p: Array, q: Array,
                     home: Array, margin: float, label: str) -> tuple[Array, Array]:
    """(orientation, joints [rad]) of the first of ``options`` whose tool pose at ``p`` the
    arm reaches; a Refusal (MOTION_FAILED) naming ``label`` and the first option's failure."""
    first = None
    for R in options:
        ik = kinematics.solve_ik_with_restarts(chain, frames.make_transform(R, p), q, home,
                                               margin)
        if ik:
            return R, np.asarray(ik.q, dtype=float)
        first = first or ik
    raise unreachable(
        f'{label}: no reachable tool orientation among {len(options)} tried (the planned one: '
        f'{first.message}); touch another point (--point) or give a smaller tilt; nothing moved')


@dataclass
class TcpTouches:
    """What the touches measured so far: joints and flange poses, in plan order."""

    labels: list[str] = field(default_factory=list)
    joints: list[Array] = field(default_factory=list)           # (n,) [rad]
    flange: list[Array] = field(default_factory=list)           # (4, 4) T_base_flange [m]
    approaches: int = 0


def take_touches(plan: TcpPlan, robot: RobotPort, chain: kinematics.Chain, hold: float,
                 cancelled: Cancelled = never,
                 on_touch: Callable[[int, TcpTouches], None] | None = None,
                 locate: Callable[[TcpPlan, Array], TcpPlan] | None = None) -> TcpTouches:
    """Touch every step of ``plan``, hold ``hold`` [s], capture the joints and take the flange
    pose by ``chain`` (a chain ending at the flange). ``locate``: for a point whose position
    was not known when planning, called once after the first touch with the plan and the
    joints [rad] there; the remaining touches follow the plan it returns (e.g.
    :func:`reachable_plan` from where the first touch found the point; its Refusal ends the
    run before the second touch). Stopped on a cancel between touches; MoveFailed /
    CaptureFailed from the robot as they come."""
    touches = TcpTouches()
    steps = plan.steps()
    for i in range(len(steps)):
        if i == 1 and locate is not None:
            plan = locate(plan, touches.joints[0])
            steps = plan.steps()
        label, approach = steps[i]
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
