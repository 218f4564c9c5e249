"""`cobot-calib move` against the suite (mock_robot serves move_to as a controller with its
nominal kinematics): the suite solves the pose with the calibrated model and sends joints, so
the tool lands on the target by the mock's truth (issue 29.1)."""
import json

from cobot_calib_msgs.srv import GetGroundTruth
import numpy as np
from scipy.spatial.transform import Rotation

from cobot_calib_ros import store
from cobot_calib_ros.api import move
from cobot_calib_ros.core import rig
from cobot_calib_ros.core.frames import from_xyz_rpy
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import convert
from cobot_calib_ros.store.cells import ResultsCell
from rosutil import call, cli

CELL = load_cell(cell_file('sawyer_close'))
MODEL = model_for(CELL)


def _move(xyz, rpy, *extra):
    out = cli('move', '--xyz', *map(repr, xyz), '--rpy', *map(repr, rpy), '--robot-cell',
              'sawyer_close', '--json', *extra)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _exact_tcp(data, T_flange_tool) -> str:
    """Store and activate, in the results ``data``, what an exact TCP calibration of the
    cell's tool would: the mock's true tool (position and orientation)."""
    record = {'id': 'tcp-true', 'stamp_ns': 1, 'method': 'tcp-test', 'tool': CELL.tool_frame,
              'inputs': {}, 'measured_through': {'kinematics': 'k-true'},
              'result': {'T_flange_tool': T_flange_tool.tolist(), 'orientation_method': 'zx'}}
    assert store.open(data, cell=ResultsCell.of(CELL)).tcp.save_and_activate(record)
    return record['id']


def test_a_compensated_move_lands_on_the_target_where_the_nominal_one_is_off(ros, tmp_path):
    """The true tool tip (the mock's true arm AND its true tool, 0.25 mm / 3.6 mrad off the
    cell's nominal T_flange_tool) lands on the target when move uses an exact kinematic
    calibration and the active TCP (an exact one); the JSON names that TCP."""
    truth = call(ros, GetGroundTruth, 'get_ground_truth')
    true_params = np.array(truth.true_parameters)
    true_tool = convert.transform_to_matrix(truth.t_flange_tool_true)
    assert np.linalg.norm(true_tool[:3, 3] - CELL.T_flange_tool[:3, 3]) > 1e-4 # not the cell's
    # what an exact calibration would store: the mock's true arm
    record = tmp_path / 'k-true.json'
    record.write_text(json.dumps({
        'id': 'k-true', 'robot': MODEL.name, 'stamp_ns': 1, 'method': 'test', 'inputs': {},
        'result': {'parameter_names': list(truth.parameter_names),
                   'params': true_params.tolist()}}))
    data = tmp_path / 'results'
    tcp_id = _exact_tcp(data, true_tool)
    true_tcp = MODEL.chain(true_params, tool=true_tool)      # the mock's truth
    target = fk(rig.Rig(CELL, model=MODEL).chain('tcp'), CELL.home + 0.15)
    xyz = target[:3, 3].tolist()
    rpy = Rotation.from_matrix(target[:3, :3]).as_euler('xyz').tolist()
    np.testing.assert_allclose(from_xyz_rpy(xyz, rpy), target, atol=1e-12)
    errors = {}
    for label, choice in (('nominal', 'nominal'), ('compensated', str(record))):
        home = move.move_joints(ros, CELL.home, executor=ros.executor_for_tests)
        assert home.error_code == home.SUCCESS, home.message     # the same seed for both
        moved = _move(xyz, rpy, '--kinematics', choice, '--data-dir', str(data))
        assert moved['moved'] and moved['kinematics'] == label.replace('compensated', 'k-true')
        assert moved['tool_record'] == tcp_id
        np.testing.assert_allclose(moved['reached'], moved['positions'], atol=1e-12)
        reached = fk(true_tcp, np.array(moved['reached']))
        errors[label] = float(np.linalg.norm(reached[:3, 3] - target[:3, 3]))
    assert errors['compensated'] < 1e-6 and errors['nominal'] > 1e-4, errors


def test_an_unreachable_target_is_refused_before_anything_moves(ros, trial_data):
    out = cli('move', '--xyz', '4', '0', '0.5', '--rpy', '0', '0', '0', '--robot-cell',
              'sawyer_close', '--kinematics', 'nominal', '--data-dir', str(trial_data))
    assert out.returncode == 2
    assert 'the target cannot be reached by the nominal model' in out.stderr
