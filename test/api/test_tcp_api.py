"""api.tcp.calibrate_and_store in-process over the simulation (sim.robot.DirectRobot, a folder
repository): the procedure tcp_calibrator runs, scored against the mock's TRUE tool (the cell's
nominal one is 0.25 mm / 3.6 mrad off), stored with what it was measured through and made
active; its refusals (approaches too alike, an unknown point, a cancel, a result the gate
refuses) as Failures with their causes, nothing moved or stored where it says so."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.api.tcp import calibrate_and_store
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics import model_for
from cobot_calib_ros.core.tcp.procedure import TcpRequest
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import rig_of

SIM = load_simulation(cell_file('sawyer_close'))
MODEL = model_for(SIM.cell)
TOOL = SIM.cell.tool_frame
# Through the exact kinematics only the touch noise (0.05 mm per axis) is left: the TCP is
# bounded by 3 standard deviations of its own covariance, and the tool z by 3 sigma of one
# elongator touch 0.1 m up the axis (sqrt(2) 0.05 mm / 0.1 m = 0.7 mrad): 2.1 mrad. The
# nominal tool is 0.25 mm / 3.6 mrad off the truth, outside both.
ELONGATION_M = 0.1
MAX_Z_ERROR_RAD = 2.1e-3


def _repo(tmp_path, exact: bool = True):
    repo = store.open(tmp_path, cell=ResultsCell.of(SIM.cell))
    if exact:
        assert repo.kinematics.save_and_activate({
            'id': 'k-true', 'robot': MODEL.name, 'stamp_ns': 1, 'method': 'test', 'inputs': {},
            'result': {'parameter_names': list(MODEL.parameter_names),
                       'params': SIM.true_parameters(MODEL).tolist()}})
    return repo


def _robot(seed: int = 7):
    return DirectRobot(SimRobot(SIM, seed_offset=seed), SIM.probe)


def _calibrate(repo, request, robot=None, **kwargs):
    robot = robot or _robot()
    rig = rig_of(repo, SIM.cell, 'latest', MODEL)
    return calibrate_and_store(request, robot, rig, repo, TOOL, 1, **kwargs), robot


def test_the_tcp_found_is_the_mocks_true_tool_stored_and_active(tmp_path):
    repo = _repo(tmp_path)
    seen = []
    outcome, robot = _calibrate(repo, TcpRequest('P1', 6, method='z', hold=0.05,
                                                 elongation=ELONGATION_M),
                                progress=lambda i, total, rms: seen.append((i, total, rms)))
    assert outcome and outcome.code == ErrorCode.SUCCESS, outcome.message
    T, truth = outcome.run.solution.T_flange_tool, SIM.T_flange_tool_true
    error = np.linalg.norm(T[:3, 3] - truth[:3, 3])
    z_error = math.acos(min(1.0, T[:3, 2] @ truth[:3, 2]))
    nominal_error = np.linalg.norm(SIM.cell.T_flange_tool[:3, 3] - truth[:3, 3])
    std = math.sqrt(np.trace(outcome.run.solution.position.covariance[:3, :3]))
    print(f'TCP error {error * 1e3:.4f} mm (1 sigma {std * 1e3:.4f} mm, nominal '
          f'{nominal_error * 1e3:.3f} mm), z {z_error * 1e3:.3f} mrad; {outcome.message}')
    assert error < 3 * std < nominal_error and z_error < MAX_Z_ERROR_RAD
    assert [s[:2] for s in seen] == [(i, 7) for i in range(7)] and robot.moves == 7
    assert seen[2][2] == 0.0 and 0.0 < seen[-1][2] < 1e-4           # RMS [m] from the 4th
    active = repo.tcp.active(TOOL)
    assert outcome.active and active['id'] == outcome.record.id
    assert active['measured_through'] == {'kinematics': 'k-true'}
    assert active['method'] == 'tcp-6-point-z' and active['kinematics'] == 'k-true'
    position = outcome.run.solution.position
    assert active['result']['mean_residual_mm'] == pytest.approx(position.mean_residual_m * 1e3)
    assert 0.0 < position.mean_residual_m <= position.max_residual_m < 0.3e-3
    assert outcome.message.startswith(f'{outcome.record.id}: TCP of {TOOL} x ')


def test_approaches_too_alike_and_an_unknown_point_are_refused_before_anything_moves(tmp_path):
    repo = _repo(tmp_path, exact=False)
    alike, robot = _calibrate(repo, TcpRequest('P1', 4, tilt=math.radians(6.0)))
    assert not alike and alike.code == ErrorCode.DEGENERATE_POINTS
    assert alike.message.startswith('planned the approaches are too alike')
    assert 'approaches 1 and 2 differ by 6.0 deg' in alike.message and robot.moves == 0
    unknown, robot = _calibrate(repo, TcpRequest('P9'))
    assert unknown.code == ErrorCode.INVALID_INPUT and "unknown point 'P9'" in unknown.message
    assert robot.moves == 0 and not repo.tcp.ids()


def test_a_cancel_between_touches_stores_nothing(tmp_path):
    repo = _repo(tmp_path, exact=False)
    seen = []
    cancelled, robot = _calibrate(repo, TcpRequest('P1', 8, hold=0.05),
                                  cancelled=lambda: len(seen) >= 2,
                                  progress=lambda *a: seen.append(a))
    assert cancelled.code == ErrorCode.CANCELED
    assert cancelled.message == 'cancelled at touch 3 of 8 (approach 3); nothing stored'
    assert robot.moves == 2 and not repo.tcp.ids()


def test_a_result_its_noise_does_not_explain_is_stored_as_rejected_not_active(tmp_path):
    """A touch noise of 1 um claimed: the ~0.1 mm residuals through the nominal kinematics
    are beyond it; the result is kept, rejected, and the goal says so."""
    repo = _repo(tmp_path, exact=False)
    outcome, _ = _calibrate(repo, TcpRequest('P1', 6, hold=0.05, touch_sigma=1e-6))
    assert outcome and outcome.code == ErrorCode.IMPLAUSIBLE_FIT and not outcome.active
    assert 'rejected, stored as rejected and not made active' in outcome.message
    assert 'more than the touch noise' in outcome.message
    assert repo.tcp.active(TOOL) is None
    assert repo.tcp.rejected()[outcome.record.id] == outcome.record.gate_problem


def test_the_record_names_the_nominal_kinematics_when_none_is_active(tmp_path):
    repo = _repo(tmp_path, exact=False)
    warned = []
    outcome, _ = _calibrate(repo, TcpRequest('P1', 5, hold=0.05), warn=warned.append)
    assert outcome, outcome.message
    assert repo.tcp.get(outcome.record.id)['measured_through'] == {'kinematics': 'nominal'}
    assert warned and 'measured through the nominal kinematics' in warned[0]
    assert outcome.message.endswith(warned[0])
    assert frames.transform_error(outcome.run.solution.T_flange_tool,
                                  SIM.T_flange_tool_true)[0] < 0.3e-3
