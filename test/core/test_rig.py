"""core.rig: the one answer to "which chain, with which tool", and targets in a user frame."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core import rig
from cobot_calib_ros.core.frames import from_xyz_rpy
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file

CELL = load_cell(cell_file('iiwa7_close'))
MODEL = model_for(CELL)
PARAMS = MODEL.nominal + np.random.default_rng(4).normal(0.0, 3e-4, MODEL.nominal.size)
RECORD = rig.Kinematics('k-rig', MODEL.name, tuple(MODEL.parameter_names), PARAMS,
                        np.array([0.001, -0.002, 0.103]))
Q = CELL.home + 0.1


def test_each_tool_ends_the_chain_where_the_cell_or_the_result_puts_it():
    flange = fk(rig.Rig(CELL, rig.ActiveSet(RECORD), MODEL).chain('flange'), Q)
    assert_allclose(flange, fk(MODEL.chain(PARAMS), Q), atol=1e-15)
    assert_allclose(fk(rig.Rig(CELL, rig.ActiveSet(RECORD), MODEL).chain('tcp'), Q),
                    flange @ CELL.T_flange_tool, atol=1e-12)
    coupling = fk(rig.Rig(CELL, rig.ActiveSet(RECORD), MODEL).chain('coupling'), Q)
    assert_allclose(coupling[:3, 3], flange[:3, :3] @ [0.001, -0.002, 0.103] + flange[:3, 3],
                    atol=1e-12)      # the identified centre
    assert_allclose(coupling[:3, :3], flange[:3, :3] @ CELL.spheres.T_flange_coupling[:3, :3],
                    atol=1e-12)      # the cell's orientation
    nominal = fk(rig.Rig(CELL, model=MODEL).chain('coupling'), Q)
    assert_allclose(nominal, fk(MODEL.chain(tool=CELL.spheres.T_flange_coupling), Q), atol=1e-12)
    hand_eye = rig.HandEye('h-0', from_xyz_rpy([0.05, 0, 0.02], [0, 0, 1]))
    assert_allclose(fk(rig.Rig(CELL, rig.ActiveSet(None, hand_eye), MODEL).chain('camera'), Q),
                    fk(MODEL.chain(), Q) @ from_xyz_rpy([0.05, 0, 0.02], [0, 0, 1]), atol=1e-12)


def test_a_tool_the_cell_lacks_or_does_not_know_is_refused_with_the_choices():
    with pytest.raises(ValueError, match='has no camera: section.*tcp, flange, camera, coupling'):
        rig.Rig(CELL, model=MODEL).chain('camera')
    with pytest.raises(ValueError, match="unknown tool 'gripper'"):
        rig.T_flange_tool(CELL, 'gripper')
    with pytest.raises(ValueError, match="is for robot 'sawyer', not 'iiwa7'"):
        rig.Rig(CELL, rig.ActiveSet(replace(RECORD, robot='sawyer')), MODEL)


def test_a_target_in_a_user_frame_is_solved_in_the_base():
    chain = rig.Rig(CELL, rig.ActiveSet(RECORD), MODEL).chain('tcp')
    T_base_user = from_xyz_rpy([0.5, -0.1, 0.02], [0.01, -0.02, 0.7])
    T_base_tool = fk(chain, Q + 0.05)
    result = rig.solve_target(chain, np.linalg.inv(T_base_user) @ T_base_tool, Q, CELL.home,
                              T_base_user)
    assert result
    assert_allclose(fk(chain, result.q), T_base_tool, atol=1e-9)


def test_the_tcp_is_the_active_tcp_records_else_the_cells():
    """Issue 30.3: a TCP record gives the tool's position, and its orientation only when it
    measured one (elongator points)."""
    assert_allclose(rig.T_flange_tool(CELL, 'tcp'), CELL.T_flange_tool, atol=0)
    T = from_xyz_rpy([0.0003, -0.0002, 0.1004], [0.003, -0.002, 0.01])
    position_only = rig.Tcp('tcp-0', 'tool0', from_xyz_rpy(T[:3, 3], [0, 0, 0]))
    expected = CELL.T_flange_tool.copy()
    expected[:3, 3] = T[:3, 3]
    assert_allclose(rig.T_flange_tool(CELL, 'tcp', tcp=position_only), expected, atol=1e-15)
    oriented = rig.Tcp('tcp-1', 'tool0', T, orientation_measured=True)
    assert_allclose(rig.T_flange_tool(CELL, 'tcp', tcp=oriented), T, atol=1e-15)
    assert_allclose(rig.T_flange_tool(CELL, 'flange', tcp=oriented), np.eye(4), atol=0)
    calibrated = rig.Rig(CELL, rig.ActiveSet(RECORD, tcp=oriented), MODEL)
    assert_allclose(fk(calibrated.chain('tcp'), Q), fk(MODEL.chain(PARAMS), Q) @ T, atol=1e-12)
    assert calibrated.active.tcp_label == 'tcp-1'
    assert rig.ActiveSet().tcp_label == 'nominal'


def test_the_nominal_chain_keeps_the_tool_and_the_labels_name_the_results():
    hand_eye = rig.HandEye('h-1', from_xyz_rpy([0.05, 0, 0.02], [0, 0, 1]))
    calibrated = rig.Rig(CELL, rig.ActiveSet(RECORD, hand_eye), MODEL)
    assert_allclose(fk(calibrated.nominal_chain('camera'), Q),
                    fk(MODEL.chain(), Q) @ from_xyz_rpy([0.05, 0, 0.02], [0, 0, 1]), atol=1e-12)
    assert (calibrated.active.kinematics_label, calibrated.active.hand_eye_label) == (
        'k-rig', 'h-1')
    nominal = calibrated.with_kinematics(None)
    assert nominal.active.kinematics_label == 'nominal' and nominal.active.hand_eye is hand_eye
    assert_allclose(fk(nominal.chain('tcp'), Q), fk(calibrated.nominal_chain('tcp'), Q),
                    atol=1e-15)


def test_no_node_verb_or_api_builds_a_chain_of_its_own():
    """Issue 29 item 4: "which chain, with which tool" is answered by the rig alone outside
    core (the sim's true robot and core's own math build theirs)."""
    import re
    from pathlib import Path
    import cobot_calib_ros
    root = Path(cobot_calib_ros.__file__).parent
    builders = re.compile(r'model\.chain\(|model_chain\(')
    found = [f'{path.relative_to(root)}: {line.strip()}'
             for package in ('nodes', 'cli', 'api', 'ros', 'store', 'bags', 'loaders')
             for path in sorted((root / package).rglob('*.py'))
             for line in path.read_text().splitlines()
             if builders.search(line)]
    assert found == [
        # the demo scores against the mock's true robot (its ground truth service), and
        # against its true arm with the model's tool (the arm's part of the error)
        "api/demo.py: true_arm = rig.model.chain(np.array(truth.true_parameters), "
        "tool=rig.tool('tcp'))",
        'api/demo.py: return model.chain(np.array(truth.true_parameters), tool=tool)']


def test_the_user_frame_is_the_active_sets_or_refused_naming_the_cell():
    T = from_xyz_rpy([0.5, -0.1, 0.02], [0.01, -0.02, 0.7])
    framed = rig.Rig(CELL, rig.ActiveSet(user_frame=rig.UserFrame('u-1', T)), MODEL)
    assert_allclose(framed.T_base_user(), T, atol=0)
    with pytest.raises(ValueError, match='no active user frame in the results of cell '
                                         'iiwa7_close; calibrate one first'):
        rig.Rig(CELL, model=MODEL).T_base_user()
