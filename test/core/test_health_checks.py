"""check_user_frame (core.health_checks) in-process on the simulated Sawyer cell: its verdict
against the ground truth (the table moved 0.3 mm or not since the calibration), its robot
time, and its record stored as a result (issue 19 must-show 3, user-frame half)."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core.health_checks import (check_user_frame, PASS, predicted_points,
                                                RECALIBRATE)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import calibrate_user_frame, moved_table
from cobot_calib_ros.store.records import UserFrameRecord

SIM = load_simulation(cell_file('sawyer_close'))
CHECKED = ['P1', 'P3', 'P5']


def _calibration():
    run = calibrate_user_frame(SIM, 7)
    return UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                    ('base', 'user'), 1).to_dict()


def _check(sim, record, seed):
    arm = SimRobot(sim, seed_offset=seed)
    robot = DirectRobot(arm, sim.probe)
    p_user = np.array([SIM.cell.marker(n).nominal_top for n in CHECKED])
    predicted = predicted_points(record['inputs'], record['result'], CHECKED, p_user)
    return check_user_frame(robot, arm.model.chain(tool=SIM.cell.T_flange_tool), predicted,
                            CHECKED)


@pytest.mark.parametrize('offset_mm, truth', [
    ((0, 0, 0), PASS), ((0.3, 0, 0), RECALIBRATE), ((0, 0.3, 0), RECALIBRATE),
    ((0, 0, 0.3), RECALIBRATE), ((0, 0, 0.1), PASS)])
def test_the_verdict_agrees_with_the_ground_truth(offset_mm, truth):
    record = _calibration()
    sim = moved_table(SIM, np.array(offset_mm) * 1e-3)
    verdicts = [_check(sim, record, 50 + k).verdict for k in range(10)]
    assert verdicts == [truth] * 10
    check = _check(sim, record, 60)
    assert np.linalg.norm(check.mean_error) * 1e3 == pytest.approx(
        np.linalg.norm(offset_mm), abs=0.08)


def test_the_check_takes_a_fraction_of_the_robot_time_of_a_calibration():
    record = _calibration()
    check = _check(SIM, record, 3)
    calibration = calibrate_user_frame(SIM, 3)
    assert 0 < check.robot_seconds < 0.7 * calibration.robot_seconds
    assert check.robot_seconds < 60.0


def test_a_check_is_stored_as_a_result_of_the_cell(tmp_path):
    record = _calibration()
    check = _check(moved_table(SIM, [3e-4, 0, 0]), record, 5)
    repo = store.open(tmp_path, f'sqlite:///{tmp_path / "c.sqlite"}', 'cell_07')
    from cobot_calib_ros.store.records import check_record
    repo.checks.save(check_record(check, 'user_frame', record['id'], stamp_ns=5))
    stored, = store.open(tmp_path, f'sqlite:///{tmp_path / "c.sqlite"}', 'cell_07'
                         ).checks.history()
    assert stored['method'] == 'user_frame' and stored['result']['verdict'] == RECALIBRATE
    assert stored['inputs']['against'] == record['id']
    assert stored['result']['robot_seconds'] == pytest.approx(check.robot_seconds)
    assert np.allclose(stored['result']['errors'], check.errors)


def test_check_kinematics_tells_a_right_model_from_a_stale_one():
    """Must-show 3, kinematic half, on the simulated iiwa7: the true model (what a good
    identification finds) passes, the nominal one (the robot's real errors unmodelled) fails;
    16 poses take far less robot time than the 120 s goal."""
    from cobot_calib_ros.core import kinematics
    from cobot_calib_ros.core.health_checks import check_kinematics, sphere_spread
    from cobot_calib_ros.core.kinematics import plans
    sim = load_simulation(cell_file('iiwa7_close'))
    model = kinematics.model_by_name(sim.cell.robot)
    plan, _ = plans.sphere_plan(sim.cell, model, 16)
    arm = SimRobot(sim, seed_offset=3)
    robot = DirectRobot(arm, sim.probe)
    check = check_kinematics(robot, arm.coupling, plan)          # the true model
    assert check.verdict == PASS and check.spread_rms_m < 0.02e-3
    assert (check.poses, check.spheres) == (16, 3) and 0 < check.robot_seconds < 120.0
    nominal = model.chain(tool=sim.cell.spheres.T_flange_coupling)
    again = check_kinematics(DirectRobot(SimRobot(sim, seed_offset=4), sim.probe), nominal, plan)
    assert again.verdict == RECALIBRATE and again.spread_rms_m > 0.15e-3
    # the spread itself: the same pose twice on one sphere is no spread
    assert sphere_spread(nominal, [plan[0]['q']] * 2, [0, 0]) == 0.0
