"""`cobot-calib export`: a stored user frame as controller syntax (no ROS needed)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.vendor_frames import from_values

STORE = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67'
RIGID = '20261125T150121.300898935Z-rigid'


def _T_base_user(record_id: str) -> np.ndarray:
    record = json.loads((STORE / 'calibrations' / f'{record_id}.json').read_text())
    return np.array(record['result']['T_base_user'])


@pytest.mark.parametrize('fmt', ['kuka', 'abb', 'fanuc', 'ur', 'yaskawa'])
def test_export_json_values_give_back_the_stored_frame(fmt, capsys):
    assert main(['export', RIGID, '--format', fmt, '--json', '--data-dir', str(STORE)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['id'] == RIGID and out['format'] == fmt
    T = from_values(list(out['values'].values()), fmt)
    assert np.allclose(T, _T_base_user(RIGID), rtol=0, atol=1e-12)


def test_export_prints_paste_ready_krl_of_the_active_frame(capsys):
    assert main(['export', 'active', '--format', 'kuka', '--index', '4',
                 '--data-dir', str(STORE)]) == 0
    lines = capsys.readouterr().out.splitlines()
    newest = RIGID              # the newest stamp_ns: active by default
    assert lines[0] == f'; user frame in the robot base: cobot_calib {newest} (rigid)'
    assert lines[1].startswith('BASE_DATA[4]={X ') and lines[1].endswith('}')
    x_mm = float(lines[1].split('X ')[1].split(',')[0])
    assert x_mm == pytest.approx(_T_base_user(newest)[0, 3] * 1e3, abs=1e-4)


def test_export_of_an_unknown_id_says_where_it_looked(capsys):
    assert main(['export', 'no-such-id', '--format', 'ur', '--data-dir', str(STORE)]) == 1
    assert "no user-frame calibration 'no-such-id'" in capsys.readouterr().err
    assert main(['export', '../etc', '--format', 'ur', '--data-dir', str(STORE)]) == 2


@pytest.mark.parametrize('fmt, index', [('fanuc', '0'), ('fanuc', '-1'), ('fanuc', '10'),
                                        ('kuka', '33'), ('kuka', '99'), ('yaskawa', '64'),
                                        ('abb', '2'), ('ur', '1')])
def test_export_refuses_a_frame_number_the_controller_does_not_have(fmt, index, capsys):
    """Issue 31.9: --index 0, -1 and 99 were written out (FANUC UFRAME 1-9, KUKA BASE 1-32);
    ABB and UR frames are named (--name), not numbered."""
    assert main(['export', RIGID, '--format', fmt, '--index', index,
                 '--data-dir', str(STORE)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('export: --index: ')
    assert ('--name' in err) if fmt in ('abb', 'ur') else (
        {'fanuc': 'give 1..9', 'kuka': 'give 1..32', 'yaskawa': 'give 1..63'}[fmt] in err)


@pytest.mark.parametrize('fmt, index, line', [('fanuc', '9', 'UFRAME[9]=PR[59] ;'),
                                              ('kuka', '32', 'BASE_DATA[32]={X ')])
def test_export_takes_the_last_frame_number(fmt, index, line, capsys):
    assert main(['export', RIGID, '--format', fmt, '--index', index,
                 '--data-dir', str(STORE)]) == 0
    assert any(x.startswith(line) for x in capsys.readouterr().out.splitlines())


def _stored_tcp(tmp_path):
    """A data dir with one TCP record of tool0 (x 0.12, y -0.19, z 100.21 mm, roll 2.8,
    pitch -2.2 mrad) and one user frame, as tcp_calibrator stores it."""
    import shutil
    from cobot_calib_ros import store
    from cobot_calib_ros.core import frames
    root = tmp_path / 'data'
    shutil.copytree(STORE, root)
    T = frames.from_xyz_rpy([0.00012, -0.00019, 0.10021], [0.0028, -0.0022, 0.0])
    store.open(root).tcp.save_and_activate({
        'id': 'tcp-probe', 'stamp_ns': 1, 'method': 'tcp-6-point-z', 'tool': 'tool0',
        'inputs': {}, 'result': {'T_flange_tool': T.tolist(), 'orientation_method': 'z'}})
    return root, T


TCP_TEXT = {
    'kuka': ['; TCP of tool0 in the flange frame: cobot_calib tcp-probe (tcp-6-point-z)',
             'TOOL_DATA[3]={X 0.1200,Y -0.1900,Z 100.2100,A 0.000000,B -0.126051,'
             'C 0.160428}'],
    'abb': ['! TCP of tool0 in the flange frame: cobot_calib tcp-probe (tcp-6-point-z)',
            '! load [1 kg at z 1 mm] is a placeholder: set the real mass and centre of gravity '
            '(LoadIdentify)',
            'PERS tooldata cobot_tcp:=[TRUE,[[0.1200,-0.1900,100.2100],[0.999998415,'
            '0.001399999,-0.001099999,0.000001540]],[1,[0,0,1],[1,0,0,0],0,0,0]];'],
    'fanuc': ['! TCP of tool0 in the flange frame: cobot_calib tcp-probe (tcp-6-point-z)',
              '! UTOOL[3] cobot_tcp: X 0.1200 Y -0.1900 Z 100.2100 W 0.160428 P -0.126051 '
              'R 0.000000',
              'PR[63,1]=0.1200 ;', 'PR[63,2]=-0.1900 ;', 'PR[63,3]=100.2100 ;',
              'PR[63,4]=0.160428 ;', 'PR[63,5]=-0.126051 ;', 'PR[63,6]=0.000000 ;',
              'UTOOL[3]=PR[63] ;'],
    'ur': ['# TCP of tool0 in the flange frame: cobot_calib tcp-probe (tcp-6-point-z)',
           'cobot_tcp = p[0.0001200, -0.0001900, 0.1002100, 0.00280000, -0.00220000, '
           '0.00000308]',
           'set_tcp(cobot_tcp)',
           '# Installation > General > TCP (mm, rad): X 0.1200 Y -0.1900 Z 100.2100 '
           'RX 0.00280000 RY -0.00220000 RZ 0.00000308'],
    'yaskawa': ['// TCP of tool0 in the flange frame: cobot_calib tcp-probe (tcp-6-point-z)',
                "// TOOL 3 cobot_tcp (the pendant's TOOL screen, mm and deg): X 0.1200 "
                'Y -0.1900 Z 100.2100 Rx 0.160428 Ry -0.126051 Rz 0.000000'],
}


@pytest.mark.parametrize('fmt', sorted(TCP_TEXT))
def test_export_writes_a_tcp_as_the_controllers_tool_data(fmt, tmp_path, capsys):
    """Issue 30.3: the calibrated TCP in each vendor's tool format (numbered tools: #3)."""
    root, _ = _stored_tcp(tmp_path)
    index = [] if fmt in ('abb', 'ur') else ['--index', '3']
    assert main(['export', 'tcp-probe', '--format', fmt, *index, '--data-dir',
                 str(root)]) == 0
    assert capsys.readouterr().out.splitlines() == TCP_TEXT[fmt]


def test_export_of_the_active_tcp_of_a_tool_gives_back_its_values(tmp_path, capsys):
    root, T = _stored_tcp(tmp_path)
    assert main(['export', 'active', '--tool', 'tool0', '--format', 'fanuc', '--index', '10',
                 '--json', '--data-dir', str(root)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['id'] == 'tcp-probe' and out['frame'].startswith('TCP of tool0')
    assert np.allclose(from_values(list(out['values'].values()), 'fanuc'), T, atol=1e-12)
    assert main(['export', 'active', '--tool', 'gripper', '--format', 'ur', '--data-dir',
                 str(root)]) == 1
    assert "no TCP calibration of tool 'gripper' 'active'" in capsys.readouterr().err
    assert main(['export', 'tcp-probe', '--format', 'kuka', '--index', '17', '--data-dir',
                 str(root)]) == 2
    assert 'give 1..16' in capsys.readouterr().err


def test_export_of_a_frame_touched_with_another_tcp_says_it_is_stale(tmp_path, capsys):
    """Issue 36.2: the frame goes to the controller with the active TCP; when it was touched
    with another, export says so in one line on stderr and in its JSON (`stale`)."""
    from cobot_calib_ros import store
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    from cobot_calib_ros.store.cells import ResultsCell
    cell = load_cell(cell_file('sawyer_close'))
    repo = store.open(tmp_path, cell=ResultsCell.of(cell))
    for tcp_id, dy in (('t1', 0.0), ('t2', 2e-4)):
        T = np.array(cell.T_flange_tool)
        T[1, 3] += dy
        repo.tcp.save_and_activate({
            'id': tcp_id, 'stamp_ns': 1 + int(dy > 0), 'method': 'tcp-4-point',
            'tool': cell.tool_frame, 'inputs': {}, 'measured_through': {'kinematics': 'nominal'},
            'result': {'T_flange_tool': T.tolist(), 'orientation_method': 'none'}})
        if tcp_id == 't1':
            repo.user_frames.save_and_activate({
                'id': 'F', 'stamp_ns': 1, 'method': 'rigid', 'inputs': {},
                'measured_through': {'kinematics': 'nominal', 'tcp': 't1'},
                'result': {'T_base_user': np.eye(4).tolist()}})
    assert main(['export', 'active', '--format', 'ur', '--json', '--data-dir',
                 str(tmp_path)]) == 0
    captured = capsys.readouterr()
    (stale,) = json.loads(captured.out)['stale']
    assert (stale['id'], stale['was'], stale['now']) == ('F', 't1', 't2')
    assert stale['change_mm'] == pytest.approx(0.2, abs=1e-9)
    assert f'export: stale: {stale["message"]}' in captured.err
