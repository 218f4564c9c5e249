"""`cobot-calib filter` with the cell's active set (issue 36): the chain ends at the active TCP,
the JSON names it, and a user frame touched with another TCP is said to be stale."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.frames import to_pose
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.cells import ResultsCell

CELL = load_cell(cell_file('ur10e_close'))
MODEL = model_for(CELL)
PARAMS = MODEL.nominal + np.random.default_rng(8).choice([-1, 1], MODEL.nominal.size) * 4e-4


def _tool(dz: float) -> np.ndarray:
    T = np.array(CELL.T_flange_tool)
    T[2, 3] += dz
    return T


def test_filter_uses_the_active_tcp_and_says_the_frame_touched_with_another_is_stale(
        tmp_path, capsys):
    repo = store.open(tmp_path, cell=ResultsCell.of(CELL))
    repo.kinematics.save_and_activate({
        'id': 'k1', 'stamp_ns': 1, 'method': 'test', 'robot': MODEL.name, 'inputs': {},
        'measured_through': {}, 'result': {'parameter_names': list(MODEL.parameter_names),
                                           'params': PARAMS.tolist()}})
    for tcp_id, dz in (('t1', 0.0), ('t2', 3e-4)):
        repo.tcp.save_and_activate({
            'id': tcp_id, 'stamp_ns': 2 + int(dz > 0), 'method': 'tcp-4-point',
            'tool': CELL.tool_frame, 'inputs': {}, 'measured_through': {'kinematics': 'k1'},
            'result': {'T_flange_tool': _tool(dz).tolist(), 'orientation_method': 'none'}})
        if tcp_id == 't1':
            repo.user_frames.save_and_activate({
                'id': 'F', 'stamp_ns': 2, 'method': 'rigid', 'inputs': {},
                'measured_through': {'kinematics': 'k1', 'tcp': 't1'},
                'result': {'T_base_user': np.eye(4).tolist()}})
    q = CELL.home + np.random.default_rng(3).normal(0, 0.2, (4, 6))
    rows = [f'wp{k},' + ','.join(repr(float(v)) for v in np.concatenate(to_pose(T)))
            for k, T in enumerate(fk(MODEL.chain(PARAMS, tool=_tool(3e-4)), q))]
    targets = tmp_path / 'program.csv'
    targets.write_text('name,x,y,z,qx,qy,qz,qw\n' + '\n'.join(rows) + '\n')
    out = tmp_path / 'filtered.csv'
    assert main(['filter', '--targets', str(targets), '--out', str(out), '--frame', 'user',
                 '--robot-cell', 'ur10e_close', '--data-dir', str(tmp_path), '--json']) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary['calibration'] == 'k1' and summary['tool_record'] == 't2'
    (stale,) = summary['stale']
    assert (stale['id'], stale['was'], stale['now']) == ('F', 't1', 't2')
    assert stale['change_mm'] == pytest.approx(0.3, abs=1e-9)
    assert f'filter: stale: {stale["message"]}' in captured.err
    # the calibrated joints written are those of the new TCP: each target is reached exactly
    joints = np.array([[float(v) for v in line.split(',')[8:]]
                       for line in out.read_text().splitlines()[1:]])
    reached = fk(MODEL.chain(PARAMS, tool=_tool(3e-4)), joints)
    assert len(joints) == 4
    np.testing.assert_allclose(reached[:, :3, 3], fk(MODEL.chain(PARAMS, tool=_tool(3e-4)),
                                                     q)[:, :3, 3], atol=1e-9)
