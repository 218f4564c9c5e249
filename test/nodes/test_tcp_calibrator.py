"""tcp_calibrator with mock_robot, joint_state_monitor, user_frame_solver and proximity_sensor
as processes on a private domain of their own (cell sawyer_close, temporary data_dir): the ROS
translation of the TCP calibration. `cobot-calib tcp` has the mock's simulated operator touch
P1 from tilted approaches and a z elongator point; the action's result is the stored record's
(fields in [m], the _mm ones in mm), active for the cell's tool; a user frame touched next
names that TCP, and is reported stale once another TCP is active (history, check, move; move
solves for the new one); approaches too alike are refused before anything moves. The
procedure itself (the true tool found, cancel, the gate) is tested in-process:
test/api/test_tcp_api.py.

Own suite, not the session's (test/nodes/conftest.py): a second mock_robot on the session's
domain would answer its hand-guiding.
"""
import json
import math
import os
import subprocess

import domain_coordinator
import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.api import launcher
from cobot_calib_ros.core.frames import from_xyz_rpy
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.cells import ResultsCell
from rosutil import cli_command, STOP_TIMEOUT

NODES = ('mock_robot', 'joint_state_monitor', 'tcp_calibrator', 'user_frame_solver',
         'proximity_sensor')      # the probe: `check user-frame` touches with it
CELL = ResultsCell('sawyer_close', 'sawyer')
SIM = load_simulation(cell_file('sawyer_close'))


@pytest.fixture(scope='module')
def tcp_suite(tmp_path_factory):
    data = tmp_path_factory.mktemp('tcp_data')
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path_factory.mktemp('tcp_logs'))
        suite.start(launcher.suite_specs('sawyer_close', NODES, overrides={
            'mock_robot': {'time_scale': '0.05'},
            'tcp_calibrator': {'data_dir': str(data), 'hold_duration': '0.1'},
            'user_frame_solver': {'data_dir': str(data)}}), env=env)
        try:
            yield suite, data, env
        finally:
            codes = suite.stop(STOP_TIMEOUT)
        assert all(c == 0 for c in codes.values()), f'nodes did not exit cleanly: {codes}'


def _tcp(env, *args):
    return subprocess.run(cli_command('tcp', *args), env=env, capture_output=True, text=True,
                          timeout=600)


def test_the_tcp_calibrated_on_the_suite_is_the_stored_record_and_becomes_active(tcp_suite):
    suite, data, env = tcp_suite
    out = _tcp(env, '--json', '--orientations', '6', '--orientation', 'z')
    logs = '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)
    assert out.returncode == 0, f'{out.stdout}\n{out.stderr}\n{logs}'
    result = json.loads(out.stdout)
    assert result['active'] and result['tool'] == 'tool0'
    assert 'touch 7/7' in out.stderr            # progress on stderr with --json
    active = store.open(data, cell=CELL).tcp.active('tool0')
    assert active['id'] == result['calibration_id']
    assert active['method'] == 'tcp-6-point-z' and active['kinematics'] == 'nominal'
    stored = active['result']
    np.testing.assert_allclose(result['T_flange_tool'], stored['T_flange_tool'], atol=1e-12)
    np.testing.assert_allclose(result['fixed_point_mm'], np.array(stored['fixed_point']) * 1e3,
                               atol=1e-9)
    assert result['mean_residual_mm'] == pytest.approx(stored['mean_residual_mm'], abs=1e-12)
    assert result['max_residual_mm'] == pytest.approx(max(stored['residuals_mm']), abs=1e-12)
    assert result['orientations_used'] == 6 and result['condition'] == stored['condition']
    # mm in the _mm fields: the mock's touches leave tens of micrometres, not metres
    assert 1e-3 < result['mean_residual_mm'] < 0.3
    truth = SIM.T_flange_tool_true               # the TCP is metres in the transform
    assert np.linalg.norm(np.array(result['T_flange_tool'])[:3, 3] - truth[:3, 3]) < 1e-3


def test_a_user_frame_touched_after_names_the_tcp_it_was_touched_with(tcp_suite):
    """The frame's points are touched with the active TCP (the one the test above found), and
    its record names it: a later TCP change is told apart from the table's (store.history)."""
    _, data, env = tcp_suite
    tcp = store.open(data, cell=CELL).tcp.active('tool0')
    assert tcp is not None, 'run with the test above: it makes the TCP active'
    out = subprocess.run(cli_command('call', 'calibrate_user_frame',
                                     '{method: rigid, point_names: [P1, P2, P3, P4]}'),
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and 'error_code: 0' in out.stdout, out.stdout + out.stderr
    frame = store.open(data, cell=CELL).user_frames.active()
    assert frame['tcp'] == tcp['id'] and frame['kinematics'] == 'nominal'


def _cli_json(env, *args) -> tuple[int, dict, str]:
    out = subprocess.run(cli_command(*args, '--json'), env=env, capture_output=True, text=True,
                         timeout=300)
    lines = out.stdout.strip().splitlines()
    return out.returncode, json.loads(lines[-1]) if lines else {}, out.stdout + out.stderr


def test_a_new_active_tcp_makes_the_frame_touched_with_the_old_one_stale_and_move_uses_it(
        tcp_suite):
    """Issue 36 must-show 2: the active TCP changes (a recalibrated tool, 0.1 mm along the
    flange's x); the user frame touched with the old one is reported stale, naming both TCPs
    and their distance at the tool, by history (JSON), check and move (JSON); move solves for
    the new TCP and its JSON names it."""
    _, data, env = tcp_suite
    repo = store.open(data, cell=CELL)
    old, frame = repo.tcp.active('tool0'), repo.user_frames.active()
    assert old is not None and frame is not None, 'run with the two tests above'
    assert frame['measured_through'] == {'kinematics': 'nominal', 'tcp': old['id']}
    T_new = np.array(old['result']['T_flange_tool'])
    T_new[0, 3] += 1e-4
    new = {**old, 'id': 'tcp-tool0-recalibrated', 'stamp_ns': old['stamp_ns'] + 1,
           'result': {**old['result'], 'T_flange_tool': T_new.tolist()}}
    assert repo.tcp.save_and_activate(new)
    try:
        words = (f'user frame {frame["id"]} was touched with TCP {old["id"]}; the active TCP '
                 f'{new["id"]} is 0.100 mm away at the tool: touch the frame again, or keep it')

        def check_stale(entries, where):
            assert [(s['kind'], s['id'], s['was'], s['now'], s['message']) for s in entries
                    if s['kind'] == 'user_frame'] == [
                ('user_frame', frame['id'], old['id'], new['id'], words)], where
            assert entries[0]['change_mm'] == pytest.approx(0.1, abs=1e-6), where

        code, history, text = _cli_json(env, 'history', '--no-plots', '--data-dir', str(data))
        assert code == 0, text
        check_stale(history['stale'], text)
        code, check, text = _cli_json(env, 'check', 'user-frame', '--data-dir', str(data),
                                      '--robot-cell', 'sawyer_close')
        assert code in (0, 1) and 'stale' in check, text     # pass or not: it says why
        check_stale(check['stale'], text)
        assert f'stale: {words}' in text
        T_user_tool = from_xyz_rpy(np.array(SIM.cell.marker('P1').nominal_top) + [0, 0, 0.03],
                                   [math.pi, 0.0, 0.0])
        xyz, rpy = T_user_tool[:3, 3], [math.pi, 0.0, 0.0]
        code, moved, text = _cli_json(env, 'move', '--frame', 'user', '--dry-run',
                                      '--data-dir', str(data), '--robot-cell', 'sawyer_close',
                                      '--xyz', *[repr(float(v)) for v in xyz],
                                      '--rpy', *[repr(float(v)) for v in rpy])
        assert code == 0, text
        assert moved['tool_record'] == new['id'] and moved['kinematics'] == 'nominal', text
        check_stale(moved['stale'], text)
        tool = np.array(SIM.cell.T_flange_tool)
        tool[:3, 3] = T_new[:3, 3]
        if new['result']['orientation_method'] != 'none':   # z measured (the test above)
            tool = T_new
        reached = fk(model_for(SIM.cell).chain(tool=tool), np.array(moved['positions']))
        np.testing.assert_allclose(reached, np.array(frame['result']['T_base_user'])
                                   @ T_user_tool, atol=1e-9)
    finally:
        repo.tcp.activate(old['id'], 'tool0')


def test_approaches_too_alike_are_refused_before_anything_moves(tcp_suite):
    _, data, env = tcp_suite
    before = store.open(data, cell=CELL).tcp.ids()
    out = _tcp(env, '--orientations', '4', '--tilt-deg', '6')
    assert out.returncode == 1
    assert 'TCP calibration failed: planned the approaches are too alike' in out.stderr
    assert 'approaches 1 and 2 differ by 6.0 deg' in out.stderr
    assert 'touch 1/' not in out.stdout
    out = _tcp(env, '--point', 'P9')
    assert out.returncode == 1 and "unknown point 'P9'" in out.stderr
    assert store.open(data, cell=CELL).tcp.ids() == before
