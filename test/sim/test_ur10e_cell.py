"""The UR10e cell (config/cells/ur10e_close.yaml, a robot named by its URDF): noise-free sphere
data from the mock robot recover its true joint-origin errors held out, through the measurement
path (3-fold) and the sphere identification `identify --cell ur10e_close` runs."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobot_calib_ros.core.kinematics import fk, model_for, plans
from cobot_calib_ros.core.kinematics.identification import absolute_errors, SphereObservations
from cobot_calib_ros.core.kinematics.plans import uniform_configurations
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.measurements import Measurements
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

TOLERANCE_MM = 1e-6


@pytest.fixture(scope='module')
def scene():
    """60 sphere poses of the cell's plan, the coupling exactly on the true spheres."""
    sim = load_simulation(cell_file('ur10e_close'))
    sim = dataclasses.replace(sim, spheres=dataclasses.replace(sim.spheres,
                                                               compliance_sigma=0.0))
    robot, model = SimRobot(sim), model_for(sim.cell)
    steps, skipped = plans.sphere_plan(sim.cell, model, 60)
    assert not skipped
    q = np.array([robot.plan_compliant(np.array(s['q'])) for s in steps])
    return sim, robot, model, q, np.array([s['target'] for s in steps])


def test_the_cell_is_the_ur10e_urdf(scene):
    sim, robot, model, _, _ = scene
    assert (sim.cell.name, model.name, model.kind) == ('ur10e_close', 'ur10e', 'origin')
    assert model.joint_names[0] == 'shoulder_pan_joint' and len(model.joint_names) == 6
    off = dict(zip(model.parameter_names, robot.true_parameters - model.nominal))
    assert off['x_elbow_joint'] == pytest.approx(3.0e-4, abs=1e-4)   # the cell's explicit errors


def test_noise_free_mock_data_recover_the_true_joint_origins_held_out(scene):
    sim, _, model, q, target = scene
    spheres = sim.cell.spheres
    data = Measurements('spheres', q, target, distances=spheres.known_distances(),
                        ball=spheres.T_flange_coupling[:3, 3])
    cv = mf.cross_validate(mf.ErrorModel(model, 'full'), data, mf.kfold(len(data), 3))
    assert cv.nominal['max_mm'] > 0.05
    assert cv.calibrated['max_mm'] < TOLERANCE_MM


def test_the_sphere_identification_recovers_the_true_robot(scene):
    """CalibrationJob (what `identify --cell ur10e_close` runs on the suite) on the same data:
    the identified robot against the true one over 200 configurations of the whole joint
    space, after the best rigid registration (relative data fix no world frame)."""
    sim, robot, model, q, target = scene
    data = SphereObservations(q, target, sim.cell.spheres.known_distances())
    outcome = CalibrationJob(sim.cell, model, data, loss='linear').run()
    Q = uniform_configurations(model, 200, 9)
    p_true = fk(robot.coupling, Q)[:, :3, 3]
    errors = absolute_errors(model, outcome.result.params, outcome.result.p_flange_tool, Q, p_true)
    nominal = absolute_errors(model, model.nominal, spheres_tool(sim), Q, p_true)
    assert nominal.max() * 1e3 > 0.5
    assert errors.max() * 1e3 < TOLERANCE_MM


def spheres_tool(sim) -> np.ndarray:
    return sim.cell.spheres.T_flange_coupling[:3, 3]
