"""api.move: a target in the base or a user frame, for a tool, solved on the chosen model (no
ROS: what `cobot-calib move` sends to move_to)."""
from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.api import move
from cobot_calib_ros.core import rig
from cobot_calib_ros.core.frames import from_xyz_rpy, invert
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import kinematics_of

CELL = load_cell(cell_file('ur10e_close'))
MODEL = model_for(CELL)
PARAMS = MODEL.nominal + np.random.default_rng(5).choice([-1, 1], MODEL.nominal.size) * 4e-4
KINEMATIC = {'id': 'k-move', 'robot': MODEL.name, 'stamp_ns': 1, 'method': 'test', 'inputs': {},
             'result': {'parameter_names': list(MODEL.parameter_names),
                        'params': PARAMS.tolist(), 'p_flange_tool': [0.0, 0.0, 0.1]}}
T_BASE_USER = from_xyz_rpy([0.6, -0.2, 0.05], [0.0, 0.0, 0.4])
FRAME = {'id': 'uf-move', 'stamp_ns': 1, 'method': 'rigid', 'inputs': {},
         'result': {'T_base_user': T_BASE_USER.tolist()}}
Q = CELL.home + 0.1


@pytest.fixture
def repo(tmp_path):
    return store.open(tmp_path, cell=ResultsCell.of(CELL))


def test_the_active_calibration_and_a_user_frame_give_the_joints_that_reach_the_target(repo):
    calibrated = rig.Rig(CELL, rig.ActiveSet(kinematics_of(KINEMATIC)), MODEL).chain('tcp')
    T_base_tool = fk(calibrated, Q)
    T_user_tool = invert(T_BASE_USER) @ T_base_tool
    nominal = move.solve(CELL, repo, T_base_tool, Q)         # nothing stored: nominal
    assert nominal.kinematics == 'nominal' and nominal.user_frame == ''
    assert np.abs(nominal.q - Q).max() > 1e-5                 # the nominal model's answer
    repo.kinematics.save_and_activate(KINEMATIC)
    repo.user_frames.save_and_activate(FRAME)
    for frame_id in ('', 'uf-move'):                         # the active one, or by id
        solved = move.solve(CELL, repo, T_user_tool, Q, frame='user', frame_id=frame_id)
        assert solved.kinematics == 'k-move' and solved.user_frame == 'uf-move'
        assert_allclose(fk(calibrated, solved.q), T_base_tool, atol=1e-9)
        assert_allclose(solved.T_base_tool, T_base_tool, atol=1e-12)
    assert move.solve(CELL, repo, T_base_tool, Q, kinematics='nominal').kinematics == 'nominal'
    flange = move.solve(CELL, repo, fk(rig.Rig(CELL, rig.ActiveSet(kinematics_of(KINEMATIC)), MODEL).chain('flange'), Q),
                        Q, tool='flange')
    assert_allclose(fk(calibrated, flange.q), T_base_tool, atol=1e-9)


@pytest.mark.parametrize('options, words', [
    ({'frame': 'user'}, 'no active user frame in the results of cell ur10e_close'),
    ({'frame': 'user', 'frame_id': 'uf-none'}, "no user frame 'uf-none'"),
    ({'kinematics': 'k-none'}, "no kinematic calibration 'k-none'"),
    ({'tool': 'gripper'}, "unknown tool 'gripper'; use one of tcp, flange, camera, coupling"),
])
def test_a_choice_that_cannot_be_met_says_what_to_do(repo, options, words):
    with pytest.raises(ValueError, match=words):
        move.solve(CELL, repo, fk(MODEL.chain(tool=CELL.T_flange_tool), Q), Q, **options)


def test_an_unreachable_target_names_the_model(repo):
    with pytest.raises(ValueError, match='cannot be reached by the nominal model'):
        move.solve(CELL, repo, from_xyz_rpy([4.0, 0.0, 0.5], [0, 0, 0]), Q)


def _tcp(record_id: str, xyz, through: dict) -> dict:
    T = np.array(CELL.T_flange_tool, dtype=float)
    T[:3, 3] = xyz
    return {'id': record_id, 'stamp_ns': 1, 'method': 'tcp-4-point', 'tool': CELL.tool_frame,
            'inputs': {}, 'measured_through': through,
            'result': {'T_flange_tool': T.tolist(), 'orientation_method': 'none'}}


def test_move_uses_the_active_tcp_names_it_and_says_a_frame_touched_with_another_is_stale(repo):
    """Issue 36 items 1 and 2: the TCP of the active set is the tool move solves for (the JSON
    names its record); a user frame touched with an older TCP is reported stale, with both
    ids and the TCPs' distance at the tool."""
    tip = np.array(CELL.T_flange_tool)[:3, 3]
    repo.tcp.save_and_activate(_tcp('tcp-old', tip + [2e-4, 0, 0], {'kinematics': 'nominal'}))
    repo.user_frames.save_and_activate({**FRAME, 'measured_through': {'kinematics': 'nominal',
                                                                      'tcp': 'tcp-old'}})
    T_user_tool = from_xyz_rpy([0.1, 0.05, 0.2], [np.pi, 0.0, 0.3])
    solved = move.solve(CELL, repo, T_user_tool, Q, frame='user')
    assert solved.tool_record == 'tcp-old' and solved.stale == ()
    repo.tcp.save_and_activate(_tcp('tcp-new', tip + [2e-4, 0, 1e-4], {'kinematics': 'nominal'}))
    solved = move.solve(CELL, repo, T_user_tool, Q, frame='user')
    assert solved.summary()['tool_record'] == 'tcp-new'
    new_tool = np.array(CELL.T_flange_tool)
    new_tool[:3, 3] = tip + [2e-4, 0, 1e-4]
    assert_allclose(fk(MODEL.chain(tool=new_tool), solved.q), T_BASE_USER @ T_user_tool,
                    atol=1e-9)
    (stale,) = solved.stale
    assert (stale.kind, stale.id, stale.through, stale.was, stale.now) == (
        'user_frame', 'uf-move', 'tcp', 'tcp-old', 'tcp-new')
    assert stale.change_mm == pytest.approx(0.1, abs=1e-9)
    assert stale.line() == ('user frame uf-move was touched with TCP tcp-old; the active TCP '
                            'tcp-new is 0.100 mm away at the tool: touch the frame again, or '
                            'keep it')
    assert move.solve(CELL, repo, T_user_tool, Q, frame='user', tool='flange').stale == (
        stale,)                              # the frame is used whatever the tool
    assert move.solve(CELL, repo, np.eye(4) @ fk(MODEL.chain(tool=new_tool), Q), Q).stale == ()


def test_move_names_what_the_calibration_could_not_see_and_how_far_a_target_is(repo):
    """issue 37: the unseen parameters of the calibration the tool goes through, and a target
    beyond reach by its distance."""
    unseen = {'name': 'yaw_wrist_3_joint', 'affects': 'tool',
              'reason': 'one point on the tool cannot see it'}
    repo.kinematics.save_and_activate({**KINEMATIC, 'unseen': [unseen]})
    solved = move.solve(CELL, repo, fk(MODEL.chain(PARAMS, tool=CELL.T_flange_tool), Q), Q)
    assert solved.note == ('k-move: not seen by the measurement, kept nominal: '
                           'yaw_wrist_3_joint (one point on the tool cannot see it)')
    with pytest.raises(ValueError, match=r"cannot be reached by the k-move model: 5.003 m from "
                                         r"the first joint, 3.455 m beyond the arm.s reach"):
        move.solve(CELL, repo, from_xyz_rpy([0.0, 5.0, 0.0], [0.0, 0.0, 0.0]), Q)
