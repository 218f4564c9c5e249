"""core.tcp.touches: every touch of a TCP plan checked for the arm's reach before it moves
(issue 36 item 4), on the mock cells' true arms (sim.robot: the robot solves each touch through
the TRUE arm and tool, as an operator guides the real one)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode, Refusal
from cobot_calib_ros.core.robot_port import MoveFailed
from cobot_calib_ros.core.tcp.touches import (checked_plan, JOINT_MARGIN, plan_touches,
                                              reachable_plan, take_touches)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.tcp_run import calibrate_tcp

IIWA = load_simulation(cell_file('iiwa7_close'))


class CountingRobot(DirectRobot):
    touches = 0

    def touch(self, name, approach=None):
        self.touches += 1
        return super().touch(name, approach)


def _robot(sim, seed=0):
    arm = SimRobot(sim, seed_offset=seed)
    return arm, CountingRobot(arm, sim.probe)


def test_the_readme_default_plan_on_the_iiwa_fails_at_a_joint_limit_unchecked():
    """The cause the check removes: the default six approaches of P1 as planned put the iiwa's
    elbow (joint_a4) at its limit on a later touch, after the arm has moved."""
    arm, robot = _robot(IIWA)
    plan = plan_touches('P1', 6)
    with pytest.raises(MoveFailed, match='joint_a4'):
        take_touches(plan, robot, arm.model.chain(), 0.05)
    assert robot.touches >= 2


@pytest.mark.parametrize('cell', ['sawyer_close', 'iiwa7_close', 'ur10e_close'])
def test_checked_touches_of_every_point_are_all_taken_and_give_the_true_tool(cell):
    """From where the first touch finds the point (no user frame yet: the first day), the
    remaining approaches are chosen reachable; every touch lands and the TCP through the true
    kinematics is the mock's true tool."""
    sim = load_simulation(cell_file(cell))
    for point in sim.cell.point_names:
        result = calibrate_tcp(sim, 3, 6, method='z', exact_kinematics=True, point=point)
        error = result.solution.position.t - sim.T_flange_tool_true[:3, 3]
        assert np.linalg.norm(error) < 0.1e-3, (cell, point, error)
        assert len(result.touches.joints) == 7


def test_a_plan_with_the_point_known_is_checked_before_the_arm_moves():
    """The point where the user frame puts it: each touch has joints within the limits and
    JOINT_MARGIN inside them; the robot then takes every one; an unreachable alternative is
    replaced by a tilt at another azimuth of the same size."""
    arm, robot = _robot(IIWA)
    chain = arm.model.chain(tool=IIWA.cell.T_flange_tool)
    p = frames.apply(IIWA.world.T_base_user, IIWA.cell.marker('P1').nominal_top)
    planned = plan_touches('P1', 6)
    plan, locate = checked_plan(planned, chain, IIWA.cell.home, point_base=p)
    assert locate is None
    changed = [not np.allclose(a, b) for a, b in zip(planned.orientations, plan.orientations)]
    assert any(changed) and not changed[0]
    R0 = plan.orientations[0]
    for R in plan.orientations[1:]:      # every approach still tilted by 30 deg
        tilt = math.acos(np.clip(R[:, 2] @ R0[:, 2], -1.0, 1.0))
        assert tilt == pytest.approx(0.52, abs=1e-9)
    take_touches(plan, robot, arm.model.chain(), 0.05)
    assert robot.touches == 6


def test_a_point_out_of_reach_is_refused_before_any_motion_naming_the_touch_and_limit():
    arm, robot = _robot(IIWA)
    chain = arm.model.chain(tool=IIWA.cell.T_flange_tool)
    far = np.array([1.5, 0.0, 0.2])
    with pytest.raises(Refusal, match=r'approach 1: .*no convergence.*nothing moved') as e:
        checked_plan(plan_touches('P1', 6), chain, IIWA.cell.home, point_base=far)
    assert e.value.failure.code == ErrorCode.MOTION_FAILED
    assert robot.touches == 0


def test_a_touch_closer_than_the_margin_to_a_joint_limit_is_named():
    """The margin keeps the real arm's solution inside the limits; the refusal names the
    joint, its angle and its limits."""
    arm, _ = _robot(IIWA)
    chain = arm.model.chain()
    q = np.array(IIWA.cell.home)
    q[3] = chain.lower[3] + 0.5 * JOINT_MARGIN
    T = kinematics.fk(chain, q)
    plain = kinematics.solve_ik_with_restarts(chain, T, q, IIWA.cell.home)
    assert plain
    near = kinematics.solve_ik_with_restarts(chain, T, q, q, margin=JOINT_MARGIN)
    assert not near
    assert 'joint_a4' in near.message and 'limits -120.0 .. 120.0' in near.message


def test_touches_already_taken_are_kept():
    arm, _ = _robot(IIWA)
    chain = arm.model.chain(tool=IIWA.cell.T_flange_tool)
    planned = plan_touches('P1', 6)
    q = IIWA.cell.home
    p = kinematics.fk(chain, q)[:3, 3]
    first = planned.orientations[0] @ frames.rot_z(0.3)      # the operator's own first touch
    plan = reachable_plan(type(planned)('P1', (first, *planned.orientations[1:])), chain, p, q,
                          IIWA.cell.home, taken=1)
    assert np.allclose(plan.orientations[0], first)
