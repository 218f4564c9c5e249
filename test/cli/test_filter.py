"""`cobot-calib filter`: a program corrected for a controller's nominal kinematics, written only
when every target is reached (no ROS needed)."""
from __future__ import annotations

import json

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.frames import to_pose
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import KinematicInputs, KinematicRecord, KinematicResult

CELL = load_cell(cell_file('ur10e_close'))
MODEL = model_for(CELL)
PARAMS = MODEL.nominal + np.random.default_rng(8).choice([-1, 1], MODEL.nominal.size) * 4e-4
RECORD = KinematicRecord(
    id='k-filter-test', stamp_ns=1, method='relative-lm', robot=MODEL.name,
    inputs=KinematicInputs(source='test'),
    result=KinematicResult(parameter_names=list(MODEL.parameter_names), params=list(PARAMS),
                           p_flange_tool=[0.0, 0.0, 0.1], rms_m=1e-5, converged=True))
HEADER = 'name,x,y,z,qx,qy,qz,qw\n'


def program(tmp_path, far: bool) -> tuple:
    q = CELL.home + np.random.default_rng(3).normal(0, 0.2, (6, 6))
    poses = fk(MODEL.chain(PARAMS, tool=CELL.T_flange_tool), q)
    lines = [f'wp{k},' + ','.join(repr(float(v)) for v in np.concatenate(to_pose(T)))
             for k, T in enumerate(poses)]
    if far:
        lines.insert(2, 'beyond_reach,4.0,0,0.5,0,0,0,1')
    path = tmp_path / 'program.csv'
    path.write_text(HEADER + '\n'.join(lines) + '\n')
    return path, q


def record_file(tmp_path):
    path = tmp_path / 'k-filter-test.json'
    path.write_text(json.dumps(RECORD.to_dict()))
    return path


def test_filter_writes_corrected_targets_and_joints(tmp_path, capsys):
    targets, q = program(tmp_path, far=False)
    out = tmp_path / 'filtered.csv'
    assert main(['filter', '--targets', str(targets), '--out', str(out), '--robot-cell',
                 'ur10e_close', '--kinematics', str(record_file(tmp_path)),
                 '--data-dir', str(tmp_path / 'data')]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith('filtered 6 targets with k-filter-test (base frame, tool tcp): '
                              'largest correction ')
    header, *rows = out.read_text().splitlines()
    assert header == HEADER.strip() + ',' + ','.join(MODEL.joint_names)
    values = np.array([[float(v) for v in row.split(',')[1:]] for row in rows])
    assert_allclose(values[:, 7:], q, rtol=0, atol=1e-6)
    nominal = fk(MODEL.chain(tool=CELL.T_flange_tool), q)
    assert_allclose(values[:, :3], nominal[:, :3, 3], rtol=0, atol=1e-9)


def test_an_unreachable_target_is_named_and_nothing_is_written(tmp_path, capsys):
    targets, _ = program(tmp_path, far=True)
    out = tmp_path / 'filtered.csv'
    assert main(['filter', '--targets', str(targets), '--out', str(out), '--robot-cell',
                 'ur10e_close', '--kinematics', str(record_file(tmp_path)),
                 '--data-dir', str(tmp_path / 'data')]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith('filter: target beyond_reach: cannot be reached by the calibrated '
                             'model (')
    assert err[-1] == f'filter: 1 of 7 targets cannot be reached; nothing written to {out}'
    assert not out.exists()


def test_the_active_calibration_of_the_cell_is_used_and_its_absence_explained(tmp_path, capsys):
    targets, q = program(tmp_path, far=False)
    out, data = tmp_path / 'filtered.csv', tmp_path / 'data'
    args = ['filter', '--targets', str(targets), '--out', str(out), '--robot-cell',
            'ur10e_close', '--data-dir', str(data), '--json']
    assert main(args) == 2
    assert 'no active kinematic calibration of the ur10e' in capsys.readouterr().err
    store.open(data, cell=ResultsCell.of(CELL)).kinematics.save_and_activate(RECORD)
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary['calibration'] == 'k-filter-test' and summary['targets'] == 6
    assert 0.1 < summary['largest_correction_mm'] < 10


@pytest.mark.parametrize('extra, words', [
    (['--frame', 'user'], 'no active user frame in the results of cell ur10e_close'),
    (['--kinematics', 'no-such-id'], "no kinematic calibration 'no-such-id'"),
])
def test_filter_refusals_say_what_to_do(tmp_path, capsys, extra, words):
    targets, _ = program(tmp_path, far=False)
    data = tmp_path / 'data'
    store.open(data, cell=ResultsCell.of(CELL)).kinematics.save_and_activate(RECORD)
    assert main(['filter', '--targets', str(targets), '--out', str(tmp_path / 'o.csv'),
                 '--robot-cell', 'ur10e_close', '--data-dir', str(data)] + extra) == 2
    assert words in capsys.readouterr().err
