"""The second paper's experiment in-process: the mock iiwa couples to the true spheres, the
core identifies, a simulated laser tracker validates (issue 10, must-show 2).

The true robot carries the deviations the paper identified (Table 6 minus nominal) plus small
random ones; the coupling self-centres within 3 um; joints carry encoder noise; the tracker
measures with 25 um per axis. Each model is registered to the tracker by its best rigid fit.
"""
import numpy as np
import pytest

from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.identification import (PositionObservations,
                                                            SphereObservations)
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

PAPER_RATIO = 0.990 / 2.381          # its max error, sphere calibration / nominal
PAPER_SPHERE_OVER_LASER = 0.990 / 0.932


@pytest.fixture(scope='module')
def cell():
    sim = load_simulation(cell_file('iiwa7_close'))
    robot = SimRobot(sim)
    plan, _ = plans.sphere_plan(sim.cell, robot.model, max_configs=600)
    q, sphere = [], []
    for step in plan:
        reached = robot.plan_compliant(np.array(step['q']))
        assert isinstance(reached, np.ndarray), reached
        robot.set_joints(reached)
        q.append(np.mean([robot.joint_reading() for _ in range(50)], axis=0))
        sphere.append(step['target'])
    spheres = SphereObservations(np.array(q), np.array(sphere),
                                 sim.cell.spheres.known_distances())
    tracker = {}
    for region, count, seed in (('volume', 125, 0), ('workspace', 125, 1),
                                ('calibration', 284, 2)):
        steps = plans.tracker_plan(sim.cell, robot.model, 'workspace' if region ==
                                   'calibration' else region, count, seed)
        qs, ps = [], []
        for step in steps:
            robot.set_joints(np.array(step['q']))
            qs.append(robot.joint_reading())
            ps.append(robot.laser_measurement())
        tracker[region] = PositionObservations(np.array(qs), np.array(ps))
    return sim, robot, spheres, tracker


def test_sphere_calibration_cuts_the_max_error_in_the_calibrated_volume(cell):
    sim, robot, spheres, tracker = cell
    validation = {k: tracker[k] for k in ('volume', 'workspace')}
    sphere = CalibrationJob(sim.cell, robot.model, spheres, validation=validation).run()
    laser = CalibrationJob(sim.cell, robot.model, tracker['calibration'],
                           validation=validation).run()
    volume, workspace = sphere.validation['volume'], sphere.validation['workspace']
    ratio = volume['calibrated']['max_m'] / volume['nominal']['max_m']
    ratio_ws = workspace['calibrated']['max_m'] / workspace['nominal']['max_m']
    laser_ws = laser.validation['workspace']['calibrated']['max_m']
    print(f'\nvolume: nominal max {volume["nominal"]["max_m"] * 1e3:.3f} mm, sphere-calibrated '
          f'{volume["calibrated"]["max_m"] * 1e3:.3f} mm ({ratio:.1%}; goal <= 30 %)')
    print(f'workspace: nominal max {workspace["nominal"]["max_m"] * 1e3:.3f} mm, sphere '
          f'{workspace["calibrated"]["max_m"] * 1e3:.3f} mm ({ratio_ws:.1%}; paper '
          f'{PAPER_RATIO:.1%}), laser {laser_ws * 1e3:.3f} mm; sphere / laser '
          f'{workspace["calibrated"]["max_m"] / laser_ws:.2f} (paper '
          f'{PAPER_SPHERE_OVER_LASER:.2f})')
    assert 3e-4 < volume['nominal']['max_m'] and 1.5e-3 < workspace['nominal']['max_m'] < 4e-3
    assert ratio <= 0.30
    assert workspace['calibrated']['max_m'] <= 1.2 * laser_ws
    assert {'alpha_1', 'a_1', 'theta_1', 'd_1'} <= {d.name for d in
                                                   sphere.identifiability.dropped}


def test_identified_deviations_match_the_true_robot(cell):
    """The paper's big deviations (Table 6) come back to a few micrometres / microradians."""
    sim, robot, spheres, _ = cell
    outcome = CalibrationJob(sim.cell, robot.model, spheres).run()
    names = robot.model.parameter_names
    for name in ('d_3', 'd_5', 'alpha_3', 'alpha_4', 'alpha_6'):
        i = names.index(name)
        delta_true = robot.true_parameters[i] - robot.model.nominal[i]
        delta_found = outcome.result.params[i] - robot.model.nominal[i]
        assert abs(delta_found - delta_true) < 0.05 * abs(delta_true), name
