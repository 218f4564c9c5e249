"""Quick health checks on the simulated Sawyer cell, in-process (issue 19 must-show 3):
``check user-frame`` (3 touches against the active frame, core.health_checks) against a 5-point
calibration, robot time as mock_robot reports it (moves at its joint velocity, holds).

- ``check_user_frame_robot_s`` [s]: robot time of one check (mean of CHECKS);
- ``check_user_frame_calibration_robot_s`` [s]: robot time of the calibration it replaces;
- ``check_user_frame_wrong_verdicts`` [count]: verdicts that disagree with the ground truth
  over CHECKS checks with the table in place (pass) and CHECKS after a 0.3 mm move in a
  random direction (recalibrate).

``check kinematics`` (16 sphere poses, the spread of the centres the model predicts) on the
simulated iiwa7:

- ``check_kinematics_robot_s`` [s]: robot time of one check;
- ``check_kinematics_true_model_spread_mm`` / ``_nominal_model_spread_mm`` [mm]: the spread
  with the true model (passes) and with the nominal one (recalibrate);
- ``check_kinematics_wrong_verdicts`` [count]: over KIN_CHECKS checks with each model.
"""
from __future__ import annotations

import sys

import numpy as np

import benchlib
from benchlib import Figures

from cobot_calib_ros.core.health_checks import (check_user_frame, PASS, predicted_points,
                                                RECALIBRATE)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import calibrate_user_frame, moved_table
from cobot_calib_ros.store.records import UserFrameRecord

CHECKS = 30
KIN_CHECKS = 5
POINTS = ['P1', 'P3', 'P5']


def run() -> Figures:
    sim = load_simulation(cell_file())
    rng = np.random.default_rng(3)
    p_user = np.array([sim.cell.marker(n).nominal_top for n in POINTS])
    seconds, calibration_seconds, wrong = [], [], 0
    for k in range(CHECKS):
        calibration = calibrate_user_frame(sim, 100 + k)
        calibration_seconds.append(calibration.robot_seconds)
        record = UserFrameRecord.from_fit(calibration.fit, None, calibration.names,
                                          calibration.p_user, calibration.p_base,
                                          ('base', 'user'), k).to_dict()
        predicted = predicted_points(record['inputs'], record['result'], POINTS, p_user)
        direction = rng.normal(size=3)
        for world, truth in ((sim, PASS), (moved_table(sim, 3e-4 * direction /
                                                       np.linalg.norm(direction)),
                                           RECALIBRATE)):
            arm = SimRobot(world, seed_offset=500 + k)
            check = check_user_frame(DirectRobot(arm, world.probe),
                                     arm.model.chain(tool=sim.cell.T_flange_tool), predicted,
                                     POINTS)
            seconds.append(check.robot_seconds)
            wrong += check.verdict != truth
    return {**_kinematics(), 'check_user_frame_robot_s': (float(np.mean(seconds)), 's'),
            'check_user_frame_calibration_robot_s': (float(np.mean(calibration_seconds)), 's'),
            'check_user_frame_wrong_verdicts': (wrong, 'count'),
            'check_user_frame_checks': (2 * CHECKS, 'count')}


def _kinematics() -> Figures:
    from cobot_calib_ros.core import kinematics
    from cobot_calib_ros.core.health_checks import check_kinematics, KINEMATIC_POSES
    from cobot_calib_ros.core.kinematics import plans
    sim = load_simulation(cell_file('iiwa7_close'))
    model = kinematics.model_by_name(sim.cell.robot)
    plan, _ = plans.sphere_plan(sim.cell, model, KINEMATIC_POSES)
    nominal = model.chain(tool=sim.cell.spheres.T_flange_coupling)
    seconds, spreads, wrong = [], {'true': [], 'nominal': []}, 0
    for k in range(KIN_CHECKS):
        for name, truth in (('true', PASS), ('nominal', RECALIBRATE)):
            arm = SimRobot(sim, seed_offset=700 + k)
            check = check_kinematics(DirectRobot(arm, sim.probe),
                                     arm.coupling if name == 'true' else nominal, plan)
            seconds.append(check.robot_seconds)
            spreads[name].append(check.spread_rms_m * 1e3)
            wrong += check.verdict != truth
    return {'check_kinematics_robot_s': (float(np.mean(seconds)), 's'),
            'check_kinematics_true_model_spread_mm': (float(np.mean(spreads['true'])), 'mm'),
            'check_kinematics_nominal_model_spread_mm': (float(np.mean(spreads['nominal'])),
                                                         'mm'),
            'check_kinematics_wrong_verdicts': (wrong, 'count'),
            'check_kinematics_checks': (2 * KIN_CHECKS, 'count')}


if __name__ == '__main__':
    sys.exit(benchlib.main(run))
