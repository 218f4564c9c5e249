"""Hand-eye error against the truth on the simulated Sawyer cell (the default cell),
in-process (no ROS), over SEEDS noise draws: the 12 views calibrate_hand_eye plans
(core.landmarks.hand_eye_views), taken over the sim's robot and camera ports (images rendered
at the arm's joints, the board detected and posed), solved (solve_hand_eye) and compared with
the simulation's true T_flange_optical. One run is one draw of the robot's noise; the
README's figures are this spread, not one run's.

- ``hand_eye_error_{min,median,p90,max}_{mm,mrad}``: translation / rotation error, the flange
  poses by the nominal kinematics (no kinematic calibration active);
- ``hand_eye_calibrated_error_{min,median,p90,max}_{mm,mrad}``: the same views, the flange
  poses by a kinematic calibration identified on the sim's sphere data (issue 36.3: the node
  solves through the active one);
- ``hand_eye_noise_ratio_max`` [1]: the largest residual / expected-from-noise ratio (the gate
  rejects above 3).
"""
from __future__ import annotations

import sys

import numpy as np

import benchlib
from benchlib import Figures

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.landmarks.hand_eye import check_noise, hand_eye_views, solve_hand_eye
from cobot_calib_ros.core.landmarks.hand_eye_capture import take_hand_eye_views
from cobot_calib_ros.core.rig import ActiveSet
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

SEEDS = 20
VIEWS = 12
# where the views are planned: the user frame a few mm and mrad off the truth, as the node
# test gives it (test/nodes/test_hand_eye_calibrator.py USER_FRAME)
T_BASE_USER = frames.from_xyz_rpy([0.352, -0.048, 0.0], [0.0, 0.0, 0.03])


def calibrated_chain(sim):
    """The flange chain of a kinematic calibration identified on the sim's sphere data (the
    product's default sphere plan, as `cobot-calib identify` stores it): what
    hand_eye_calibrator takes its flange poses from once one is active (store.rigs)."""
    from bench_identification import sphere_data
    from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
    from cobot_calib_ros.core.rig import Rig
    from cobot_calib_ros.store.records import KinematicRecord
    from cobot_calib_ros.store.rigs import kinematics_of
    robot = SimRobot(sim)
    outcome = CalibrationJob(robot.cell, robot.model, sphere_data(robot, robot.cell)).run()
    identified = kinematics_of(KinematicRecord.from_outcome(outcome).to_dict())
    return Rig(sim.cell, ActiveSet(identified), robot.model).chain('flange')


def run() -> Figures:
    sim = load_simulation(cell_file())
    model = kinematics.model_for(sim.cell)
    plan = hand_eye_views(sim.cell, model, VIEWS, 0, T_base_user=T_BASE_USER)
    chains = {'': model.chain(), 'calibrated_': calibrated_chain(sim)}
    errors = {prefix: ([], []) for prefix in chains}
    ratios = []
    for seed in range(SEEDS):
        arm = SimRobot(sim, seed_offset=seed)
        views = take_hand_eye_views(plan, DirectRobot(arm, sim.probe),
                                    DirectCamera(SimCamera(sim, arm), arm, boards=True),
                                    model.chain(), hold=0.1, landmark_timeout=5.0)
        for prefix, chain in chains.items():      # the same views through each kinematics
            flange = kinematics.fk(chain, np.array(views.joints))
            result = solve_hand_eye(flange, views.boards, covariances=views.covariances)
            distance, angle = frames.transform_error(result.T_flange_optical,
                                                     sim.camera.T_flange_optical)
            errors[prefix][0].append(distance * 1e3)
            errors[prefix][1].append(angle * 1e3)
            if not prefix:
                ratios.append(check_noise(result, views.covariances).ratio)
    figures: Figures = {}
    for prefix, (mm, mrad) in errors.items():
        for unit, values in (('mm', mm), ('mrad', mrad)):
            for name, value in (('min', np.min(values)), ('median', np.median(values)),
                                ('p90', np.percentile(values, 90)), ('max', np.max(values))):
                figures[f'hand_eye_{prefix}error_{name}_{unit}'] = (float(value), unit)
    figures['hand_eye_noise_ratio_max'] = (float(max(ratios)), '1')
    figures['hand_eye_seeds'] = (SEEDS, 'count')
    return figures


if __name__ == '__main__':
    sys.exit(benchlib.main(run))
