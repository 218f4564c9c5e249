"""Issue 23: each verb refuses bad input before the robot moves, in one line that names the
cause; `call` exits 1 on a refused answer; `record` warns of a topic nobody publishes; a client
leaves no log file; `param` reads and sets a node's parameters as ros2 param."""
import contextlib
import os
import subprocess
import sys
import threading
from types import SimpleNamespace

import pytest

from cobot_calib_ros.cli.common import cell_names
from cobot_calib_ros.cli.main import main
from side_by_side import cli_side_by_side


def _cli(*args, env=None, timeout=60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', *args],
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    return err.strip()


# -- teach, trial, demo: refused before anything moves (no suite on this domain) -----------

@pytest.mark.parametrize('options, words', [
    (['--method', 'landmark_single'],
     ['--method landmark_single measures the frame with the wrist camera, not from touches',
      'teach can use: three_point, five_point_lsq, rigid, robust; nothing was touched']),
    (['--method', 'bogus'], ['--method bogus is not a method; teach can use: three_point,']),
    (['--hold', '-1'], ['--hold -1: give a time > 0 [s]; nothing was touched']),
    (['--timeout', '0'], ['--timeout 0: give a time > 0 [s]']),
])
def test_teach_refuses_a_bad_option_before_the_first_touch(capsys, options, words):
    """On e6ccb73 these were refused after every touch (or landmark_single ignored them)."""
    assert main(['teach', *options]) == 2
    err = _one_line(capsys)
    for word in words:
        assert word in err


@pytest.mark.parametrize('stall', ['-1', '0', 'nan'])
def test_trial_refuses_a_stall_timeout_that_is_not_positive(capsys, stall):
    """On e6ccb73 --stall-timeout -1 started a trial and cancelled it 'for -1 s'."""
    assert main(['trial', '--stall-timeout', stall]) == 2
    err = _one_line(capsys)
    assert err.startswith(f'trial rejected: --stall-timeout {stall}: give a time > 0 [s]')


@pytest.fixture(scope='module', autouse=True)
def own_domain():
    """This module's fake suite nodes (user_frame_solver, repeatability_trial) on a domain of
    their own: on the session's domain a real suite of test/nodes (the same worker under
    `make test`'s parallel workers) answered their calls."""
    import domain_coordinator
    with domain_coordinator.domain_id() as domain, pytest.MonkeyPatch.context() as patch:
        patch.setenv('ROS_DOMAIN_ID', str(domain))
        yield domain


@contextlib.contextmanager
def _spinning_node(name: str):
    """A node of this process with parameter services, spun on a thread of its own."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(5.0)


@pytest.fixture
def fake_trial_node(tmp_path):
    """A node named repeatability_trial whose data_dir holds one unfinished trial."""
    from cobot_calib_ros.store.trials import TrialStore
    TrialStore(tmp_path).create('20261125T100000-rigid-z', method='rigid', axis='z',
                                layout='close', point_names=['P1', 'P2', 'P3'], cycles_total=3)
    with _spinning_node('repeatability_trial') as node:
        node.declare_parameter('data_dir', str(tmp_path))
        yield tmp_path


def test_trial_refuses_a_trial_id_that_is_not_stored(fake_trial_node):
    """On e6ccb73 `--trial-id no-such-trial` started and completed a fresh trial under it."""
    done = _cli('trial', '--trial-id', 'no-such-trial')
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == (
        f'trial rejected: no trial no-such-trial in {fake_trial_node / "trials"}; unfinished: '
        '20261125T100000-rigid-z (leave --trial-id out to start a new trial)')


def test_demo_refuses_a_missing_or_broken_cell_in_one_line(capsys, tmp_path):
    assert main(['demo', '--cell', 'nonexistent']) == 2
    err = _one_line(capsys)
    assert err.startswith('demo: cell file ') and 'nonexistent.yaml not found' in err
    assert err.endswith(f'({cell_names()})') and 'iiwa7_close, sawyer_close' in err
    broken = tmp_path / 'broken.yaml'
    broken.write_text('cell:\n  name: x\n  robot: sawyer\n  base_frme: base_link\n')
    assert main(['demo', '--cell', str(broken)]) == 2
    assert _one_line(capsys) == (f"demo: {broken}:4: cell.base_frme: unknown key 'base_frme'; "
                                 "did you mean 'base_frame'? known here: " + ', '.join(
                                     __import__('cobot_calib_ros.core.cell', fromlist=['x'])
                                     .CELL_KEYS))


# -- demo: a temporary data dir, and the attached suite's cell ----------------------------

def test_demo_without_attach_stores_in_a_temporary_data_dir(monkeypatch, tmp_path):
    """Issue 23.6: the demo's suite stored in the shared data dir and changed the running
    suite's active user frame. Its nodes now get a temporary data_dir (and no $COBOT_CALIB_DB),
    removed afterwards, with the user's kinematic calibrations copied in for --kinematics."""
    import contextlib
    import numpy as np
    from cobot_calib_ros import store
    from cobot_calib_ros.cli import demo
    from cobot_calib_ros.core.kinematics import model_by_name
    from cobot_calib_ros.store.database import sqlite_url
    shared = tmp_path / 'shared'
    shared.mkdir()
    monkeypatch.setenv('COBOT_CALIB_DATA', str(shared))
    monkeypatch.setenv('COBOT_CALIB_DB', sqlite_url(shared))
    model = model_by_name('sawyer')
    user = store.open(shared).kinematics
    for number in (1, 2):
        user.save({'id': f'k{number}', 'stamp_ns': number, 'method': 'relative-lm',
                   'robot': 'sawyer', 'inputs': {'source': 'test'},
                   'result': {'parameter_names': list(model.parameter_names),
                              'params': np.asarray(model.nominal).tolist(),
                              'p_flange_tool': [0.0, 0.0, 0.0]}})
    user.activate('k1', 'sawyer')
    started = {}

    @contextlib.contextmanager
    def private_suite(cell, overrides=None, say=print):
        started.update(cell=cell, overrides=overrides, db=os.environ.get('COBOT_CALIB_DB'))
        yield None
    monkeypatch.setattr(demo.launcher, 'private_suite', private_suite)
    args = SimpleNamespace(attach=False, cell='sawyer_close', kinematics='latest', json=False)
    with demo._suite(args) as root:
        assert root is not None and shared not in root.parents
        copied = store.open(root, cell='sawyer_close').kinematics     # the demo cell's
        assert sorted(r['id'] for r in copied.history()) == ['k1', 'k2']
        assert copied.active('sawyer')['id'] == 'k1'
    assert started == {'cell': 'sawyer_close', 'db': None,
                       'overrides': {n: {'data_dir': str(root)} for n in demo.STORING_NODES}}
    assert not root.exists() and os.environ['COBOT_CALIB_DB'] == sqlite_url(shared)
    assert sorted(r['id'] for r in store.open(shared).kinematics.history()) == ['k1', 'k2']


# -- call: a refused answer exits 1 -------------------------------------------------------

def test_call_reports_a_refused_answer_so_that_a_script_can_test_it():
    from cobot_calib_msgs.srv import CalibrateUserFrame
    from std_srvs.srv import Trigger
    from cobot_calib_ros.cli.call import refusal
    res = CalibrateUserFrame.Response(error_code=CalibrateUserFrame.Response.UNKNOWN_METHOD,
                                      message="unknown method 'bogus'")
    assert refusal(res) == "error_code 4 (UNKNOWN_METHOD): unknown method 'bogus'"
    assert refusal(CalibrateUserFrame.Response()) == ''
    assert refusal(Trigger.Response(success=False, message='no')) == 'success: false: no'
    assert refusal(Trigger.Response(success=True)) == ''


# -- record, bag info ---------------------------------------------------------------------

def test_record_warns_of_a_topic_nothing_publishes_and_an_empty_bag_has_no_start(tmp_path):
    """Issue 23.9: `record -o out /no_such_topic` said nothing, and `bag info` of the empty bag
    showed its start as 'Apr 11 2262' (rosbag2's largest time, which the metadata keeps so that
    ros2 bag reads it as its own: test_writer)."""
    out = tmp_path / 'out'
    done = _cli('record', '-o', str(out), '/no_such_topic_23', '--duration', '4')
    assert done.returncode == 0, done.stderr
    assert ('warning: nothing publishes /no_such_topic_23 (after 3 s); recorded only if a '
            'publisher appears') in done.stdout
    info = _cli('bag', 'info', str(out))
    assert info.returncode == 0, info.stderr
    lines = info.stdout.splitlines()
    assert 'Start:             (no messages)' in lines and 'End:               (no messages)' \
        in lines and 'Messages:          0' in lines
    assert '2262' not in info.stdout


# -- clients leave no log file --------------------------------------------------------------

def test_a_short_verb_leaves_no_log_file_unless_asked(tmp_path):
    """Issue 23.14: every CLI call left a python_<pid>.log in the ROS log dir."""
    quiet, asked = tmp_path / 'quiet', tmp_path / 'asked'
    for log_dir, extra in ((quiet, {}), (asked, {'COBOT_CALIB_CLIENT_LOG': '1'})):
        done = _cli('echo', 'no/such/topic', '--once', '--timeout', '0.3',
                    env={'ROS_LOG_DIR': str(log_dir), **extra})
        assert done.returncode == 1 and 'not found within 0.3 s' in done.stderr
    assert not quiet.exists() or not list(quiet.glob('python_*.log'))
    assert len(list(asked.glob('python_*.log'))) == 1


# -- param ----------------------------------------------------------------------------------

@pytest.fixture
def parameter_node():
    from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
    with _spinning_node('param_target_23') as node:
        node.declare_parameter('max_rms_error', 0.001, ParameterDescriptor(
            floating_point_range=[FloatingPointRange(from_value=1e-6, to_value=0.1)]))
        node.declare_parameter('cell_file', 'sawyer_close', ParameterDescriptor(read_only=True))
        node.declare_parameter('points', ['P1', 'P2'])
        yield node


def test_param_lists_gets_and_sets_as_ros2_param(parameter_node):
    """Issue 23.15: `param list|get|set NODE [NAME] [VALUE]`, the output of ros2 param."""
    # the reads side by side (each CLI's start is most of its time), then the sets
    listed, got, points, missing, gone, no_name = cli_side_by_side(
        ('param', 'list', 'param_target_23'),
        ('param', 'get', '/param_target_23', 'max_rms_error'),
        ('param', 'get', 'param_target_23', 'points'),
        ('param', 'get', 'param_target_23', 'nope'),
        ('param', 'list', 'no_such_node_23', '--timeout', '1'),
        ('param', 'get', 'param_target_23'))
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.splitlines() == ['  cell_file', '  max_rms_error', '  points',
                                          '  start_type_description_service', '  use_sim_time']
    assert (got.returncode, got.stdout) == (0, 'Double value is: 0.001\n')
    assert points.stdout == "String values are: ['P1', 'P2']\n"
    assert missing.returncode == 1 and "has no parameter 'nope'" in missing.stderr
    assert gone.returncode == 1 and gone.stderr.startswith(
        'node no_such_node_23 offers no parameter services within 1 s')
    assert no_name.returncode == 2     # NAME missing
    done = _cli('param', 'set', 'param_target_23', 'max_rms_error', '0.002')
    assert (done.returncode, done.stdout) == (0, 'Set parameter successful\n'), done.stderr
    assert parameter_node.get_parameter('max_rms_error').value == 0.002
    refused = cli_side_by_side(('param', 'set', 'param_target_23', 'max_rms_error', '1'),  # 1.0
                            ('param', 'set', 'param_target_23', 'cell_file', 'iiwa7_close'))
    for done in refused:
        assert done.returncode == 1 and done.stderr.startswith('Setting parameter failed: ')
    assert parameter_node.get_parameter('max_rms_error').value == 0.002



def test_demo_attach_takes_the_cell_and_data_dir_of_the_running_suite(tmp_path):
    """Issue 23.3: `demo --attach` without --cell took sawyer_close against an iiwa suite and
    raised ValueError; it now asks the suite's user_frame_solver for its cell and data dir."""
    from cobot_calib_ros.api import demo
    from cobot_calib_ros.ros.session import session
    with _spinning_node('user_frame_solver') as node:
        node.declare_parameter('cell_file', '/somewhere/iiwa7_close.yaml')
        node.declare_parameter('data_dir', str(tmp_path))
        with session('cobot_calib_demo_test') as (client, _):
            assert demo.attached(None, client) == ('/somewhere/iiwa7_close.yaml', tmp_path)
            assert demo.attached('sawyer_close', client) == ('sawyer_close', tmp_path)


def test_nodes_the_launcher_starts_write_only_their_own_log(monkeypatch):
    """Their console output is <node>.log in the suite's log dir: rcl's python_<pid>.log (the
    same lines, in the ROS log root) is left out, unless asked."""
    from cobot_calib_ros.api.launcher import NodeSpec
    monkeypatch.delenv('COBOT_CALIB_CLIENT_LOG', raising=False)
    command = NodeSpec('mock_robot', {'time_scale': '0.2'}).command()
    assert command[3:5] == ['--ros-args', '--disable-external-lib-logs']
    monkeypatch.setenv('COBOT_CALIB_CLIENT_LOG', '1')
    assert '--disable-external-lib-logs' not in NodeSpec('mock_robot').command()
