"""`cobot-calib up` checks the whole cell file before it starts any node; two cells' suites on
one data dir each activate only their own results (real `up` processes, Ctrl-C between)."""
import contextlib
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import pytest

from cobot_calib_ros import store
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.cells import ResultsCell
from proc_lines import Lines
from side_by_side import cli_side_by_side


@pytest.mark.parametrize('old, new, words', [
    ('  robot: {model', '  robt: {model', ["cell.robt: unknown key 'robt'; did you mean 'robot'"]),
    ('  seed: 7', '  seed: seven', ['simulation.seed: expected a finite number']),
    ('  layout: close', '  layout: narrow', ['cell.layout', 'close, wide'])])
def test_up_refuses_a_broken_cell_file_before_starting_anything(tmp_path, old, new, words):
    text = cell_file('sawyer_close').read_text()
    assert old in text
    broken = tmp_path / 'broken.yaml'
    broken.write_text(text.replace(old, new, 1))
    shutil.copy(cell_file('sawyer_close').parent / 'sawyer.urdf', tmp_path)
    out = subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'up', '--cell',
                          str(broken)], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, ROS_DOMAIN_ID='101'))
    assert out.returncode == 2
    assert 'node suite up' not in out.stdout and 'Traceback' not in out.stderr
    assert f'{broken}:' in out.stderr and 'nothing started' in out.stderr
    for word in words:
        assert word in out.stderr


# -- two cells on one data dir (issue 31 item 1) -----------------------------------------------

SQUARE = ('[{x: 0.0, y: 0.0, z: 0.0}, {x: 0.2, y: 0.0, z: 0.0}, {x: 0.2, y: 0.15, z: 0.0}, '
          '{x: 0.0, y: 0.15, z: 0.0}]')
SHIFTED = ('[{x: 0.5, y: 0.1, z: 0.05}, {x: 0.7, y: 0.1, z: 0.05}, {x: 0.7, y: 0.25, z: 0.05}, '
           '{x: 0.5, y: 0.25, z: 0.05}]')
READY_TIMEOUT = 240.0       # [s] nine node processes starting on two loaded cores
SAWYER, IIWA = ResultsCell('sawyer_close', 'sawyer'), ResultsCell('iiwa7_close', 'iiwa7')


def _cli(*args) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


def test_up_refuses_nodes_that_are_not_in_the_suite():
    out = subprocess.run(_cli('up', '--nodes', 'user_frame_solver,no_such_node'),
                         capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, ROS_DOMAIN_ID='101'))
    assert out.returncode == 2 and 'node suite' not in out.stdout
    assert "--nodes 'user_frame_solver,no_such_node': no_such_node not in the suite" in out.stderr
    assert 'nothing started' in out.stderr


# what each suite of the two-cell test needs: the Sawyer's serves a calibration and its
# stored hand-eye; the iiwa's also the robot calls `check` makes (no camera nodes, no trials)
SERVING = 'user_frame_solver,hand_eye_calibrator'
CHECKING = 'mock_robot,joint_state_monitor,proximity_sensor,' + SERVING


@contextlib.contextmanager
def _up(env: dict[str, str], cell: str, nodes: str):
    """`cobot-calib up --cell CELL --nodes NODES` as a user runs it, until 'ready'; Ctrl-C
    (SIGINT to its process group) at the end, and it has stopped. (--force: a domain of its
    own; not up's ~3 s look for a suite already there.)"""
    proc = subprocess.Popen(_cli('up', '--cell', cell, '--nodes', nodes, '--force'),
                            stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    lines = Lines(proc.stdout)
    try:
        ready = lines.match(r'^ready: all \d+ nodes answer$', READY_TIMEOUT)
        assert ready, f'up --cell {cell} not ready:\n{"".join(lines.seen)}'
        yield lambda *args: cli_side_by_side(args, env=env)[0]
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, ''.join(lines.seen)


def _sawyer_hand_eye() -> dict:
    """A hand-eye calibration of the Sawyer cell (as 5252a67 stored it)."""
    folder = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67' / 'hand_eye'
    return json.loads(next(folder.glob('*.json')).read_text())


def test_a_second_cell_on_the_same_data_dir_activates_none_of_the_first_s_results(tmp_path):
    """`up --cell sawyer_close`, a user frame calibrated and a hand-eye active; Ctrl-C; then
    `up --cell iiwa7_close` on the same data dir: the iiwa's suite publishes neither on
    user_frame / hand_eye (on 85479bc it published the Sawyer's as its own), refuses the
    Sawyer's frame by name, and the Sawyer's results are still its own, active."""
    import domain_coordinator
    data = tmp_path / 'data'
    hand_eye = _sawyer_hand_eye()
    assert store.open(data, cell=SAWYER).hand_eye.save_and_activate(hand_eye)
    with domain_coordinator.domain_id() as domain:
        env = {k: v for k, v in os.environ.items() if k not in ('COBOT_CALIB_DB',
                                                                 'COBOT_CALIB_CELL')}
        env.update(ROS_DOMAIN_ID=str(domain), COBOT_CALIB_DATA=str(data),
                   ROS_LOG_DIR=str(tmp_path / 'logs'))
        with _up(env, 'sawyer_close', SERVING) as run:
            out = run('call', 'calibrate_user_frame',
                      f'{{method: rigid, points_user: {SQUARE}, points_base: {SHIFTED}}}',
                      '--json')
            frame = json.loads(out.stdout)['calibration']
            assert out.returncode == 0 and frame['id'], out.stderr
            latched, he = cli_side_by_side(('echo', 'user_frame', '--once', '--json'),
                                           ('echo', 'hand_eye', '--once', '--json'), env=env)
            assert json.loads(latched.stdout)['id'] == frame['id'], latched.stderr
            assert he.returncode == 0, he.stderr
            x = json.loads(he.stdout)['transform']['translation']['x']
            assert x == pytest.approx(hand_eye['result']['T_flange_optical'][0][3], abs=1e-12)
        with _up(env, 'iiwa7_close', CHECKING):
            # side by side: the echoes wait out their 5 s whatever the others do
            listed, user_frame, hand_eye_topic, refused, check = cli_side_by_side(
                ('call', 'list_calibrations', '{}', '--json'),
                ('echo', 'user_frame', '--once', '--timeout', '5'),
                ('echo', 'hand_eye', '--once', '--timeout', '5'),
                ('call', 'set_active_calibration',
                 f'{{calibration_id: {frame["id"]}, action: 0}}', '--json'),
                ('check', 'user-frame'), env=env, timeout=180.0)
            listed = json.loads(listed.stdout)
            assert listed['active_id'] == '' and listed['calibrations'] == []
            assert user_frame.returncode == 1 and hand_eye_topic.returncode == 1
            answer = json.loads(refused.stdout)
            assert answer['error_code'] == 2 and answer['active']['id'] == ''
            assert ("made in cell 'sawyer_close' on the sawyer; this is cell 'iiwa7_close' on "
                    "the iiwa7") in answer['message']
            assert check.returncode == 1 and ('no active user frame in the results of cell '
                                              'iiwa7_close (iiwa7)') in check.stderr
    sawyer = store.open(data, cell=SAWYER)
    assert sawyer.user_frames.active()['id'] == frame['id']
    assert sawyer.hand_eye.active()['id'] == hand_eye['id']
    assert (sawyer.user_frames.active()['cell'], sawyer.user_frames.active()['robot']) == (
        'sawyer_close', 'sawyer')
    assert store.open(data, cell=IIWA).user_frames.history() == []
