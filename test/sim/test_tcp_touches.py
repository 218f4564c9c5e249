"""The simulated operator's oriented touches and the TCP procedure on the simulated cell
(in-process, no ROS): the mock's true tool differs from the cell's nominal one, and the
calibration finds the true one."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.robot_port import Approach, elongator_problem, MoveFailed
from cobot_calib_ros.core.tcp import gate_problem, GateLimits
from cobot_calib_ros.core.tcp.touches import plan_touches, solve_touches, take_touches
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

SIM = load_simulation(cell_file('sawyer_close'))


def _robot(seed: int = 5):
    arm = SimRobot(SIM, seed_offset=seed)
    return arm, DirectRobot(arm, SIM.probe)


def test_the_mock_tool_is_off_the_nominal_one_by_a_realistic_error():
    distance, angle = frames.transform_error(SIM.T_flange_tool_true, SIM.cell.T_flange_tool)
    assert 1e-4 < distance < 1e-3 and 1e-3 < angle < 1e-2


def test_an_oriented_touch_puts_the_true_tip_on_the_point_in_that_orientation():
    arm, robot = _robot()
    R = frames.rot_y(0.4) @ np.diag([1.0, -1.0, -1.0])
    robot.touch('P1', Approach(R))
    top = frames.apply(SIM.world.T_base_user, SIM.world.marker('P1').true_top)
    true_tool = arm.true_tool()
    assert np.linalg.norm(true_tool[:3, 3] - top) < 5 * SIM.noise.touch_sigma + 5 * \
        SIM.repeatability_sigma_at(top)
    assert frames.rotation_angle(true_tool[:3, :3].T @ R) < 1e-9
    robot.touch('P1', Approach(R, 'z', -0.05))
    lifted = arm.true_tool()[:3, 3] - top
    assert lifted @ R[:, 2] == pytest.approx(-0.05, abs=2e-4)
    assert np.linalg.norm(np.cross(lifted, R[:, 2])) < 2e-4


def test_an_elongator_point_is_an_axis_and_a_distance_or_refused_saying_why():
    assert elongator_problem('', 0.0) is None and elongator_problem('z', -0.05) is None
    assert elongator_problem('x', 0.05) is None
    assert "use 'z' or 'x'" in elongator_problem('y', 0.05).message
    assert 'within 1 m' in elongator_problem('z', 2.5).message
    assert 'within 1 m' in elongator_problem('z', 0.0).message
    assert 'within 1 m' in elongator_problem('z', float('nan')).message
    assert 'without an elongator axis' in elongator_problem('', 0.05).message
    assert elongator_problem('y', 0.05).code == ErrorCode.INVALID_INPUT

def test_an_unreachable_approach_fails_as_a_move():
    _, robot = _robot()
    with pytest.raises(MoveFailed, match="unknown point 'P9'"):
        robot.touch('P9', Approach(np.eye(3)))


def test_the_procedure_finds_the_true_tool_where_the_nominal_one_is_off():
    """8 approaches tilted 30 deg and a z elongator, measured through an exact kinematic
    calibration (the mock's true arm): the TCP lands within a few hundredths of a millimetre
    of the mock's true one (the nominal is 0.25 mm / 3.6 mrad off). Through the nominal
    kinematics the arm's own errors add ~0.15 mm (bench/bench_tcp.py)."""
    arm, robot = _robot()
    plan = plan_touches('P1', 8, 0.52, method='z')
    touches = take_touches(plan, robot, arm.model.chain(arm.true_parameters), hold=0.1)
    assert touches.labels[-1] == 'z elongator' and touches.approaches == 8
    solution = solve_touches(plan, touches)
    truth = SIM.T_flange_tool_true
    error = np.linalg.norm(solution.position.t - truth[:3, 3])
    nominal_error = np.linalg.norm(SIM.cell.T_flange_tool[:3, 3] - truth[:3, 3])
    z_error = math.acos(min(1.0, solution.R_flange_tool[:, 2] @ truth[:3, 2]))
    print(f'TCP error {error * 1e3:.4f} mm (nominal {nominal_error * 1e3:.3f} mm), '
          f'z {z_error * 1e3:.3f} mrad; residual mean '
          f'{solution.position.mean_residual_m * 1e3:.4f} max '
          f'{solution.position.max_residual_m * 1e3:.4f} mm')
    nominal_z_error = frames.rotation_angle(SIM.cell.T_flange_tool[:3, :3].T @ truth[:3, :3])
    assert error < 0.25 * nominal_error
    assert z_error < 0.5 * nominal_z_error
    assert gate_problem(solution, GateLimits(), nominal=SIM.cell.T_flange_tool) is None
    assert robot.moves == 9
