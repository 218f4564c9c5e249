"""core.kinematics.kinematic_calibration.CalibrationJob: Nelder-Mead runs to convergence
unless told otherwise, and a solve that stopped early says so in the summary and the record
(issue 16.6), on sphere data collected in-process from the simulated Sawyer."""
import numpy as np
import pytest

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.collection import collect
from cobot_calib_ros.core.kinematics.identification import SphereObservations
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.measurement_fit import NM_CONVERGED
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.records import KinematicRecord

SIM = load_simulation(cell_file('sawyer_close'))
MODEL = kinematics.model_by_name(SIM.cell.robot)


@pytest.fixture(scope='module')
def data() -> SphereObservations:
    """30 sphere poses (10 per sphere) collected by Algorithm 2 on the simulated Sawyer."""
    steps, _ = plans.sphere_plan(SIM.cell, MODEL, 30)
    log = []
    collect(steps, 0, DirectRobot(SimRobot(SIM), SIM.probe), log.append, hold=0.02)
    return SphereObservations(np.array([r.q for r in log]), np.array([r.target for r in log]),
                              tuple(tuple(d) for d in SIM.cell.spheres.known_distances()))


def test_nelder_mead_runs_to_convergence_by_default(data, monkeypatch):
    seen = []
    real = mf._nelder_mead

    def spy(monitor, x0, lower, upper, options):
        seen.append(options)
        return real(monitor, x0, lower, upper, {**options, 'max_evaluations': 60})   # capped
    monkeypatch.setattr(mf, '_nelder_mead', spy)
    CalibrationJob(SIM.cell, MODEL, data, solver='nelder-mead').run()
    assert seen == [NM_CONVERGED]
    seen.clear()
    CalibrationJob(SIM.cell, MODEL, data).run()                      # LM: its own stopping
    assert not seen


def test_a_solve_stopped_by_its_cap_says_so_in_the_summary_and_the_record(data):
    capped = CalibrationJob(SIM.cell, MODEL, data, solver='nelder-mead',
                            solver_options={'max_evaluations': 60}).run()
    assert not capped.result.converged
    assert capped.summary().startswith('REFUSED: the solver did not converge (did not '
                                       'converge: Maximum number of function evaluations has '
                                       'been exceeded.): the model may be far from the optimum')
    assert not capped.verdict.passed
    assert KinematicRecord.from_outcome(capped).result.converged is False
    lm = CalibrationJob(SIM.cell, MODEL, data).run()
    assert lm.result.converged and KinematicRecord.from_outcome(lm).result.converged is True
    assert 'CONVERGED' not in lm.summary() and lm.verdict.passed
    assert capped.result.rms_m > 2 * lm.result.rms_m
